"""Blender's default startup scene by Cycles and by RESTframe's Path Tracing, at rest and moving.

    tools/dev.sh sample_blends/render_default_scene.py     # writes docs/gallery/default_scene.png

Left to right: Cycles (CPU), RESTframe Path Tracing at rest (the faces turned from the lamp lit by
the grey world, as in Cycles), and the cube flying toward the camera at 0.5c in Spectral mode
(light-travel delay, aberration, the world and the lamp blue-shifted and brighter as the cube
receives them, its light Doppler-shifted again on the way to the camera).  Same samples and bounce
limits for both engines, the 'Standard' view transform.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "sample_blends"), str(ROOT / "tests" / "blender")]

SIZE = (192, 108)
SAMPLES = 64


def main():
    import bpy

    import restframe_addon
    import render_gallery
    from blender_helpers import render_rgba

    import samplelib as lib

    restframe_addon.register()
    bpy.ops.wm.read_factory_settings()
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = SIZE
    scene.render.resolution_percentage = 100
    scene.view_settings.view_transform = 'Standard'
    scene.cycles.device, scene.cycles.samples, scene.cycles.use_denoising = 'CPU', SAMPLES, False
    scene.cycles.max_bounces = 4
    rf = scene.restframe
    rf.integrator, rf.samples, rf.max_bounces = 'PATH', SAMPLES, 4
    folder = Path(tempfile.mkdtemp())
    images = []
    scene.render.engine = 'CYCLES'
    images.append(render_rgba(scene, folder / "cycles.exr")[..., :3])
    scene.render.engine = 'RESTFRAME'
    images.append(render_rgba(scene, folder / "rest.exr")[..., :3])
    cube, camera = bpy.data.objects["Cube"], bpy.data.objects["Camera"]
    toward = np.asarray(camera.location) - np.asarray(cube.location)
    cube.restframe.velocity = tuple(0.5 * toward / np.linalg.norm(toward))
    rf.doppler_mode, rf.spectral_samples = 'SPECTRAL', 16
    images.append(render_rgba(scene, folder / "moving.exr")[..., :3])
    # rows bottom-up (Blender) -> top-down, linear -> display
    images = [lib.srgb(image[::-1]) for image in images]
    render_gallery.strip(images, ["Cycles", "RESTframe at rest", "cube at 0.5c (Spectral)"],
                         os.path.join(lib.ROOT, "docs", "gallery", "default_scene.png"))


if __name__ == "__main__":
    main()

"""Subprocess of the benchmark: one scene rendered through bpy by Cycles (CPU) and by RESTframe.

    python tests/bench/bench_cycles_worker.py OUT.json SIZE "CYCLES:1,4,16;RESTFRAME:1,4"

Each render is ``bpy.ops.render.render()`` timed on the wall clock (scene sync and BVH build
included on both sides), then the Combined image is written as EXR and read back.  Images go
to OUT.json's folder as .npy; the JSON lists (engine, samples, seconds, npy path).
"""

import json
import math
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path[:0] = [str(ROOT), str(ROOT / "tests" / "blender")]


def build_scene(size):
    import bpy
    from blender_helpers import principled

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.resolution_x = scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    scene.render.threads_mode = 'FIXED'
    scene.render.threads = 2
    scene.view_settings.view_transform = 'Standard'
    world = bpy.data.worlds.new("World")
    world.color = (0.0, 0.0, 0.0)  # no world light: RESTframe lights only with lamps
    with warnings.catch_warnings():  # deprecated in 5.0, still the way to a plain colour world
        warnings.simplefilter("ignore", DeprecationWarning)
        world.use_nodes = False
    scene.world = world

    bpy.ops.mesh.primitive_uv_sphere_add(segments=64, ring_count=32, radius=1.0, location=(0.0, 0.0, 0.0))
    ball = bpy.context.active_object
    ball.data.materials.append(principled("Ball", (0.8, 0.3, 0.2), 0.0, 0.5))
    bpy.ops.mesh.primitive_plane_add(size=12.0, location=(0.0, 0.0, -1.0))
    bpy.context.active_object.data.materials.append(principled("Floor", (0.7, 0.7, 0.7), 0.0, 0.8))
    lamp = bpy.data.lights.new("Lamp", 'POINT')
    lamp.energy = 2500.0
    lamp.shadow_soft_size = 0.6
    obj = bpy.data.objects.new("Lamp", lamp)
    obj.location = (3.0, -4.0, 5.0)
    scene.collection.objects.link(obj)
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    cam.location = (0.0, -6.0, 1.5)
    direction = np.array([0.0, 6.0, -1.7])
    cam.rotation_euler = (math.atan2(math.hypot(direction[0], direction[1]), -direction[2]), 0.0, 0.0)
    scene.collection.objects.link(cam)
    scene.camera = cam
    scene.cycles.device = 'CPU'
    scene.cycles.use_denoising = False
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.max_bounces = 0  # direct light only: what RESTframe computes for a diffuse scene
    scene.cycles.filter_width = 0.01  # (almost) box pixels, like RESTframe's stratified samples
    scene.cycles.seed = 1
    scene.restframe.integrator = 'DIRECT'  # as Cycles' max_bounces = 0 (a new scene's default is PATH)
    return scene


def render(scene, engine, samples, path):
    import bpy

    scene.render.engine = engine
    if engine == 'CYCLES':
        scene.cycles.samples = samples
    else:
        scene.restframe.samples = samples
    settings = scene.render.image_settings
    if hasattr(settings, "media_type"):
        settings.media_type = 'IMAGE'
    settings.file_format = 'OPEN_EXR'
    settings.color_depth = '32'
    t0 = time.perf_counter()
    bpy.ops.render.render(write_still=False)
    seconds = time.perf_counter() - t0
    bpy.data.images["Render Result"].save_render(filepath=str(path.with_suffix(".exr")), scene=scene)
    import OpenEXR

    with OpenEXR.File(str(path.with_suffix(".exr"))) as exr:
        channels = exr.parts[0].channels
        if "RGBA" in channels or "RGB" in channels:
            pixels = np.asarray(channels.get("RGBA", channels.get("RGB")).pixels, dtype=np.float32)
        else:
            pixels = np.stack([np.asarray(channels[c].pixels, dtype=np.float32) for c in "RGB"], axis=-1)
    np.save(path.with_suffix(".npy"), pixels[..., :3])
    path.with_suffix(".exr").unlink()
    return seconds


def main():
    out = Path(sys.argv[1])
    size = int(sys.argv[2])
    plan = [(engine, [int(s) for s in counts.split(",")]) for engine, counts in
            (part.split(":") for part in sys.argv[3].split(";"))]
    import restframe_addon

    restframe_addon.register()
    scene = build_scene(size)
    results = []
    for engine, counts in plan:
        for samples in counts:
            path = out.parent / f"{engine.lower()}_{samples}"
            seconds = render(scene, engine, samples, path)
            results.append({"engine": engine, "samples": samples, "seconds": seconds, "image": str(path.with_suffix(".npy"))})
            print(f"{engine} {samples}: {seconds:.2f} s", file=sys.stderr, flush=True)
    out.write_text(json.dumps(results))


if __name__ == "__main__":
    main()

"""Cost of depth of field and motion blur against samples: error against run time.

    tools/dev.sh tests/bench/measure_lens.py [--width 64] [--reference 256]

One small scene (a lit floor, three spheres, one of them moving at 0.5c) rendered as a pinhole,
with depth of field, with motion blur and with both, at 4, 16 and 64 samples per pixel; the
error is the relative RMS difference from the same mode at the reference sample count, the time
the best of two single-threaded runs, interleaved across modes so all see the same machine load.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

from bench_common import look_at_camera, quad, uv_sphere  # (bench_common puts the repository on sys.path)
from restframe_addon.core.render import render_image
from restframe_addon.core.scene import Light, Material, Mesh, RenderSettings, Scene, Velocity

MODES = ("pinhole", "depth of field", "motion blur", "both")


def scene_for(mode: str, aspect: float) -> Scene:
    camera = look_at_camera((0.0, -6.0, 1.5), (0.0, 0.0, 0.5), fov_half_tan=0.45, aspect=aspect)
    if mode in ("depth of field", "both"):
        camera = replace(camera, aperture_radius=0.12, focus_distance=6.2, aperture_blades=6)
    if mode in ("motion blur", "both"):
        camera = replace(camera, shutter_interval=(-1.0, 1.0))  # c = 1 unit/s: 2 units of light travel
    floor, floor_tris = quad((0.0, 0.0, 0.0), (20.0, 20.0))
    meshes = [Mesh("floor", floor, floor_tris, material_indices=np.zeros(2, dtype=int))]
    for name, centre, velocity in (("near", (-1.5, -2.5, 0.6), (0.0, 0.0, 0.0)),
                                   ("moving", (0.0, 0.0, 0.8), (0.5, 0.0, 0.0)),
                                   ("far", (1.8, 4.0, 1.0), (0.0, 0.0, 0.0))):
        v, t = uv_sphere(centre, 0.6 if name != "far" else 1.0, 32, 16)
        meshes.append(Mesh(name, v, t, velocity=Velocity(velocity), pivot=centre,
                           material_indices=np.ones(len(t), dtype=int)))
    return Scene(camera=camera, meshes=meshes,
                 materials=[Material(base_color=(0.6, 0.6, 0.6)), Material(base_color=(0.8, 0.3, 0.1), roughness=0.3)],
                 lights=[Light("lamp", "POINT", (2.0, -3.0, 4.0), power=800.0, radius=0.2)],
                 world_color=(0.05, 0.05, 0.08), light_speed=1.0)


def render(scene, resolution, samples):
    start = time.perf_counter()
    image = render_image(scene, RenderSettings(resolution=resolution, samples=samples, threads=1, passes=()))
    return image["Combined"][..., :3].astype(np.float64), time.perf_counter() - start


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--width", type=int, default=64)
    parser.add_argument("--reference", type=int, default=256)
    args = parser.parse_args()
    resolution = (args.width, args.width * 3 // 4)
    scenes = {mode: scene_for(mode, 4 / 3) for mode in MODES}
    reference = {mode: render(scenes[mode], resolution, args.reference)[0] for mode in MODES}
    print(f"{resolution[0]}x{resolution[1]} px, reference {args.reference} samples; relative RMS error, seconds (1 thread)")
    print("| samples | " + " | ".join(f"{mode}: error, s" for mode in MODES) + " |")
    print("| --- |" + " --- |" * len(MODES))
    for samples in (4, 16, 64):
        best, errors = {mode: np.inf for mode in MODES}, {}
        for _ in range(2):  # interleaved repeats: every mode sees the same load
            for mode in MODES:
                image, seconds = render(scenes[mode], resolution, samples)
                best[mode] = min(best[mode], seconds)
                errors[mode] = float(np.sqrt(np.mean((image - reference[mode]) ** 2) / np.mean(reference[mode] ** 2)))
        print(f"| {samples} | " + " | ".join(f"{errors[mode]:.4f}, {best[mode]:.2f}" for mode in MODES) + " |")


if __name__ == "__main__":
    main()

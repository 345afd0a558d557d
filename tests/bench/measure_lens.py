"""Section 8: the cost of depth of field and motion blur against samples: error against run time.

    tools/dev.sh tests/bench/measure_lens.py [--width 96] [--reference 512]   # this section alone, printed
    tools/dev.sh tests/bench/measure_lens.py --smoke                          # tiny sizes

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

from bench_common import Context, Section, load, look_at_camera, print_section, quad, standalone_context, uv_sphere  # (puts the repository on sys.path)
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


def measure(width: int, reference_samples: int, sample_counts, repeats: int):
    """{samples: {mode: (error, best seconds)}}: every mode at every sample count, timed
    ``repeats`` times interleaved across modes, so all see the same machine load."""
    resolution = (width, width * 3 // 4)
    scenes = {mode: scene_for(mode, 4 / 3) for mode in MODES}
    reference = {mode: render(scenes[mode], resolution, reference_samples)[0] for mode in MODES}
    table = {}
    for samples in sample_counts:
        best, errors = {mode: np.inf for mode in MODES}, {}
        for _ in range(repeats):
            for mode in MODES:
                image, seconds = render(scenes[mode], resolution, samples)
                best[mode] = min(best[mode], seconds)
                errors[mode] = float(np.sqrt(np.mean((image - reference[mode]) ** 2) / np.mean(reference[mode] ** 2)))
        table[samples] = {mode: (errors[mode], best[mode]) for mode in MODES}
    return table


def run(ctx: Context, width: int | None = None, reference_samples: int | None = None) -> Section:
    sec = Section("8. Depth of field and motion blur: error against run time")
    width = width or ctx.pick(96, 16)
    reference_samples = reference_samples or ctx.pick(512, 16)
    sample_counts = ctx.pick((4, 16, 64), (1, 4))
    load_start = load()
    table = measure(width, reference_samples, sample_counts, repeats=2)
    sec.add(" ".join(__doc__.split("\n\n", 2)[2].split()))
    sec.add("")
    sec.add(f"{width}x{width * 3 // 4} px, reference {reference_samples} samples, one thread; load average "
            f"{load_start:.2f} at the start, {load():.2f} at the end (2 cores shared with other work). "
            "Each cell: relative RMS error, seconds.")
    sec.add("")
    sec.table(["samples", "pinhole", "depth of field (6 blades)", "motion blur (2 units of light travel)", "both"],
              [[n] + [f"{table[n][mode][0]:.4f}, {table[n][mode][1]:.2f} s" for mode in MODES] for n in sample_counts])
    for n in sample_counts:
        for mode in MODES:
            sec.number(f"lens_error_{mode.replace(' ', '_')}_{n}", table[n][mode][0])
    sec.add("A sample costs more with a lens or a shutter (rays from many origins or times lose the shared-origin "
            "culling of a pinhole's bundle); the blur itself needs samples. The lens and shutter numbers are "
            "stratified per pixel, each in a random order of its own (stratifying them in step with the pixel "
            "jitter left a bias: an error of 0.010 at 256 samples instead of 0.004).")
    return sec


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--smoke", action="store_true")
    parser.add_argument("--width", type=int)
    parser.add_argument("--reference", type=int)
    args = parser.parse_args()
    print_section(run(standalone_context(args.smoke), args.width, args.reference))


if __name__ == "__main__":
    main()

"""Pixel baseline: render every sample .blend and a few core scenes, save or compare every pass.

    tools/dev.sh tools/pixel_baseline.py save /work/baseline       # on the code to keep bit-identical
    tools/dev.sh tools/pixel_baseline.py compare /work/baseline    # after a change: exit 1 unless identical
    tools/dev.sh tools/pixel_baseline.py compare /work/baseline -k moving_sphere -k core_
    tools/dev.sh tools/pixel_baseline.py compare /work/baseline --colour-rtol 2e-6  # colour within a tolerance

The sample scenes go through the whole headless path (bpy, the RESTFRAME engine, a 32-bit
multilayer EXR, as sample_blends/samplelib.py renders them) at a small resolution (the longer
side ``--size`` pixels) with the samples saved in each file; the core scenes through
``render_image``.  Each scene's passes go to ``FOLDER/<name>.npz``.  The renderer is
deterministic (every random number is keyed by pixel and sample), so any refactor that keeps
the physics must reproduce these arrays bit for bit.  ``--colour-rtol R`` lets the colour passes
(:data:`COLOUR_PASSES`) differ by at most R times each pixel's largest colour channel (relative to
the pixel's value: a channel near 0 beside a bright one is not asked for more than the bright
one's precision); every other pass stays bit for bit, and each case reports its largest
differences.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "sample_blends"
sys.path[:0] = [str(ROOT), str(SAMPLES), str(ROOT / "tests" / "core")]
COLOUR_PASSES = ("Combined",)  # the passes --colour-rtol applies to (RGBA: the tolerance of the RGB)


def sample_scenes(size: int):
    """name -> render(): every committed sample .blend through the engine."""
    def render(blend: Path):
        import samplelib

        def small(scene):
            render = scene.render
            render.resolution_percentage = max(1, min(100, round(100 * size / max(render.resolution_x,
                                                                                     render.resolution_y))))
        with tempfile.TemporaryDirectory() as folder:
            passes, _ = samplelib.render_blend(str(blend), Path(folder) / "frame.exr", prepare=small)
        return passes
    return {blend.stem: (lambda blend=blend: render(blend)) for blend in sorted(SAMPLES.glob("*.blend"))}


def core_scenes():
    """name -> render(): scenes built in numpy covering the core's modes (moving, spinning and
    animated bodies, spectral colour, the Doppler-factor display, exposure, glass, regions)."""
    from scenes import busy_scene

    from restframe_addon.core.render import render_image
    from restframe_addon.core.scene import RenderSettings, Velocity

    def settings(**kw):
        return RenderSettings(**{"resolution": (40, 30), "threads": 1, "tile_size": 16, **kw})

    moving = Velocity((0.0, 0.4, 0.0))
    return {
        "core_rgb": lambda: render_image(busy_scene(), settings(samples=2)),
        "core_spectral_exposure": lambda: render_image(busy_scene(), settings(
            doppler_mode="SPECTRAL", spectral_samples=8, normalize_exposure=True)),
        "core_factor_levels": lambda: render_image(busy_scene(moving), settings(
            doppler_mode="FACTOR", doppler_levels=5, samples=3)),
        "core_factor_region": lambda: render_image(busy_scene(), settings(
            doppler_mode="FACTOR", region=(5, 4, 33, 27), film_transparent=True)),
        "core_moving_camera_transparent": lambda: render_image(busy_scene(moving), settings(
            film_transparent=True, searchlight=False, passes=("Doppler", "Normal"))),
    }


def scenes(size: int):
    return {**sample_scenes(size), **core_scenes()}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("mode", choices=("save", "compare"))
    parser.add_argument("folder", type=Path)
    parser.add_argument("-k", action="append", default=[], help="only scenes whose name contains this (repeatable)")
    parser.add_argument("--size", type=int, default=64, help="pixels on the longer side of the sample renders")
    parser.add_argument("--colour-rtol", type=float, default=0.0,
                        help="compare: the colour passes may differ by this times each pixel's largest "
                             "colour channel (default 0: bit for bit)")
    args = parser.parse_args(argv)
    chosen = {name: render for name, render in scenes(args.size).items()
              if not args.k or any(k in name for k in args.k)}
    if args.mode == "save":
        args.folder.mkdir(parents=True, exist_ok=True)
        os.chmod(args.folder, 0o755)
    failures, tolerated = [], []
    for name, render in chosen.items():
        passes = {key: np.asarray(value) for key, value in render().items()}
        path = args.folder / f"{name}.npz"
        if args.mode == "save":
            np.savez_compressed(path, **passes)
            os.chmod(path, 0o644)
            print(f"saved {name}: {', '.join(sorted(passes))}", flush=True)
            continue
        with np.load(path) as reference:
            expected = dict(reference)
        problems, within = compare_passes(passes, expected, args.colour_rtol)
        verdict = "DIFFERENT" if problems else "within colour tolerance" if within else "identical"
        notes = problems + within
        print(f"{verdict} {name}{': ' if notes else ''}{'; '.join(notes)}", flush=True)
        if problems:
            failures.append(name)
        elif within:
            tolerated.append(name)
    if args.mode == "compare":
        print(f"{len(chosen) - len(failures) - len(tolerated)} of {len(chosen)} scenes bit-identical"
              + (f", {len(tolerated)} within --colour-rtol {args.colour_rtol:g}" if tolerated else ""), flush=True)
    return 1 if failures else 0


def compare_passes(passes: dict, expected: dict, colour_rtol: float = 0.0) -> tuple[list, list]:
    """(what differs beyond the tolerance, what differs within it), a line per pass: every pass bit
    for bit but the colour passes, which may differ by ``colour_rtol`` of the pixel's value."""
    problems = [f"passes {sorted(passes)} != {sorted(expected)}"] if passes.keys() != expected.keys() else []
    within = []
    for key in sorted(passes.keys() & expected.keys()):
        a, b = passes[key], expected[key]
        if a.shape != b.shape or a.dtype != b.dtype:
            problems.append(f"{key}: {a.shape} {a.dtype} != {b.shape} {b.dtype}")
        elif not np.array_equal(a.view(np.uint8), b.view(np.uint8)):
            differ = np.count_nonzero(a != b) + np.count_nonzero(np.isnan(a) != np.isnan(b))
            absolute, relative = colour_difference(a, b)
            note = f"{key}: {differ} values differ (max |diff| {absolute:.3g}, of the pixel {relative:.3g})"
            (within if key in COLOUR_PASSES and relative <= colour_rtol else problems).append(note)
    return problems, within


def colour_difference(a, b) -> tuple[float, float]:
    """The largest |a - b| of two (..., C) images and the largest |a - b| over the pixel's largest
    |b| of its first three channels (its colour; inf where NaNs differ or a black pixel changed)."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if np.any(np.isnan(a) != np.isnan(b)):
        return np.inf, np.inf
    diff = np.abs(np.where(np.isnan(b), 0.0, a - b))
    scale = np.nanmax(np.abs(b[..., :3]), axis=-1, keepdims=True) if b.ndim >= 2 else np.abs(b)
    relative = np.divide(diff, scale, out=np.where(diff > 0.0, np.inf, 0.0), where=scale > 0.0)
    return float(diff.max(initial=0.0)), float(relative.max(initial=0.0))


if __name__ == "__main__":
    sys.exit(main())

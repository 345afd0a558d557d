"""Before/after of moving_sphere's random numbers and camera rays per sample, both checkouts in one process.

    git worktree add /tmp/base origin/main
    tools/dev.sh tests/bench/ab_keys.py /tmp/base --repeats 15   # this checkout against /tmp/base

What render_tile and the shader do with a batch's samples, for every batch of one moving_sphere
render (960x540, 8 samples, in each checkout's render_tile batches: one sample of 32 768 pixels
since cull15), each checkout's own code: "camera" = the tiles'
pixel grids and strata starts, then per batch the jitter (with this checkout: the (pixel, sample)
hash kept for the batch) and the pinhole rays through it; "shader" = what the shader's hits take
of the samples (the orders and lit selections recorded from a render) and the lamp's two random
numbers from them.  The two checkouts' modules are imported side by side and timed in turn (CPU
time, min and median over the repeats); the results are checked bit for bit.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve()
SAMPLES, DIMENSIONS = 8, (1000, 1001)


def _load(root: str) -> dict:
    sys.path.insert(0, root)
    for name in [name for name in sys.modules if name.split(".")[0] == "restframe_addon"]:
        del sys.modules[name]
    from restframe_addon.core import camera, malloc, render, rows, sampling
    sys.path.pop(0)
    return {"camera": camera, "rows": rows, "sampling": sampling, "malloc": malloc, "render": render}


def _record():
    """The scene, its non-empty tiles and the shader's (order, lit selection, pixel ids, sample
    numbers) of each batch, from one render with this checkout."""
    sys.path[:0] = [str(HERE.parent), str(HERE.parents[2])]
    from bench_common import register_addon
    register_addon()
    from bench_parallel import export_blend

    from restframe_addon.core import shading
    from restframe_addon.core.prepared import prepare
    from restframe_addon.core.render import UnseenTiles, render_tiles
    from restframe_addon.core.tracer import TraceCache
    scene, settings = export_blend("moving_sphere.blend", (960, 540), SAMPLES, None)
    prepared = prepare(scene, dataclasses.replace(settings, parallelism="THREADS", threads=1))
    calls, shade, occlude = [], shading.Shader._shade_batch, shading.Shader._occluded

    def shade_batch(self, src, hits, order, segments, depth, ids, *args):
        calls.append([order, None, ids.pixel, ids.sample])
        return shade(self, src, hits, order, segments, depth, ids, *args)

    def occluded(self, segments, sel, *args):
        calls[-1][1] = sel
        return occlude(self, segments, sel, *args)
    shading.Shader._shade_batch, shading.Shader._occluded = shade_batch, occluded
    list(render_tiles(prepared, threads=1))
    shading.Shader._shade_batch, shading.Shader._occluded = shade, occlude
    rects = prepared.tiles()
    seen = [rect for rect, empty in zip(rects, UnseenTiles(prepared).find(rects, TraceCache())) if not empty]
    return prepared, seen, calls


def _camera(side: dict, prepared, rects):
    """The tiles' jitter and camera rays in render_tile's batches; with Samples: the hash kept."""
    sampling, cameras = side["sampling"], side["camera"].CameraRays(prepared.scene.camera, prepared.settings.resolution)
    kept = hasattr(sampling, "Samples")
    out = []
    for x0, y0, x1, y1 in rects:
        width = prepared.settings.resolution[0]
        pixel = np.add.outer(np.arange(y0, y1) * width, np.arange(x0, x1)).ravel()
        dtype = np.float64 if kept else np.int64  # (pixel_grid's coordinates in each checkout)
        xs = np.tile(np.arange(x0, x1, dtype=dtype), y1 - y0)
        ys = np.repeat(np.arange(y0, y1, dtype=dtype), x1 - x0)
        starts = sampling.strata_starts(pixel, SAMPLES)
        halves = sampling.pixel_halves(pixel) if kept else None
        for part, first, count in side["render"]._batches(len(pixel), SAMPLES, 3):  # (render_tile's batches)
            keys = sampling.block_keys(halves[part], first, count) if kept else None
            args = (xs[part], ys[part], pixel[part], first, count, SAMPLES, starts[part])
            px, py = sampling.stratified_positions(*args, keys) if kept else sampling.stratified_positions(*args)
            out.append(cameras(px, py)[1:4])
    return out


def _shader(side: dict, calls):
    """The shader's hits' samples and the lamp's numbers, as each checkout takes them."""
    sampling, rows = side["sampling"], side["rows"]
    out = []
    for order, sel, pixel, sample in calls:
        if hasattr(sampling, "Samples"):
            ids = sampling.Samples(pixel, sample, _KEYS[id(pixel)]).take(order)  # (the camera stage made the hash)
            out.append(ids.uniforms(DIMENSIONS))
            if sel is not None:
                ids.take(sel)
        else:
            p, s = rows.take(pixel, order), rows.take(sample, order)
            out.append(sampling.uniforms(p, s, DIMENSIONS))
            if sel is not None:
                rows.take(p, sel), rows.take(s, sel)
    return out


_KEYS: dict = {}  # the jitter's hash of each recorded batch (made by the camera stage, outside the timing)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("before", help="the checkout to compare against (a git worktree)")
    parser.add_argument("--repeats", type=int, default=15)
    args = parser.parse_args()
    prepared, rects, calls = _record()
    after = _load(str(HERE.parents[2]))
    for order, sel, pixel, sample in calls:
        _KEYS[id(pixel)] = after["sampling"]._sample_keys(pixel, sample)
    sides = {"before": _load(args.before), "after": after}
    after["malloc"].tune()
    stages = {"camera": lambda side: _camera(side, prepared, rects), "shader": lambda side: _shader(side, calls)}
    results = {(s, n): stage(side) for s, side in sides.items() for n, stage in stages.items()}
    same = {n: all(np.array_equal(a, b) for x, y in zip(results["before", n], results["after", n]) for a, b in zip(x, y))
            for n in stages}
    times = {key: [] for key in results}
    for repeat in range(args.repeats):
        for s in (("before", "after") if repeat % 2 else ("after", "before")):
            for n, stage in stages.items():
                start = time.process_time()
                stage(sides[s])
                times[s, n].append(time.process_time() - start)
    print(f"moving_sphere 960x540x{SAMPLES}: {len(rects)} tiles seen, {len(calls)} shaded batches; CPU s, "
          f"min / median of {args.repeats} interleaved repeats")
    print("| stage | before | after | after / before (min) | same bits |\n|---|---|---|---|---|")
    for n in stages:
        b, a = sorted(times["before", n]), sorted(times["after", n])
        print(f"| {n} | {b[0]:.4f} / {b[len(b) // 2]:.4f} | {a[0]:.4f} / {a[len(a) // 2]:.4f} | {a[0] / b[0]:.2f} | "
              f"{same[n]} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Before/after of a batch's sample jitter and camera rays, both checkouts in one process, interleaved.

    git worktree add /tmp/base origin/main
    tools/dev.sh tests/bench/ab_jitter.py /tmp/base          # this checkout against /tmp/base

One batch of render_tile (a 64x64-pixel tile at 8 samples, pixel-major, as render_tile asks for
it): the jitter (image positions of every sample), then the perspective camera's rays through them
(in that order: a stage's page faults depend on what the one before freed).
The two checkouts' modules are imported side by side and timed in turn (CPU time, min over the
repeats), so a process's memory layout and the machine's load fall on both alike: ab_cpu.py's
separate processes differ by up to 15% even for the same checkout.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

WIDTH, HEIGHT, SAMPLES, TILE = 960, 540, 8, 64


def _load(root: str):
    sys.path.insert(0, root)
    for name in [name for name in sys.modules if name.split(".")[0] == "restframe_addon"]:
        del sys.modules[name]
    from restframe_addon.core import camera, sampling, scene
    sys.path.pop(0)
    return camera, sampling, scene


def _jitter(sampling, xs, ys, pixel):
    if hasattr(sampling, "stratified_positions"):
        return sampling.stratified_positions(xs, ys, pixel, 0, SAMPLES, SAMPLES)
    pix, smp = np.repeat(pixel, SAMPLES), np.tile(np.arange(SAMPLES), len(pixel))  # render_tile's, before
    ox, oy = sampling.stratified_offsets(pix, smp, SAMPLES)
    return np.repeat(xs, SAMPLES) + ox, np.repeat(ys, SAMPLES) + oy


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("before")
    parser.add_argument("--after", default=str(Path(__file__).resolve().parents[2]))
    parser.add_argument("--repeats", type=int, default=60)
    args = parser.parse_args()
    xs = np.tile(np.arange(TILE), TILE)
    ys = np.repeat(np.arange(TILE), TILE)
    pixel = ys * WIDTH + xs
    batches, results = {}, {}
    for side, root in (("before", args.before), ("after", args.after)):
        camera, sampling, scene = _load(root)
        rays = camera.CameraRays(scene.Camera(name="Camera", matrix=np.eye(4)), (WIDTH, HEIGHT))
        batches[side] = (lambda s=sampling: _jitter(s, xs, ys, pixel)), rays
        px, py = batches[side][0]()
        results[side] = (px, py, *rays(px, py))
    same = all(np.array_equal(a, b) for a, b in zip(results["before"], results["after"]))
    best = {(side, stage): np.inf for side in batches for stage in ("jitter", "camera rays", "both")}
    for _ in range(args.repeats):
        for side, (jitter, rays) in batches.items():  # as render_tile: the rays right after the jitter
            start = time.process_time()
            px, py = jitter()
            middle = time.process_time()
            rays(px, py)
            end = time.process_time()
            for stage, seconds in (("jitter", middle - start), ("camera rays", end - middle), ("both", end - start)):
                best[side, stage] = min(best[side, stage], seconds)
    n = len(pixel) * SAMPLES
    print(f"{n} samples per batch, ns per sample, min of {args.repeats} interleaved; bit-identical: {same}")
    print("| | before | after | after / before |\n|---|---|---|---|")
    for stage in ("jitter", "camera rays", "both"):
        before, after = best["before", stage] / n * 1e9, best["after", stage] / n * 1e9
        print(f"| {stage} | {before:.1f} | {after:.1f} | {after / before:.2f} |")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())

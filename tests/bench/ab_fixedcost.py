"""The fixed cost of an F12: section 7's Cornell box through ``bpy.ops.render.render()``, before/after.

    git worktree add /tmp/fixedcost-base origin/main
    tools/dev.sh tests/bench/ab_fixedcost.py /tmp/fixedcost-base                 # base against this checkout
    tools/dev.sh tests/bench/ab_fixedcost.py /tmp/fixedcost-base --samples 16 --rounds 4

Each round renders the box (``tests/blender/test_blender_path.cornell_box``, 32 x 32 px, 4
bounces, as ``bench_path_cycles``, worker processes by default) REPEATS times in one process per
checkout, the checkouts in turn, after a warm-up.  CPU is this process's plus the workers' (their
builds and shares, from ``WorkerPool.last_stats``), what the render costs whatever the machine's
load; wall clock only means something on a quiet machine.  Min over every render of every round.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve()
ROOT = HERE.parents[2]


def measure(repo: str, samples: int, repeats: int, parallelism: str) -> dict:
    """(wall, CPU) seconds of each F12 of ``repo``'s Cornell box, after three warm-up renders."""
    sys.path[:0] = [repo, repo + "/tests/blender"]
    import test_blender_path as path_tests
    from blender_helpers import render_rgba

    import restframe_addon
    from restframe_addon.core import workers

    restframe_addon.register()
    scene = path_tests.cornell_box()
    path_tests.SIZE = 32
    folder = Path(tempfile.mkdtemp())
    path_tests.render_pair(scene, folder, samples=1, bounces=4, seeds=(1,))  # set up as section 7
    scene.render.engine = "RESTFRAME"
    rf = scene.restframe
    rf.samples, rf.parallelism = samples, parallelism
    rf.max_bounces = rf.diffuse_bounces = rf.glossy_bounces = rf.transmission_bounces = 4
    for _ in range(3):
        render_rgba(scene, folder / "warm.exr")
    wall, cpu = [], []
    for _ in range(repeats):
        started, cpu_started = time.perf_counter(), time.process_time()
        render_rgba(scene, folder / "timed.exr")
        wall.append(time.perf_counter() - started)
        stats = workers.pool().last_stats if parallelism == "PROCESSES" else None
        in_workers = 0.0 if stats is None else (sum(c for _, _, c in stats.builds.values())
                                                + sum(c for shares in stats.rendered.values() for *_, c in shares))
        cpu.append(time.process_time() - cpu_started + in_workers)
    return {"wall": wall, "cpu": cpu}


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("base", help="the checkout to compare against (a git worktree)")
    parser.add_argument("--samples", type=int, default=4)
    parser.add_argument("--rounds", type=int, default=4)
    parser.add_argument("--repeats", type=int, default=8, help="renders per round and checkout")
    parser.add_argument("--parallelism", default="PROCESSES", choices=("PROCESSES", "THREADS"))
    parser.add_argument("--worker", help=argparse.SUPPRESS)  # a checkout to measure in this process
    args = parser.parse_args()
    if args.worker:
        print(json.dumps(measure(args.worker, args.samples, args.repeats, args.parallelism)))
        return
    checkouts = {"base": str(Path(args.base).resolve()), "this": str(ROOT)}
    results = {name: {"wall": [], "cpu": []} for name in checkouts}
    for round_ in range(args.rounds):
        for name in (list(checkouts) if round_ % 2 == 0 else list(checkouts)[::-1]):
            done = subprocess.run([sys.executable, str(HERE), checkouts["base"], "--worker", checkouts[name],
                                   "--samples", str(args.samples), "--repeats", str(args.repeats),
                                   "--parallelism", args.parallelism],
                                  capture_output=True, text=True, check=True)
            for key, values in json.loads(done.stdout.splitlines()[-1]).items():
                results[name][key] += values
    print(f"{args.samples} samples, {args.parallelism}, {args.rounds} rounds x {args.repeats} renders: min ms")
    for name, times in results.items():
        print(f"  {name}: CPU {1e3 * min(times['cpu']):.1f}, wall {1e3 * min(times['wall']):.1f}")


if __name__ == "__main__":
    main()

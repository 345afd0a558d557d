"""Before/after in one run for the 11x11 bars of ``bench_throughput.py --bars``: each checkout
renders the scene at one velocity and at 11 velocities (256x192, one thread), interleaved, in CPU
milliseconds (min of the repeats), with the CPU time inside the shading's shadow-ray calls
(``occluded``, summed over the render; it repeats far better than the whole render), the rays its
camera bundle maps and queries per render and the minor page faults per render.

    git worktree add /tmp/base origin/main
    tools/dev.sh tests/bench/ab_bars.py /tmp/base --repeats 40

Each checkout runs in its own process, asked in turn, alternating the order (``ab_servers``). The 1-velocity render
moves by several ms between processes of the same code (page faults: how glibc's heap happens to
grow), so compare the 11-velocity render across checkouts and run the command more than once.
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

from ab_servers import answer_requests, ask_each_in_turn

HERE = Path(__file__).resolve()
VELOCITIES = {"1": [0.5] * 11, "11": [0.05 + 0.08 * i for i in range(11)]}


def serve(repo: str) -> None:
    sys.path[:0] = [repo + "/tests/bench", repo]
    from bench_throughput import bars_scene, settings

    from restframe_addon.core import shading, tracer
    from restframe_addon.core.render import render_image

    queried = [0]
    query = tracer._query

    def counted(frame, tau, origin, d, t_lo, t_hi, occlusion):
        queried[0] += 0 if occlusion else len(d)
        return query(frame, tau, origin, d, t_lo, t_hi, occlusion)

    tracer._query = counted
    shadow = [0.0]
    occluded = shading.occluded

    def timed(*args, **kwargs):
        started = time.process_time()
        try:
            return occluded(*args, **kwargs)
        finally:
            shadow[0] += time.process_time() - started

    shading.occluded = timed
    s = settings((256, 192))
    scenes = {k: bars_scene(v) for k, v in VELOCITIES.items()}
    for scene in scenes.values():
        render_image(scene, s)

    def answer(velocities):
        queried[0], shadow[0] = 0, 0.0
        faults, t0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt, time.process_time()
        render_image(scenes[velocities], s)
        cpu = time.process_time() - t0
        return [cpu, queried[0], resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults, shadow[0]]

    answer_requests(answer)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("before", help="the checkout to compare against (a git worktree)")
    parser.add_argument("--after", default=str(HERE.parents[2]), help="default: this checkout")
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--serve", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve:
        serve(args.serve)
        return 0
    results = ask_each_in_turn({name: ([sys.executable, str(HERE), "-", "--serve", repo], None)
                                for name, repo in (("before", args.before), ("after", args.after))},
                               args.repeats, tuple(VELOCITIES))
    print(f"11x11 bars, 256x192, one thread, CPU ms (min of {args.repeats} interleaved repeats)")
    print("| | 1 velocity | 11 velocities | 11 / 1 | occluded (1 / 11) | camera rays queried (1 / 11) "
          "| page faults (1 / 11) |")
    print("|---|---|---|---|---|---|---|")
    for name in ("before", "after"):
        (one, rays1, faults1, shadow1), (many, rays11, faults11, shadow11) = (
            (min(a[0] for a in results[(name, k)]) * 1e3, results[(name, k)][0][1],
             min(a[2] for a in results[(name, k)]), min(a[3] for a in results[(name, k)]) * 1e3) for k in VELOCITIES)
        print(f"| {name} | {one:.2f} | {many:.2f} | {many / one:.2f} | {shadow1:.2f} / {shadow11:.2f} "
              f"| {rays1} / {rays11} | {faults1} / {faults11} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())

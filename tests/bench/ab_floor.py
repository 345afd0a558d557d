"""Before/after in one run: the primary-ray floor's F12 on two threads beside raw Embree's, per thread.

    git worktree add /tmp/base origin/main
    tools/dev.sh tests/bench/ab_floor.py /tmp/base --repeats 9              # wall, sleep, ratio
    tools/dev.sh tests/bench/ab_floor.py /tmp/base --repeats 9 --timeline   # and each thread's intervals

The floor of ``bench_per_sample`` (261k-triangle sphere at (0.5, 0.2, 0) c, 1536^2, one sample, no
lights, threads) against raw Embree (its build, then ``embree.run`` of the same pixel rays over as
many Python threads: every other tile to each thread, ``bench_per_sample``'s split before
session 8, and ``raw dealt``, each thread taking the next tile's rays when it is free, its split
since), both in each checkout's own server, asked in turn (``ab_servers``).  Wall
clock means little on a shared machine, so each interval of a thread is split by the kernel's
accounting of that thread (``/proc/thread-self/schedstat``): on a CPU, waiting for one (other
processes: the machine's load) and the rest, asleep (the GIL, the pool's queue).  Reported per
checkout: min and median of the F12's and raw's walls and of their ratio (each request's own), the
prepare's wall, the tiles' wall (from the end of ``prepare`` to the last tile) and the render
threads' sleep in their tiles summed; ``--timeline`` prints the intervals of the fastest F12 and raw.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import threading
import time
from pathlib import Path

from ab_servers import answer_requests, ask_in_turn

HERE = Path(__file__).resolve()


def _schedstat() -> tuple[float, float]:
    """(seconds on a CPU, seconds waiting for one) of the calling thread so far."""
    with open("/proc/thread-self/schedstat") as f:
        run, wait, _ = f.read().split()
    return int(run) * 1e-9, int(wait) * 1e-9


def _timed(label, func, events: list, label_of=None):
    """``func``, appending (thread, label, start, end, on CPU, waiting for a CPU) of each call to ``events``."""
    def timed(*args, **kwargs):
        t0, (r0, w0) = time.perf_counter(), _schedstat()
        try:
            return func(*args, **kwargs)
        finally:
            (r1, w1), t1 = _schedstat(), time.perf_counter()
            events.append((threading.current_thread().name, label if label_of is None else label_of(args),
                           t0, t1, r1 - r0, w1 - w0))
    return timed


def serve(repo: str, threads: int) -> None:
    sys.path[:0] = [repo + "/tests/bench", repo]
    import numpy as np
    from bench_build import raw_build, sphere_scene
    from bench_per_sample import _settings
    from bench_throughput import raw_batches, raw_primary

    from restframe_addon.core import frames, render
    from restframe_addon.core import prepared as prepared_module

    events: list = []
    prepare = _timed("prepare", prepared_module.prepare, events)
    frames._commit = _timed("BVH", frames._commit, events)
    render.render_tile = _timed("tile", render.render_tile, events, lambda args: "tile {} {}".format(*args[1][:2]))
    scene, settings = sphere_scene(512), _settings(1536, threads)
    prepared = prepared_module.prepare(scene, settings)
    geometry = prepared.frames.frames[-1].geometry
    vertices = (geometry.vertices - geometry.anchor).astype(np.float32)
    triangles = geometry.triangles.astype(np.int32)
    batches = raw_batches(prepared, prepared.tiles())
    build = _timed("raw build", raw_build, events)  # (its commit, the BVH, is the last of it)
    trace = _timed("raw trace", raw_primary, events)

    def f12():
        list(render.render_tiles(prepare(scene, settings), threads=threads))

    raw_bvh = []

    def raw(dealt: bool = False):
        """Raw: every ``threads``-th tile's rays on each thread, or ``dealt`` (bench_per_sample's)
        (each thread takes the next tile's rays as it is free, as the render's pool deals tiles)."""
        raw_bvh[:] = [build(vertices, triangles, True)]
        queue = iter(batches)
        dealt_trace = _timed("raw trace", lambda: sum(raw_primary([batch]) for batch in queue), events)
        workers = [threading.Thread(target=dealt_trace) if dealt else
                   threading.Thread(target=trace, args=(batches[i::threads],), name=f"raw-{i}") for i in range(threads)]
        for worker in workers:
            worker.start()
        for worker in workers:
            worker.join()

    def measured(work):
        events.clear()
        t0 = time.perf_counter()
        work()
        return time.perf_counter() - t0, [(e[0], e[1], e[2] - t0, e[3] - t0, e[4], e[5]) for e in events]

    def answer(_request):
        (f12_wall, f12_events), (raw_wall, raw_events) = measured(f12), measured(raw)
        dealt_wall, _ = measured(lambda: raw(dealt=True))
        tiles = [e for e in f12_events if e[1].startswith("tile")]
        prepare_end = next(e[3] for e in f12_events if e[1] == "prepare")
        bvh = next(e for e in f12_events if e[1] == "BVH")
        return {"F12": f12_wall, "raw": raw_wall, "ratio": f12_wall / raw_wall,
                "raw dealt": dealt_wall, "ratio to raw dealt": f12_wall / dealt_wall, "prepare": prepare_end,
                "prepare but BVH": prepare_end - (bvh[3] - bvh[2]), "BVH": bvh[3] - bvh[2],
                "raw build": next(e[3] - e[2] for e in raw_events if e[1] == "raw build"),
                "raw BVH": raw_bvh[0],
                "tiles": max(e[3] for e in tiles) - prepare_end,
                "tile sleep": sum(e[3] - e[2] - e[4] - e[5] for e in tiles),
                "tile cpu": sum(e[4] for e in tiles), "runq": sum(e[5] for e in f12_events),
                "events": {"F12": f12_events, "raw": raw_events}}

    f12(), raw()
    answer_requests(answer)


def timeline(events: list) -> list[str]:
    """One line per interval but the tiles, which are one line per thread (start+wall in ms each)."""
    lines = []
    for thread in sorted({e[0] for e in events}):
        mine = sorted((e for e in events if e[0] == thread), key=lambda e: e[2])
        tiles = [e for e in mine if e[1].startswith("tile")]
        for e in (e for e in mine if not e[1].startswith("tile")):
            lines.append(f"  {thread:>24} {e[1]:<10} {1e3 * e[2]:6.1f} .. {1e3 * e[3]:6.1f} ms: on CPU {1e3 * e[4]:5.1f}, "
                         f"waiting for one {1e3 * e[5]:4.1f}, asleep {1e3 * (e[3] - e[2] - e[4] - e[5]):4.1f}")
        if tiles:
            wall, cpu, runq = (sum(f(e) for e in tiles) for f in (lambda e: e[3] - e[2], lambda e: e[4], lambda e: e[5]))
            lines.append(f"  {thread:>24} {len(tiles)} tiles {1e3 * tiles[0][2]:6.1f} .. {1e3 * tiles[-1][3]:6.1f} ms: "
                         f"on CPU {1e3 * cpu:5.1f}, waiting for one {1e3 * runq:4.1f}, asleep {1e3 * (wall - cpu - runq):4.1f}")
            lines.append("      " + " ".join(f"({e[1][5:].replace(' ', ',')}) {1e3 * e[2]:.0f}+{1e3 * (e[3] - e[2]):.1f}"
                                             for e in tiles))
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("before", help="the checkout to compare against (a git worktree)")
    parser.add_argument("--after", default=str(HERE.parents[2]), help="default: this checkout")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--timeline", action="store_true")
    parser.add_argument("--serve", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve:
        serve(args.serve, args.threads)
        return 0
    command = lambda repo: [sys.executable, str(HERE), "-", "--serve", repo, "--threads", str(args.threads)]  # noqa: E731
    answers = ask_in_turn({name: (command(repo), None) for name, repo in (("before", args.before), ("after", args.after))},
                          args.repeats)
    print(f"primary-ray floor on {args.threads} threads, wall ms, {args.repeats} interleaved repeats (min / median)")
    print("| | before | after | after / before |\n|---|---|---|---|")
    for key in ("F12", "raw", "ratio", "raw dealt", "ratio to raw dealt", "prepare", "prepare but BVH", "BVH", "raw build", "raw BVH", "tiles", "tile sleep",
                "tile cpu", "runq"):
        scale, form = (1, "{:.2f}") if key.startswith("ratio") else (1e3, "{:.1f}")
        cells = []
        for name in ("before", "after"):
            values = [a[key] * scale for a in answers[name]]
            cells.append((min(values), statistics.median(values)))
        print(f"| {key} | " + " | ".join(f"{form.format(lo)} / {form.format(mid)}" for lo, mid in cells)
              + f" | {cells[1][0] / cells[0][0]:.2f} / {cells[1][1] / cells[0][1]:.2f} |")
    if args.timeline:
        for name in ("before", "after"):
            fastest = min(answers[name], key=lambda a: a["F12"])
            for kind in ("F12", "raw"):
                wall = fastest[kind]
                print(f"\n{name}: {kind} (the fastest F12's run), {1e3 * wall:.1f} ms")
                print("\n".join(timeline(fastest["events"][kind])))
    return 0


if __name__ == "__main__":
    sys.exit(main())

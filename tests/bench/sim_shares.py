"""How evenly N workers would finish moving_sphere with the shares core.workers deals them.

    tools/dev.sh tests/bench/sim_shares.py [--repeats 2] [--latency-ms 1] [--per-call-ms 1]

The machine has 2 cores, so the balance of 8 or 16 workers cannot be measured; it is simulated
from measured costs.  Each 8-row band of each tile (at the 16-worker tiling, 256x128) is rendered
once per repeat in this process (thread CPU, the minimum kept; the cheapest band is taken as a
render_tile call's fixed cost and taken off every band).  Then, for 2/4/8/16 workers, the
shares of ``workers.share_out`` (with ``_SHARES_PER_WORKER`` 2, 3, 4) are dealt as the render
loop deals them: two in flight a worker, one in the tail (``_Pace.tail``: at most ``tail`` shares
a worker left to deal; 0: never), a worker with nothing waiting ``--latency-ms`` for its next
share, each share costing its rows plus ``--per-call-ms``.  Efficiency = the ideal (work / N)
over the simulated end of the last share.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import heapq
import sys
import time
from pathlib import Path

sys.path[:0] = [str(Path(__file__).resolve().parent), str(Path(__file__).resolve().parents[2])]

BAND = 8  # rows per measured band


def row_costs(repeats: int) -> tuple[dict, float, object]:
    """CPU seconds of each pixel row of each 256-px column, {(x0, y): seconds}, the fixed cost of a
    call, and the prepared scene."""
    import restframe_addon
    from bench_parallel import export_blend
    from restframe_addon.core import blas, malloc
    from restframe_addon.core.prepared import prepare
    from restframe_addon.core.render import render_tile
    from restframe_addon.core.tracer import TraceCache

    restframe_addon.register()
    scene, settings = export_blend("moving_sphere.blend", (960, 540), 8, None)
    prepared = prepare(scene, dataclasses.replace(settings, threads=16))
    malloc.tune()
    bands, cache = {}, TraceCache()
    with blas.single_threaded():
        for _ in range(repeats):
            for rect in prepared.tiles():
                for y in range(rect[1], rect[3], BAND):
                    cpu = time.thread_time()
                    render_tile(prepared, rect, lambda: False, cache, (y, min(y + BAND, rect[3])))
                    key = (rect[0], y, min(y + BAND, rect[3]))
                    bands[key] = min(bands.get(key, float("inf")), time.thread_time() - cpu)
    fixed = min(bands.values())
    rows = {(x0, y): (seconds - fixed) / (y1 - y0) for (x0, y0, y1), seconds in bands.items() for y in range(y0, y1)}
    return rows, fixed, prepared


def finish(rects, shares, workers_count: int, rows: dict, per_call: float, latency: float, tail: int) -> float:
    """When the last share ends, dealt in order: two a worker, one a worker in the tail."""
    def cost(share):
        index, band = share
        x0, y0, _, y1 = rects[index]
        return per_call + sum(rows[(x0 - x0 % 256, y)] for y in range(*(band or (y0, y1))))

    todo = collections.deque(shares)
    held = [collections.deque() for _ in range(workers_count)]
    for _ in range(2):
        for queue in held:
            if todo:
                queue.append(todo.popleft())
    events = [(cost(queue[0]), k) for k, queue in enumerate(held) if queue]
    heapq.heapify(events)
    end = 0.0
    while events:
        now, k = heapq.heappop(events)
        end = max(end, now)
        held[k].popleft()
        start = now
        while todo and len(held[k]) < (1 if len(todo) <= tail * workers_count else 2):
            held[k].append(todo.popleft())
            if len(held[k]) == 1:  # it had nothing left: it waits for the deal
                start = now + latency
        if held[k]:
            heapq.heappush(events, (start + cost(held[k][0]), k))
    return end


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--latency-ms", type=float, default=1.0)
    parser.add_argument("--per-call-ms", type=float, default=1.0)
    args = parser.parse_args()
    from bench_parallel import tiles_on

    from restframe_addon.core import workers

    rows, fixed, prepared = row_costs(args.repeats)
    work = sum(rows.values())
    print(f"moving_sphere 960x540, 8 samples: {work:.3f} CPU s in rows, {fixed * 1e3:.2f} ms a call; "
          f"simulated with {args.per_call_ms} ms a share, {args.latency_ms} ms to deal a waiting worker\n")
    print("| shares a worker | tail (shares a worker) | " + " | ".join(f"{n} workers" for n in (2, 4, 8, 16)) + " |")
    print("|---|---|" + "---|" * 4)
    for per_worker in (2, 3, 4):
        workers._SHARES_PER_WORKER = per_worker
        for tail in (0, 2, 4):
            cells = []
            for count in (2, 4, 8, 16):
                rects = tiles_on(prepared, count)
                shares = workers.share_out(rects, count)
                end = finish(rects, shares, count, rows, args.per_call_ms / 1e3, args.latency_ms / 1e3, tail)
                cells.append(f"{work / count / end:.3f} ({len(shares)} shares)")
            print(f"| {per_worker} | {tail} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()

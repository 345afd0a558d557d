"""Before/after in one run: what the parent process spends on an F12 in worker processes (the
strict serial share of issue 20), each checkout in its own process, asked in turn (``ab_servers``).

    git worktree add /tmp/base origin/main
    tools/dev.sh tests/bench/ab_parent.py /tmp/base --scene bars --workers 1 --repeats 12

Each request is one F12 through the engine (``bpy.ops.render.render``, Parallelism Processes,
warm workers, the same scene each time); the answer is the render's ``RenderStats`` (this
process's CPU: the render loop, reading the workers' messages, the engine streaming tiles into
Blender's result) with the whole process's CPU and its voluntary context switches (wake-ups:
each costs this VM 60-250 us of CPU, docs/speed.md).  Milliseconds, min of the repeats.
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import time
from pathlib import Path

from ab_servers import answer_requests, ask_in_turn

HERE = Path(__file__).resolve()
SCENES = {"bars": ("bars_sideways.blend", None, None, 64), "moving_sphere": ("moving_sphere.blend", (960, 540), 8, None)}
FIELDS = ("parent_seconds", "loop_cpu", "receiving_cpu", "caller_cpu", "pickling", "sending")


def serve(repo: str, scene_name: str, workers_count: int) -> None:
    answers = os.fdopen(os.dup(1), "w")
    os.dup2(2, 1)  # whatever Blender prints goes to stderr, not into the answers
    sys.path[:0] = [repo + "/tests/bench", repo]
    import bpy
    from bench_parallel import export_blend

    import restframe_addon
    from restframe_addon.core import workers

    restframe_addon.register()
    blend, resolution, samples, tile_size = SCENES[scene_name]
    export_blend(blend, resolution, samples, tile_size)
    scene = bpy.context.scene
    if resolution is not None:
        (scene.render.resolution_x, scene.render.resolution_y), scene.render.resolution_percentage = resolution, 100
    scene.restframe.parallelism = 'PROCESSES'
    scene.render.threads_mode, scene.render.threads = 'FIXED', workers_count
    for _ in range(2):  # the workers started and warm
        bpy.ops.render.render(write_still=False)

    def answer(_request):
        usage, cpu = resource.getrusage(resource.RUSAGE_SELF), time.process_time()
        bpy.ops.render.render(write_still=False)
        stats, after = workers.pool().last_stats, resource.getrusage(resource.RUSAGE_SELF)
        out = {field: getattr(stats, field) * 1e3 for field in FIELDS}
        out.update(process_cpu=(time.process_time() - cpu) * 1e3, wakeups=after.ru_nvcsw - usage.ru_nvcsw,
                   shares=stats.shares)
        return out

    answer_requests(answer, answers)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("before", help="the checkout to compare against (a git worktree)")
    parser.add_argument("--after", default=str(HERE.parents[2]), help="default: this checkout")
    parser.add_argument("--scene", choices=SCENES, default="bars")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=12)
    parser.add_argument("--serve", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve:
        serve(args.serve, args.scene, args.workers)
        return 0
    argv = [sys.executable, str(HERE), "-", "--scene", args.scene, "--workers", str(args.workers), "--serve"]
    results = ask_in_turn({name: (argv + [repo], None) for name, repo in (("before", args.before),
                                                                          ("after", args.after))}, args.repeats)
    columns = FIELDS + ("process_cpu", "wakeups")
    print(f"{args.scene}, F12 in {args.workers} worker process(es), {results['after'][0]['shares']} shares; "
          f"min of {args.repeats} interleaved repeats, load average {os.getloadavg()[0]:.1f} at the end")
    print("| | " + " | ".join(f"{column} (ms)" if column != "wakeups" else column for column in columns) + " |")
    print("|---|" + "---|" * len(columns))
    for name in ("before", "after"):
        print(f"| {name} | " + " | ".join(f"{min(answer[column] for answer in results[name]):.2f}"
                                          for column in columns) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Before/after in one run for the 11x11 bars of ``bench_throughput.py --bars``, stage by stage: each
checkout renders the scene (``render_image``: prepare and render, 256x192, one thread) at one velocity
and at 11 velocities, interleaved, and reports CPU milliseconds (min of the repeats) of the render and
of the calls inside it: ``prepare``, the camera rays' ``trace_nearest``, ``Shader.radiance`` (all the
shading, with the next three inside it), its shadow rays (``occluded``), hit geometry
(``facing_normals``) and lamps' incident light (``Shader._incident``), and the passes (``pixel_passes``).

    git worktree add /tmp/base origin/main
    tools/dev.sh tests/bench/ab_bars_stages.py /tmp/base --repeats 20
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from ab_bars import VELOCITIES
from ab_cpu import _timed
from ab_servers import ask_each_in_turn

HERE = Path(__file__).resolve()
STAGES = (("render", "prepare"), ("shading", "trace_nearest"), ("shading", "Shader.radiance"), ("shading", "occluded"),
          ("shading", "facing_normals"), ("shading", "Shader._incident"), ("render", "pixel_passes"))


def serve(repo: str) -> None:
    sys.path[:0] = [repo + "/tests/bench", repo]
    from bench_throughput import bars_scene, settings

    from restframe_addon.core import render, shading

    totals: dict[str, float] = {}
    for module, name in STAGES:
        owner = {"render": render, "shading": shading}[module]
        *outer, attr = name.split(".")
        for part in outer:
            owner = getattr(owner, part)
        setattr(owner, attr, _timed(owner.__dict__[attr], attr, totals))
    s = settings((256, 192))
    scenes = {k: bars_scene(v) for k, v in VELOCITIES.items()}
    for scene in scenes.values():
        render.render_image(scene, s)
    print("ready", flush=True)
    for line in sys.stdin:
        totals.clear()
        t0 = time.process_time()
        render.render_image(scenes[line.strip()], s)
        totals["render"] = time.process_time() - t0
        print(json.dumps(totals), flush=True)


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
    names = ("before", "after")
    results = ask_each_in_turn({name: ([sys.executable, str(HERE), "-", "--serve", repo], None)
                                for name, repo in zip(names, (args.before, args.after))},
                               args.repeats, tuple(VELOCITIES))
    print(f"11x11 bars, 256x192, one thread, CPU ms (min of {args.repeats} interleaved repeats)")
    print("| | " + " | ".join(f"{name} {k} velocit{'y' if k == '1' else 'ies'}" for name in names for k in VELOCITIES)
          + " |\n|---|" + "---|" * (len(names) * len(VELOCITIES)))
    for key in results[("before", "1")][0]:
        print(f"| {key} | " + " | ".join(f"{min(t.get(key, 0.0) for t in results[(name, k)]) * 1e3:.2f}"
                                         for name in names for k in VELOCITIES) + " |")
    for name in names:
        one, many = (min(t["render"] for t in results[(name, k)]) for k in VELOCITIES)
        print(f"{name}: 11 / 1 = {many / one:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

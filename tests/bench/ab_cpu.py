"""Before/after in one run: two checkouts render the same .blend on one thread, interleaved, in CPU seconds.

    git worktree add /tmp/base origin/main
    tools/dev.sh tests/bench/ab_cpu.py /tmp/base                      # moving_sphere, 960x540, 8 samples
    tools/dev.sh tests/bench/ab_cpu.py /tmp/base --stages --repeats 7  # and the tracer's stages
    tools/dev.sh tests/bench/ab_cpu.py /tmp/base --scene floor         # the primary-ray floor's F12

Each checkout runs in its own process (a server that exports and prepares the scene once, then
renders on request); the driver asks them in turn, alternating the order, so both see the same
machine. Times are CPU seconds of the render (one thread: other work on a shared machine inflates
them less than wall time), min over the repeats. ``--stages`` adds the CPU time inside the tracer
calls of the shading, the hit geometry, the sample jitter, the camera rays, the boosts of rays into
other frames (``FrameMap.rays``, inside the tracer calls) and the pixel-centre rays' passes. ``--scene floor`` is
the primary-ray floor of ``bench_per_sample`` (261k-triangle sphere at (0.5, 0.2, 0) c, 1536^2, one
sample, no lights); it adds the F12's ``prepare`` and their sum, ``F12``.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

from ab_servers import answer_requests, ask_in_turn

HERE = Path(__file__).resolve()
SCENES = {"moving_sphere": ("moving_sphere.blend", (960, 540), 8), "bars": ("bars_sideways.blend", None, None),
          "floor": None}
STAGES = (("shading", "occluded"), ("shading", "trace_nearest"), ("shading", "facing_normals"),
          ("sampling", "stratified_offsets"), ("sampling", "stratified_positions"),
          ("prepared", "PreparedScene.sample_rays"), ("frames", "FrameMap.rays"), ("render", "pixel_passes"))
LABELS = {"stratified_positions": "stratified_offsets"}  # the sample jitter, whichever of the two a checkout calls


def serve(repo: str, scene: str, stages: bool) -> None:
    sys.path[:0] = [repo + "/tests/bench", repo]
    from bench_parallel import export_blend

    import restframe_addon
    from restframe_addon.core import frames, prepared, render, sampling, shading
    from restframe_addon.core.render import render_tiles

    restframe_addon.register()
    if scene == "floor":
        from bench_build import sphere_scene
        from bench_per_sample import _settings

        core_scene, settings = sphere_scene(512), _settings(1536, 1)
    else:
        blend, resolution, samples = SCENES[scene]
        core_scene, settings = export_blend(blend, resolution, samples, None)
    settings = dataclasses.replace(settings, parallelism="THREADS", threads=1)
    prep = prepared.prepare(core_scene, settings)
    totals: dict[str, float] = {}
    modules = {"shading": shading, "sampling": sampling, "prepared": prepared, "frames": frames, "render": render}
    for module, name in STAGES if stages else ():
        owner = modules[module]
        *outer, attr = name.split(".")
        for part in outer:
            owner = getattr(owner, part)
        if attr in owner.__dict__:  # (an older checkout may lack it)
            setattr(owner, attr, _timed(owner.__dict__[attr], LABELS.get(attr, attr), totals))
    list(render_tiles(prep, threads=1))

    def answer(_request):
        totals.clear()
        t0 = time.process_time()
        list(render_tiles(prep, threads=1))
        totals["render"] = time.process_time() - t0
        if scene == "floor":
            t0 = time.process_time()
            prepared.prepare(core_scene, settings)
            totals["prepare"] = time.process_time() - t0
            totals["F12"] = totals["render"] + totals["prepare"]
        return totals

    answer_requests(answer)


def _timed(func, name, totals):
    def timed(*args, **kwargs):
        t0 = time.process_time()
        try:
            return func(*args, **kwargs)
        finally:
            totals[name] = totals.get(name, 0.0) + time.process_time() - t0
    return timed


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("before", help="the checkout to compare against (a git worktree)")
    parser.add_argument("--after", default=str(HERE.parents[2]), help="default: this checkout")
    parser.add_argument("--scene", default="moving_sphere", choices=sorted(SCENES))
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--stages", action="store_true")
    parser.add_argument("--serve", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve:
        serve(args.serve, args.scene, args.stages)
        return 0
    command = lambda repo: [sys.executable, str(HERE), "-", "--serve", repo, "--scene", args.scene] + (  # noqa: E731
        ["--stages"] * args.stages)
    times = ask_in_turn({name: (command(repo), None) for name, repo in (("before", args.before), ("after", args.after))},
                        args.repeats)
    print(f"{args.scene}, one thread, CPU seconds, min of {args.repeats} interleaved repeats")
    print("| | before | after | after / before |\n|---|---|---|---|")
    for key in times["before"][0]:
        before, after = (min(t[key] for t in times[name]) for name in ("before", "after"))
        print(f"| {key} | {before:.3f} | {after:.3f} | {after / before:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The path tracer's CPU time per sample on section 7's Cornell box, before/after in one run.

    git worktree add /tmp/base origin/main
    tools/dev.sh tests/bench/ab_path.py /tmp/base                  # base against this checkout, interleaved
    tools/dev.sh tests/bench/ab_path.py --samples 16 --repeats 5   # this checkout alone
    tools/dev.sh tests/bench/ab_path.py --profile                  # and where the time goes (cProfile)

The scene is ``tests/blender/test_blender_path.cornell_box`` (32 x 32 px, 4 bounces of every
kind, no clamping, as ``bench_path_cycles``), exported once per checkout in its own process and
rendered on one thread on request; the driver asks the checkouts in turn, alternating the order.
Times are CPU seconds of ``render_tiles`` (min over the repeats) per sample per pixel.  With
``--noise`` each checkout also renders a reference of REFERENCE samples and reports the relative
RMSE of its renders against it (``bench_common.rel_rmse``, as section 7): time x error^2 is
what the time to equal noise compares.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

from ab_servers import answer_requests, ask_in_turn

HERE = Path(__file__).resolve()
SIZE, BOUNCES, REFERENCE = 32, 4, 1024


def prepared_cornell_box(repo: str, samples: int):
    """The Cornell box of ``repo`` exported and prepared for one thread at ``samples`` per pixel."""
    sys.path[:0] = [repo, repo + "/tests/blender"]
    import test_blender_path as path_tests
    from blender_helpers import export_now

    import restframe_addon
    from restframe_addon.core import prepared

    assert Path(restframe_addon.__file__).is_relative_to(Path(repo).resolve()), restframe_addon.__file__
    restframe_addon.register()
    scene = path_tests.cornell_box()
    scene.render.resolution_x = scene.render.resolution_y = SIZE
    scene.render.resolution_percentage = 100
    scene.render.engine = 'RESTFRAME'
    rf = scene.restframe
    rf.integrator, rf.samples = 'PATH', samples
    rf.max_bounces = rf.diffuse_bounces = rf.glossy_bounces = rf.transmission_bounces = BOUNCES
    rf.clamp_direct = rf.clamp_indirect = 0.0
    core_scene, settings, _ = export_now(scene)
    return core_scene, settings, prepared


def image_of(tiles) -> np.ndarray:
    """The Combined pass of rendered tiles as one (H, W, C) image."""
    image = np.zeros((SIZE, SIZE, 4))
    for tile in tiles:
        image[tile.y0:tile.y1, tile.x0:tile.x1] = tile.passes["Combined"]
    return image[..., :3]


def serve(repo: str, samples: int, noise: bool) -> None:
    """Render on request (a line on stdin), print the CPU seconds (and the error against the
    checkout's own reference with ``noise``) as JSON."""
    core_scene, settings, prepared = prepared_cornell_box(repo, samples)
    from bench_common import rel_rmse  # (after the checkout's own restframe_addon is imported)
    from restframe_addon.core.render import render_tiles

    def render(spp):
        prep = prepared.prepare(core_scene, dataclasses.replace(settings, samples=spp, parallelism="THREADS",
                                                                threads=1))
        t0 = time.process_time()
        tiles = list(render_tiles(prep, threads=1))
        return time.process_time() - t0, image_of(tiles)

    reference = render(REFERENCE)[1] if noise else None
    render(1)  # warm

    def answer(_request):
        seconds, image = render(samples)
        out = {"seconds": seconds}
        if reference is not None:
            out["rmse"] = rel_rmse(image, reference)
        return out

    answer_requests(answer)


def profile(samples: int) -> None:
    import cProfile
    import pstats

    core_scene, settings, prepared = prepared_cornell_box(str(HERE.parents[2]), samples)
    from restframe_addon.core.render import render_tiles

    prep = prepared.prepare(core_scene, dataclasses.replace(settings, parallelism="THREADS", threads=1))
    list(render_tiles(prep, threads=1))
    profiler = cProfile.Profile(time.process_time)
    profiler.enable()
    list(render_tiles(prep, threads=1))
    profiler.disable()
    pstats.Stats(profiler).sort_stats("tottime").print_stats(35)
    pstats.Stats(profiler).sort_stats("cumulative").print_stats(40)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("base", nargs="?", help="another checkout to compare with (interleaved)")
    parser.add_argument("--samples", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--noise", action="store_true", help=f"also the error against {REFERENCE} samples")
    parser.add_argument("--profile", action="store_true")
    parser.add_argument("--serve", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve:
        return serve(args.serve, args.samples, args.noise)
    if args.profile:
        return profile(args.samples)
    repos = {"this": str(HERE.parents[2])}
    if args.base:
        repos = {"base": str(Path(args.base).resolve()), **repos}
    command = lambda repo: [sys.executable, str(HERE), "--serve", repo, "--samples",  # noqa: E731
                            str(args.samples)] + ["--noise"] * args.noise
    results = ask_in_turn({name: (command(repo), repo) for name, repo in repos.items()}, args.repeats)
    pixels = SIZE * SIZE
    for name, runs in results.items():
        best = min(run["seconds"] for run in runs)
        line = f"{name}: {best:.3f} CPU s for {args.samples} spp = {1e6 * best / args.samples / pixels:.2f} us " \
               f"per sample per pixel (min of {len(runs)})"
        if args.noise:
            rmse = runs[0]["rmse"]
            line += f"; rel. RMSE {rmse:.4f}, time x error^2 {best * rmse ** 2:.3g}"
        print(line)


if __name__ == "__main__":
    main()

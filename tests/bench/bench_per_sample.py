"""Per-sample cost against the raw Embree time of the render's own queries, and the primary-ray floor (issue 20).

    tools/dev.sh tests/bench/bench_per_sample.py            # this section alone, printed (Markdown)
    tools/dev.sh tests/bench/bench_per_sample.py --smoke    # tiny sizes
    tools/dev.sh tests/bench/bench_per_sample.py --only floor   # one part: "queries" or "floor"

**Own queries**: `sample_blends/moving_sphere.blend` rendered on one core (threads=1; and in one
worker process). Every Embree call the render makes is recorded (the exact float32 origins,
directions and lengths handed to `embree.run`, the query kind, the geometry frame) and replayed
through raw embreex on the same built scenes: render / replay is what the numpy code around
Embree costs (goal <= 3). The breakdown times the render's stages with timers wrapped around them
(exclusive times: embree inside the shadow rays is counted as embree).

**Primary-ray floor**: a 261k-triangle UV sphere at (0.5, 0.2, 0) c, 1536x1536, one sample, no
lights. **F12** = `prepare` + `render_tiles` with the passes of a new Blender scene's view layer
(Combined, Depth and RESTframe's own Doppler, Emission Time, Object Time); **raw** = Embree's build of the same
float32 triangles (`bench_build.raw_build`, one geometry filled by memory copies) + `embree.run` of the
same pixel-centre rays, already mapped into the sphere's frame and in float32
(`bench_throughput.raw_batches`), on the same cores (goal <= 1.25).
"""

from __future__ import annotations

import dataclasses
import os
import sys
import threading
import time

import numpy as np

from bench_common import (Context, Goal, Section, cpu_interleaved, fmt, load, print_section, register_addon, settings,
                          standalone_context, wall_interleaved)
from bench_build import raw_build, sphere_scene
from bench_parallel import cpu_seconds, export_blend
from bench_throughput import raw_batches, raw_primary
from restframe_addon.core import prepared as prepared_module
from restframe_addon.core import sampling, shading
from restframe_addon.core.passes import PASSES
from restframe_addon.core.prepared import prepare
from restframe_addon.core.render import render_tiles

RENDER_GOAL = 3.0  # moving_sphere on one core at most this many times the raw Embree time of its queries
FLOOR_GOAL = 1.25  # F12 of primary rays at most this many times raw Embree build + trace


# --------------------------------------------------------------------------- recording embree's calls
class RecordingScene:
    """Stands in for a geometry's embree scene: hands every call on and keeps its arguments."""

    def __init__(self, scene, calls: list, probe=None):
        self.scene, self.calls, self.probe = scene, calls, probe

    def run(self, origins, directions, dists=None, query="INTERSECT", output=None):
        if self.calls is not None:
            self.calls.append((self.scene, origins.copy(), directions.copy(), None if dists is None else dists.copy(),
                               query, output))
        if self.probe is None:
            return self.scene.run(origins, directions, dists=dists, query=query, output=output)
        with self.probe.stage("embree"):
            return self.scene.run(origins, directions, dists=dists, query=query, output=output)


def geometries(prepared):
    return [frame.geometry for frame in prepared.frames.frames if frame.geometry is not None]


def record_queries(prepared) -> list:
    """Every embree call of one render of ``prepared`` (one thread), in order."""
    calls = []
    originals = [(g, g.embree) for g in geometries(prepared)]
    try:
        for g, scene in originals:
            g.embree = RecordingScene(scene, calls)
        list(render_tiles(prepared, threads=1))
    finally:
        for g, scene in originals:
            g.embree = scene
    return calls


def replay(calls) -> int:
    hit = 0
    for scene, o, d, dists, query, output in calls:
        result = scene.run(o, d, dists=dists, query=query, output=output)
        hit += int(np.count_nonzero((result["primID"] if output else result) >= 0))
    return hit


# --------------------------------------------------------------------------- the breakdown
class Probe:
    """Exclusive time per stage: wrappers around the render's stages charge the time since the
    last mark to the innermost stage running."""

    def __init__(self):
        self.totals: dict[str, float] = {}
        self.stack = ["other"]
        self.mark = time.process_time()

    def _charge(self):
        now = time.process_time()
        self.totals[self.stack[-1]] = self.totals.get(self.stack[-1], 0.0) + now - self.mark
        self.mark = now

    def stage(self, name):
        probe = self

        class Stage:
            def __enter__(self):
                probe._charge()
                probe.stack.append(name)

            def __exit__(self, *exc):
                probe._charge()
                probe.stack.pop()

        return Stage()

    def wrap(self, name, func):
        def wrapped(*args, **kwargs):
            with self.stage(name):
                return func(*args, **kwargs)
        return wrapped


STAGES = (  # (stage, where it is wrapped, attribute): what each stage of the breakdown holds
    ("camera rays", prepared_module.PreparedScene, "sample_rays"),
    ("camera rays", sampling, "stratified_offsets"),
    ("camera rays", sampling, "stratified_positions"),  # (render_tile's jitter)
    ("camera rays", sampling, "strata_starts"),
    ("camera rays", sampling, "block_keys"),  # (render_tile's jitter's hash, kept for the lamps' numbers)
    ("hit bookkeeping", shading, "trace_nearest"),
    ("shadow-ray bookkeeping", shading, "occluded"),
    ("hit geometry", shading, "facing_normals"),
    ("shading", shading.Shader, "radiance"),
)


def breakdown(prepared) -> dict[str, float]:
    """CPU seconds per stage of one render on one thread (timers add a few calls per batch)."""
    probe = Probe()
    saved = [(owner, attr, owner.__dict__[attr]) for _, owner, attr in STAGES]
    embrees = [(g, g.embree) for g in geometries(prepared)]
    try:
        for name, owner, attr in STAGES:
            setattr(owner, attr, probe.wrap(name, owner.__dict__[attr]))
        for g, scene in embrees:
            g.embree = RecordingScene(scene, None, probe)
        probe.mark = time.process_time()
        list(render_tiles(prepared, threads=1))
        probe._charge()
    finally:
        for owner, attr, value in saved:
            setattr(owner, attr, value)
        for g, scene in embrees:
            g.embree = scene
    return probe.totals


def one_worker(prepared, repeats: int) -> float | None:
    """CPU seconds (parent + worker) of the render in one worker process (min of repeats), None
    where workers cannot start."""
    from restframe_addon.core import workers

    pool = workers.WorkerPool()
    try:
        warnings = []
        list(pool.render(prepared, lambda: False, 1, warnings.append))
        if warnings or not pool.pids:
            return None
        best = float("inf")
        for _ in range(repeats):
            c0 = cpu_seconds(pool.pids)
            list(pool.render(prepared, lambda: False, 1))
            best = min(best, cpu_seconds(pool.pids) - c0)
        return best
    finally:
        pool.close()


def own_queries(ctx: Context, sec: Section) -> None:
    resolution, samples = ctx.pick(((960, 540), 8), ((96, 54), 2))
    repeats = ctx.pick(3, 1)
    scene, settings = export_blend("moving_sphere.blend", resolution, samples, None)
    settings = dataclasses.replace(settings, parallelism="THREADS", threads=1)
    prepared = prepare(scene, settings)
    calls = record_queries(prepared)
    camera_rays = sum(len(c[1]) for c in calls if c[4] != "OCCLUDED")
    shadow_rays = sum(len(c[1]) for c in calls if c[4] == "OCCLUDED")
    t = cpu_interleaved({"render": lambda: list(render_tiles(prepared, threads=1)),
                         "replay": lambda: replay(calls)}, repeats)
    stages = min((breakdown(prepared) for _ in range(repeats)), key=lambda s: sum(s.values()))
    worker = one_worker(prepared, repeats)
    n = resolution[0] * resolution[1] * samples
    ratio = t["render"] / t["replay"]
    sec.number("render_over_replay", ratio)
    sec.number("per_sample_us", t["render"] / n * 1e6)
    sec.number("replay_per_sample_us", t["replay"] / n * 1e6)
    ctx.log(f"  moving_sphere: render {t['render']:.2f} s, replay {t['replay']:.2f} s, ratio {ratio:.2f}")
    sec.add(f"### moving_sphere, {resolution[0]}x{resolution[1]}, {samples} samples, one core")
    sec.add("")
    sec.add(f"{fmt(n)} samples; the render made {len(calls)} embree calls: {fmt(camera_rays)} intersection rays "
            f"and {fmt(shadow_rays)} occlusion rays. CPU seconds, min of {repeats} interleaved repeats, load "
            f"average {load():.2f}.")
    sec.add("")
    rows = [["render, one thread", t["render"], t["render"] / n * 1e6, ratio],
            ["replay of its embree calls (raw embreex)", t["replay"], t["replay"] / n * 1e6, 1.0]]
    if worker is not None:
        sec.number("worker_over_replay", worker / t["replay"])
        rows.insert(1, ["render, one worker process (parent + worker CPU)", worker, worker / n * 1e6,
                        worker / t["replay"]])
    sec.table(["", "CPU (s)", "per sample (us)", "/ replay"], rows)
    total = sum(stages.values())
    sec.add("Where a sample's time goes (timers around the stages, one render; exclusive times, "
            f"{total:.2f} CPU s in all):")
    sec.add("")
    order = ["shading", "hit geometry", "shadow-ray bookkeeping", "hit bookkeeping", "camera rays", "embree", "other"]
    sec.table(["stage", "CPU (s)", "per sample (us)", "share"],
              [[name, stages.get(name, 0.0), stages.get(name, 0.0) / n * 1e6, f"{100 * stages.get(name, 0.0) / total:.0f}%"]
               for name in order])
    for name in order:
        sec.number(f"stage_{name.replace(' ', '_').replace('-', '_')}_us", stages.get(name, 0.0) / n * 1e6)
    sec.add("**shading** = `Shader.radiance` but for the stages below it; **hit geometry** = positions and "
            "normals of hits (`facing_normals`); **shadow-ray bookkeeping** = `tracer.occluded` (frame maps, "
            "culling, float32 conversion); **hit bookkeeping** = `trace_nearest` of the camera rays (frame maps, "
            "bounds clipping, nearest-hit merge); **camera rays** = sample positions and rays; **other** = tile "
            "set-up, the passes of the pixel-centre rays, accumulation.")
    sec.add("")
    sec.goals.append(Goal("moving_sphere, one core: render / raw Embree replay of its own queries",
                          f"<= {RENDER_GOAL:g}", f"{ratio:.2f} ({t['render'] / n * 1e6:.2f} us per sample)",
                          ratio <= RENDER_GOAL))


# --------------------------------------------------------------------------- the primary-ray floor
def raw_floor(vertices, triangles, batches, threads: int) -> None:
    """Embree's build of the triangles, then the rays traced on ``threads`` threads, each taking
    the next tile's rays as it comes free, as the render's pool deals its tiles.  (Every
    ``threads``-th tile to each thread, as before session 8, gave one thread every tile of the
    sphere's first column: its trace ran 14-46 ms past the other's, a raw wall longer than a
    balanced trace's, which flattered the F12's ratio.)"""
    raw_build(vertices, triangles, direct=True)
    if threads == 1:
        raw_primary(batches)
        return
    queue = iter(batches)  # a list iterator's next is atomic under the GIL: each tile once
    workers = [threading.Thread(target=lambda: sum(raw_primary([batch]) for batch in queue)) for _ in range(threads)]
    for worker in workers:
        worker.start()
    for worker in workers:
        worker.join()


def primary_floor(ctx: Context, sec: Section) -> None:
    segments, size = ctx.pick((512, 1536), (32, 64))
    repeats = ctx.pick(3, 1)
    cores = os.cpu_count() or 1
    scene = sphere_scene(segments)
    rows = []
    ratios = {}
    for threads in sorted({1, cores}):
        settings = _settings(size, threads)
        prepared = prepare(scene, settings)
        geometry = prepared.frames.frames[-1].geometry
        vertices = (geometry.vertices - geometry.anchor).astype(np.float32)
        triangles = geometry.triangles.astype(np.int32)
        batches = raw_batches(prepared, prepared.tiles())
        funcs = {"F12": lambda: list(render_tiles(prepare(scene, settings), threads=threads)),
                 "raw": lambda: raw_floor(vertices, triangles, batches, threads)}
        t = cpu_interleaved(funcs, repeats) if threads == 1 else wall_interleaved(funcs, repeats)
        ratio = ratios[threads] = t["F12"] / t["raw"]
        sec.number(f"floor_ratio_{threads}", ratio)
        rows.append([f"{threads} ({'CPU s' if threads == 1 else 'wall s'})", t["F12"], t["raw"], ratio])
        ctx.log(f"  floor, {threads} thread(s): F12 {t['F12']:.2f} s, raw {t['raw']:.2f} s, ratio {ratio:.2f}")
    sec.add(f"### Primary-ray floor: {fmt(len(triangles))} triangles at (0.5, 0.2, 0) c, {size}x{size}, one sample, "
            "no lights")
    sec.add("")
    sec.add(f"Min of {repeats} interleaved repeats; one thread in CPU seconds, {cores} threads (the machine's "
            f"cores) in wall seconds, load average {load():.2f}.")
    sec.add("")
    sec.table(["threads", "F12 (s)", "raw build + trace (s)", "F12 / raw"], rows)
    for threads, ratio in ratios.items():
        sec.goals.append(Goal(f"primary rays, 261k triangles, 1536^2, {threads} thread{'s' if threads > 1 else ''}: "
                              "F12 / raw Embree build + trace", f"<= {FLOOR_GOAL:g}", f"{ratio:.2f}",
                              ratio <= FLOOR_GOAL))


def _settings(size: int, threads: int):
    """An F12 of a new Blender scene's view layer: Combined, Depth and RESTframe's own passes."""
    return settings((size, size), samples=1, threads=threads, parallelism="THREADS", passes=("Depth", *PASSES))


PARTS = ("queries", "floor")  # the parts of the section, each runnable alone (--only)


def run(ctx: Context, parts=PARTS) -> Section:
    register_addon()  # the .blend export needs the add-on's properties
    sec = Section("9. Per-sample cost and the primary-ray floor")
    sec.add(" ".join(__doc__.split("\n\n", 2)[2].split("\n\n")[0].split()))
    sec.add("")
    sec.add(" ".join(__doc__.split("\n\n", 2)[2].split("\n\n")[1].split()))
    sec.add("")
    if "queries" in parts:
        own_queries(ctx, sec)
    if "floor" in parts:
        primary_floor(ctx, sec)
    return sec


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--smoke", action="store_true", help="tiny sizes")
    parser.add_argument("--only", choices=PARTS, help="run one part of the section")
    args = parser.parse_args()
    print_section(run(standalone_context(args.smoke), (args.only,) if args.only else PARTS))

"""Scaling from one core to two: threads against worker processes (core.workers).

    tools/dev.sh tests/bench/bench_parallel.py [--repeats N] [--quick] [--checkout DIR]   # printed (Markdown)
    tools/dev.sh tests/bench/run.py --only 10 --out FILE                                   # section 10 of the report

Each scene is exported from its .blend and prepared once; every timed thread render then
renders a fresh copy of the prepared scene (a pickle round trip, untimed).  A timed process
render goes as an F12 goes: a fresh copy of the scene and settings is built ahead in the
workers (``WorkerPool.build_ahead``) while this process prepares it (untimed, as for threads),
then rendered, so it pays what an F12 pays after its prepare: pickling the scene, sending
it, and whatever is left of the workers' build by then.  As in a session's second F12 of an
unchanged scene, the copy's arrays are the same bytes as the last render's: its file names them
in the last scene's files instead of holding them (``WorkerPool._scene_files``); the strict rows
also give F12s that write every array again.  The workers are started before timing (they stay warm across renders; their start-up is reported
on its own).  CPU seconds (this process and its workers, Linux) are given next to the wall
times: unlike those, they do not grow when other work takes the cores.  Variants run interleaved in one process, rotating their order each repeat, with
the load average noted: the machine may be shared.  Run alone, it prints the section as Markdown.

From each process render's ``RenderStats`` (when each share of the image ran in which worker,
and what this process spent) it also reports the balance of two workers (busy and idle time
per worker) and the serial work on the render's critical path: pickling and sending the
scene, a worker rebuilding it (whole, for a render without build ahead; as an F12 renders,
only the part of it the render waited for, measured cold on a fresh worker and warm), this
process dealing and handling the workers' messages, and, from one F12 through Blender, the
engine streaming each tile into Blender's result.  The
Amdahl projection to 8 and 16 cores rests on that measured serial time.  Two independent
one-worker renders at once give the machine's own scaling from one busy core to two (shared
caches, memory bandwidth, clocks, or vCPUs that share a core): the ceiling for processes x2.

Goals (issue 20): processes x2 at least 1.9x processes x1 on each scene, shown next to the machine's
own two-process scaling of the same run (below 1.9, the machine is the limit, not the renderer);
and the strict projection (everything this process does for a render counted as serial) at least 12x
on 16 cores, the worse of the first F12 (cold) and a warm one, with this process's CPU measured in
renders on 16 worker processes (the least of three F12s; their tiles and shares; the engine's
streaming of those tiles fitted from two F12s through Blender).  The rows scaled from one worker's
costs per share and per tile are kept beside it: they count the loop's cost per render (its
results image, the first deal) again for every share, an upper bound.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import pickle
import sys
import threading
import time
import weakref
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
OTHER_CHECKOUT = __name__ == "__main__" and "--checkout" in sys.argv
if OTHER_CHECKOUT:  # the renderer of another checkout (a git worktree)
    ROOT = Path(sys.argv[sys.argv.index("--checkout") + 1]).resolve()
sys.path.insert(0, str(ROOT))
import restframe_addon  # noqa: E402,F401  (this checkout's, before bench_common puts the suite's own on the path)

from bench_common import Context, Goal, Section, print_section, register_addon, standalone_context  # noqa: E402

if OTHER_CHECKOUT:  # the worker processes boot with this process's sys.path, on which bench_common has put
    sys.path.remove(str(ROOT))  # the suite's own checkout first: ROOT first again, so that they too run its code
    sys.path.insert(0, str(ROOT))

SCENES = {  # name: (.blend, resolution or None for the file's, samples or None, tile size or None)
    "moving_sphere": ("moving_sphere.blend", (960, 540), 8, None),
    "bars_sideways (11x11 bars, 11 velocities)": ("bars_sideways.blend", None, None, 64),
}
# times the repeats of a scene whose render is short: the bars' 0.1-0.2 s renders, where one load
# spike moved the least of 3 by 10% (malloc17, docs/speed.md)
REPEAT_FACTOR = {"bars_sideways": 3}


def export_blend(blend: str, resolution, samples, tile_size):
    import bpy

    from restframe_addon import export

    bpy.ops.wm.open_mainfile(filepath=str(ROOT / "sample_blends" / blend), load_ui=False)
    scene = bpy.context.scene
    scene.render.engine = 'RESTFRAME'
    if samples is not None:
        scene.restframe.samples = samples
    if tile_size is not None:
        scene.restframe.tile_size = tile_size
    core_scene, settings = export.export_scene(bpy.context.evaluated_depsgraph_get(), resolution=resolution,
                                               warn=lambda message: None)
    return core_scene, settings


def cpu_seconds(pids) -> float:
    """User + system CPU time of this process and the processes ``pids`` so far (Linux)."""
    total = sum(os.times()[:2])
    ticks = os.sysconf("SC_CLK_TCK")
    for pid in pids:
        with open(f"/proc/{pid}/stat") as stat:
            fields = stat.read().rsplit(")", 1)[1].split()
        total += (int(fields[11]) + int(fields[12])) / ticks
    return total


def peak_rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as status:
        for line in status:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def balance(stats) -> list[dict]:
    """Per worker of a process render: shares, busy seconds (rendering shares), idle seconds
    (the render's wall time less busy) and when its first share started and its last ended,
    from the render's start."""
    rows = []
    for pid, shares in sorted(stats.rendered.items()):
        busy = sum(end - start for _, _, start, end, _ in shares)
        rows.append({"pid": pid, "shares": len(shares), "pixels": sum(s[1] for s in shares), "busy": busy,
                     "cpu": sum(s[4] for s in shares), "idle": stats.ended - stats.started - busy,
                     "first": min(s[2] for s in shares) - stats.started,
                     "last": max(s[3] for s in shares) - stats.started})
    return rows


def serial_seconds(stats, rebuild: float, streaming_per_tile: float, tiles: int) -> dict:
    """The render's serial work, as measured (CPU seconds, which the machine's load does not
    inflate): what no added core shortens.  This process's loop and unpickling run beside the
    workers but are counted whole (an upper bound: on a machine whose every core runs a worker
    they take a core's time)."""
    return {"pickling": stats.pickling, "sending": stats.sending, "rebuild in a worker": rebuild,
            "parent loop": stats.loop_cpu, "reader threads (the workers' messages)": stats.receiving_cpu,
            "streaming into Blender's result": streaming_per_tile * tiles}


# pool -> the geometry cache this process prepares its renders with (it goes with its pool: the
# scene report's cold pool's, with its built geometry, once that pool is gone)
PARENT_CACHES = weakref.WeakKeyDictionary()


def f12_prepared(pool, count: int, source):
    """A fresh copy of the exported scene and settings ``source``, built ahead in the pool's
    workers while this process prepares it, as the engine does for an F12 (with Persistent
    Data: this process too reuses the geometry it built for the pool's last render, so its
    prepare is no longer than it is in an animation); and the CPU seconds of that prepare."""
    from restframe_addon.core.persistent import GeometryCache
    from restframe_addon.core.prepared import prepare

    scene, settings = pickle.loads(pickle.dumps(source))
    pool.build_ahead(scene, settings, count)
    cpu = time.thread_time()
    prepared = prepare(scene, settings, geometry_cache=PARENT_CACHES.setdefault(pool, GeometryCache()))
    return prepared, time.thread_time() - cpu


def build_wait(stats, preparing: float) -> tuple[float, float]:
    """What a render built ahead waited for its workers' build: (CPU, wall) seconds.  CPU: the
    build's CPU beyond the CPU this process spent preparing meanwhile (what a machine with a
    free core per process would wait, load or not); wall: as measured here, from the render's
    start to the end of the last build (0 when they were built before it began)."""
    cpu = max([build_cpu - preparing for _, _, build_cpu in stats.builds.values()] + [0.0])
    return cpu, max([ended - stats.started for _, ended, _ in stats.builds.values()] + [0.0])


def amdahl(serial: float, work: float, cores: int) -> float:
    return (serial + work) / (serial + work / cores)


def tiles_on(prepared, workers_count: int) -> list[tuple[int, int, int, int]]:
    """The tiles of a render of ``prepared`` on ``workers_count`` workers (PreparedScene.tiles:
    halved while fewer than the workers)."""
    return dataclasses.replace(prepared, settings=dataclasses.replace(prepared.settings,
                                                                      threads=workers_count)).tiles()


def tiles_and_shares(prepared, workers_count: int) -> tuple[int, int]:
    """The tiles and shares a render of ``prepared`` has with ``workers_count`` workers: the
    tiles are halved while fewer than the workers, and the shares cut them in bands."""
    from restframe_addon.core import workers

    rects = tiles_on(prepared, workers_count)
    return len(rects), len(workers.share_out(rects, workers_count))


def engine_streaming(blend, resolution, samples, tile_size) -> tuple[float, int]:
    """One F12 through Blender's render engine in worker processes: seconds the engine spent
    streaming tiles into Blender's result (RenderStats.caller_cpu: CPU seconds, which the
    machine's load does not inflate as it does the wall time), and the tile count."""
    import bpy

    from restframe_addon.core import workers

    export_blend(blend, resolution, samples, tile_size)
    scene = bpy.context.scene
    if resolution is not None:
        (scene.render.resolution_x, scene.render.resolution_y), scene.render.resolution_percentage = resolution, 100
    scene.restframe.parallelism = 'PROCESSES'
    bpy.ops.render.render(write_still=False)
    stats = workers.pool().last_stats
    return stats.caller_cpu, len({share[0] for shares in stats.rendered.values() for share in shares})


def streaming_for_tiles(measured):
    """The engine's streaming CPU as a function of the tile count, fitted to F12s of one image at
    two tile sizes, ``measured`` = ((seconds, tiles), (seconds, tiles)): a cost per tile (Blender's
    begin_result / end_result) plus one for the image's pixels (foreach_set: the same pixels for
    any tiling).  Where the fit is not positive (noise) the first F12's cost per tile is scaled
    by the tiles, which counts its pixels again for every added tile (an upper bound)."""
    (first, first_tiles), (second, second_tiles) = measured
    if second_tiles != first_tiles:
        per_tile = (second - first) / (second_tiles - first_tiles)
        per_image = first - per_tile * first_tiles
        if per_tile > 0 and per_image >= 0:
            return lambda tiles: per_image + per_tile * tiles
    return lambda tiles: first / first_tiles * tiles


TWO_CORES_GOAL = 1.9  # two cores at least this many times one core (worker processes)
MEASURED_WORKERS = 16  # the worker processes of the measured strict rows (the projection's cores)
# F12s on them whose least parent CPU the measured rows count: one moved 12-33 ms for moving_sphere
# between runs of the same code (serial17, docs/speed.md), 3 of them 13-17 ms
MEASURED_RENDERS = 3
PROJECTION_GOAL = 12.0  # the strict serial share projects at least this many times on 16 cores


def scene_report(sec: Section, name: str, spec, pools: dict, repeats: int, quick: bool) -> None:
    """One scene's part of the section: threads and processes 1 vs 2, the machine's own two-process
    scaling, the balance of two workers, the serial work and the 8/16-core projections, with its goals."""
    from restframe_addon.core import workers
    from restframe_addon.core.prepared import prepare
    from restframe_addon.core.render import render_tiles

    tuned, untuned, twin = pools["tuned"], pools["untuned"], pools["twin"]
    blend, resolution, samples, tile_size = spec
    short = name.split(" (")[0]
    key = short.split("_")[0]  # the numbers' prefix: "moving", "bars"
    repeats *= REPEAT_FACTOR.get(short, 1)
    if quick:
        resolution, samples = (96, 54), 1
    streaming, streamed = engine_streaming(blend, resolution, samples, tile_size)  # warms the session pool
    core_scene, settings = export_blend(blend, resolution, samples, tile_size)
    # the same image at half the tile size, for the cost per tile apart from the pixels' (the strict
    # projection's renders on 8 / 16 workers have more, smaller tiles); min of two F12s each
    halved = settings.tile_size // 2
    sizes = [(tile_size, [(streaming, streamed)]), (halved, [])]
    for size, runs in sizes[::-1] + sizes:
        if len(runs) < 2:
            runs.append(engine_streaming(blend, resolution, samples, size))
    streaming, streamed = min(sizes[0][1])
    streaming_for = streaming_for_tiles([min(runs) for _, runs in sizes])
    t0 = time.perf_counter()
    prepared = prepare(core_scene, settings)
    preparing = time.perf_counter() - t0
    t0 = time.perf_counter()
    data = pickle.dumps(prepared)
    pickling = time.perf_counter() - t0
    t0 = time.thread_time()
    pickle.loads(data)  # no geometry cache here: what a worker pays for a scene it has not built before
    rebuild = time.thread_time() - t0
    payload = len(data)

    def threads(count, prepared=prepared):
        copy = pickle.loads(pickle.dumps(prepared))
        copy = dataclasses.replace(copy, settings=dataclasses.replace(copy.settings, parallelism="THREADS"))
        return lambda: list(render_tiles(copy, threads=count))

    def processes(count, pool, source=(core_scene, settings)):
        copy, preparing = f12_prepared(pool, count, source)

        def run():
            return list(pool.render(copy, lambda: False, count))
        run.preparing = preparing  # CPU s of the prepare the workers' build overlapped
        return run

    def two_renders_at_once(source=(core_scene, settings)):
        """Two independent one-worker renders of the image at once (each its own pool):
        the hardware's own scaling from one busy core to two, the ceiling for processes x2."""
        copies = [f12_prepared(tuned, 1, source)[0], f12_prepared(twin, 1, source)[0]]

        def run():
            other = threading.Thread(target=lambda: list(twin.render(copies[1], lambda: False, 1)))
            other.start()
            tiles = list(tuned.render(copies[0], lambda: False, 1))
            other.join()
            return tiles
        return run

    variants = {
        "threads x1": lambda: threads(1),
        "threads x2": lambda: threads(2),
        "processes x1": lambda: processes(1, tuned),
        "processes x2": lambda: processes(2, tuned),
        "processes x1, glibc malloc untuned": lambda: processes(1, untuned),
        "processes x2, glibc malloc untuned": lambda: processes(2, untuned),
        "two processes x1 renders at once": two_renders_at_once,
    }
    times = {variant: [] for variant in variants}
    cpu = {variant: [] for variant in variants}
    stats = {variant: [] for variant in variants if variant.startswith("processes")}
    overlapped_prepare = {}  # id of a process render's stats -> CPU s of the prepare its build overlapped
    images = {}
    loads = []
    names = list(variants)
    for repeat in range(repeats):
        order = names[repeat % len(names):] + names[:repeat % len(names)]
        for variant in order:
            run = variants[variant]()  # the untimed copy
            loads.append(os.getloadavg()[0])
            pids = tuned.pids + untuned.pids + twin.pids
            c0, t0 = cpu_seconds(pids), time.perf_counter()
            tiles = run()
            times[variant].append(time.perf_counter() - t0)
            cpu[variant].append(cpu_seconds(pids) - c0)
            if variant in stats:
                stats[variant].append((untuned if "untuned" in variant else tuned).last_stats)
                overlapped_prepare[id(stats[variant][-1])] = run.preparing
            images[variant] = {(t.x0, t.y0): t.passes["Combined"] for t in tiles}
    reference = images["threads x1"]
    same = all(v.keys() == reference.keys() and all(np.array_equal(v[k].view(np.uint32), reference[k].view(np.uint32))
                                                    for k in v) for v in images.values())
    width, height = prepared.settings.resolution
    sec.add(f"### {name}: {width}x{height}, {prepared.settings.samples} samples, "
            f"{len(prepared.tiles())} tiles of {prepared.settings.tile_size} px, pickled scene {payload / 1e6:.2f} MB "
            f"(pickled in {pickling:.2f} s, rebuilt from it in {rebuild:.2f} s: what each process render adds)")
    sec.add()
    sec.add(f"{repeats} interleaved repeats. Load average during the runs: {min(loads):.2f}-{max(loads):.2f}. "
            f"Every variant's Combined pass bit-identical to threads x1: {same}.")
    sec.add()
    base = min(times["threads x1"])
    rows = []
    for variant, values in times.items():
        fastest = int(np.argmin(values))
        rows.append([variant, f"{min(values):.2f}", f"{np.median(values):.2f}", f"{base / min(values):.2f}x",
                     f"{min(cpu[variant]):.2f}", f"{cpu[variant][fastest] / values[fastest]:.2f}"])
    sec.table(["variant", "min s", "median s", "vs threads x1 (min)", "CPU s (min; this process and the workers)",
               "cores used (CPU s / wall s, fastest run)"], rows)
    for mode in ("threads", "processes", "processes x{}, glibc malloc untuned"):
        one, two = (mode.format(n) if "{}" in mode else f"{mode} x{n}" for n in (1, 2))
        scaling = sec.number(f"{key}_{mode.replace(' x{}, glibc malloc ', '_').replace(' ', '_')}_x2",
                             min(times[one]) / min(times[two]))
        sec.add(f"- {mode.replace(' x{}', '')}: 2 cores / 1 core = {scaling:.2f}x "
                f"(medians {np.median(times[one]) / np.median(times[two]):.2f}x)")
    processes_x2 = min(times["processes x1"]) / min(times["processes x2"])
    ceiling = sec.number(f"{key}_machine_x2", 2 * min(times["processes x1"]) / min(times["two processes x1 renders at once"]))
    sec.add(f"- the hardware's own scaling: two independent one-worker renders at once deliver {ceiling:.2f}x the "
            f"images per second of one; processes x2 reaches {processes_x2 / ceiling:.0%} of that")
    sec.add(f"- malloc tuning, one worker: {min(times['processes x1, glibc malloc untuned']) / min(times['processes x1']):.2f}x "
            f"faster; two workers: {min(times['processes x2, glibc malloc untuned']) / min(times['processes x2']):.2f}x")
    tiles = len(prepared.tiles())
    fastest = {variant: runs[int(np.argmin(times[variant]))] for variant, runs in stats.items()}
    one, two = fastest["processes x1"], fastest["processes x2"]
    rows = balance(two)
    sec.add()
    sec.add(f"Balance of processes x2 (its fastest run, {two.ended - two.started:.2f} s wall; {two.shares} shares "
            f"for {tiles} tiles; times from the render's start):")
    sec.add()
    sec.table(["worker", "shares", "pixels", "busy s", "CPU s", "idle s", "first share starts, s", "last share ends, s"],
              [[str(row["pid"]), str(row["shares"]), str(row["pixels"]), f"{row['busy']:.2f}", f"{row['cpu']:.2f}",
                f"{row['idle']:.2f}", f"{row['first']:.3f}", f"{row['last']:.3f}"] for row in rows])
    ends = [row["last"] for row in rows]
    work_one, work_two = sum(row["busy"] for row in balance(one)), sum(row["busy"] for row in rows)
    cpu_one, cpu_two = sum(row["cpu"] for row in balance(one)), sum(row["cpu"] for row in rows)
    wall_one, wall_two = one.ended - one.started, two.ended - two.started
    sec.add(f"- imbalance: the two workers' last shares end {max(ends) - min(ends):.3f} s apart "
            f"({(max(ends) - min(ends)) / wall_two:.1%} of the render); both workers' busy time together "
            f"{work_two:.2f} s against one worker's {work_one:.2f} s ({work_two / work_one:.2f}x), their CPU "
            f"{cpu_two:.2f} s against {cpu_one:.2f} s ({cpu_two / cpu_one:.2f}x: what the bands and a second "
            f"worker cost; busy time above CPU time is time waiting for a core)")
    sec.add(f"- processes x2 against half of processes x1 ({wall_one:.2f} / 2 s, fastest runs): {wall_two - wall_one / 2:+.3f} s "
            f"= before the first share {min(row['first'] for row in rows) - min(row['first'] for row in balance(one)):+.3f} s, "
            f"extra busy per worker {work_two / 2 - work_one / 2:+.3f} s, idle at the end {(max(ends) - min(ends)) / 2:+.3f} s, "
            f"after the last share {(wall_two - max(ends)) - (wall_one - max(row['last'] for row in balance(one))):+.3f} s")
    streaming_per_tile = streaming / streamed if streamed else 0.0
    warm = max((cpu for _, _, cpu in one.builds.values()), default=0.0)
    # an F12 on workers that have not built this scene's geometry (they rendered another scene)
    cold_pool = workers.WorkerPool()
    try:
        other = next(other for other in SCENES.values() if other[0] != blend)[0]
        list(cold_pool.render(prepare(*export_blend(other, (8, 8), 1, None)), lambda: False, 1))
        cold_copy, cold_preparing = f12_prepared(cold_pool, 1, (core_scene, settings))
        list(cold_pool.render(cold_copy, lambda: False, 1))
    finally:
        cold_pool.close()
    (cold_wait, cold_wall), (warm_wait, warm_wall) = (build_wait(cold_pool.last_stats, cold_preparing),
                                                      build_wait(one, overlapped_prepare[id(one)]))
    sec.add(f"- serial work, CPU s (processes x1, fastest run; the streaming from one F12 through the engine, "
            f"{streaming * 1e3:.1f} ms for {streamed} tiles): "
            + ", ".join(f"{part} {value * 1e3:.1f} ms" for part, value in
                        serial_seconds(one, rebuild, streaming_per_tile, tiles).items())
            + f" (cold: a scene the worker has not built; {warm * 1e3:.1f} ms warm, its geometry cached, "
            f"as for the frames of an animation; built ahead as in an F12, the render waits for it "
            f"{cold_wait * 1e3:.1f} ms cold, {warm_wait * 1e3:.1f} ms warm: the worker's build CPU less this "
            f"process's prepare CPU meanwhile, {cold_preparing * 1e3:.1f} / {overlapped_prepare[id(one)] * 1e3:.1f} ms; "
            f"the wall wait measured here {cold_wall * 1e3:.1f} / {warm_wall * 1e3:.1f} ms); "
            f"rendering in the worker {cpu_one:.2f} CPU s. Not counted: "
            f"the loop's checks for Esc between messages, {one.polling_cpu * 1e3:.1f} ms (every 50 ms of wall time, "
            f"so they shrink with the render's wall time)")
    sec.add()
    projections = []  # (label, serial s at 8 cores, at 16 cores, the parallel work s)
    for label, rebuilt, extra in (("F12: built ahead, cold (the wait for the workers' build)", cold_wait, 0.0),
                                  ("F12: built ahead, warm (geometry cached: re-render, animation frames)",
                                   warm_wait, 0.0),
                                  ("cold rebuild after prepare (a render not built ahead)", rebuild, 0.0),
                                  ("warm rebuild after prepare", warm, 0.0),
                                  (f"cold, and this process preparing the scene first ({preparing * 1e3:.0f} ms, "
                                   f"the same for threads)", rebuild, preparing)):
        total = sum(serial_seconds(one, rebuilt, streaming_per_tile, tiles).values()) + extra
        projections.append((label, total, total, cpu_one))
    # the parent's per-tile work overlaps the workers' (it receives and streams tile k while they
    # render k+1...): only the last tile's is on the critical path, the rest takes its share of the cores
    per_tile = (one.loop_cpu + one.receiving_cpu) / tiles + streaming_per_tile
    for label, rebuilt in (("F12 cold, the parent's per-tile work overlapping the workers'", cold_wait),
                           ("F12 warm, the parent's per-tile work overlapping the workers'", warm_wait),
                           ("cold rebuild after prepare, the per-tile work overlapping", rebuild),
                           ("warm rebuild after prepare, the per-tile work overlapping", warm)):
        serial = one.pickling + one.sending + rebuilt + per_tile
        projections.append((label, serial, serial, cpu_one + per_tile * (tiles - 1)))
    overlapped_cold = projections[-4]  # the first F12's, for the numbers
    # strict, for N cores: the parent's work per share (dealing, the workers' messages) and per
    # tile (streaming) as measured here, times the shares and tiles a render on N workers has
    # (the tiles are halved while fewer than the workers, the shares cut them in bands)
    per_share = (one.loop_cpu + one.receiving_cpu) / one.shares
    counts = {cores: tiles_and_shares(prepared, cores) for cores in (8, 16)}
    strict, strict_measured = [], []
    for label, rebuilt in (("F12 cold, strict, with the tiles and shares of 8 / 16 workers", cold_wait),
                           ("F12 warm, strict, with the tiles and shares of 8 / 16 workers", warm_wait)):
        fixed = one.pickling + one.sending + rebuilt
        serial = {cores: fixed + per_share * shares + streaming_for(count)
                  for cores, (count, shares) in counts.items()}
        projections.append((f"{label} ({' / '.join(f'{t} tiles, {n} shares' for t, n in counts.values())})",
                            serial[8], serial[16], cpu_one))
        strict.append(projections[-1])
    # strict, measured: this process's CPU in renders on as many worker processes as the projection's
    # cores (here sharing this machine's cores: CPU seconds, which the wait does not grow), so the
    # loop's cost per render (the results image, dealing) is not scaled by the shares as above
    many, many_settings = MEASURED_WORKERS, dataclasses.replace(settings, threads=MEASURED_WORKERS)
    many_pool, parents, rewritten = workers.WorkerPool(), [], []
    try:
        # the first starts the workers and builds the scene; then MEASURED_RENDERS as F12s, the least
        # of them counted (as for every other CPU figure here: the load only adds to a CPU time).  Each
        # F12 exports the scene again unchanged, so its arrays are named from the last F12's files, not
        # written (WorkerPool._scene_files); then as many F12s with those files forgotten first, which
        # write every array again (the session's first F12, or one whose textures and meshes all changed)
        for render in range(1 + 2 * MEASURED_RENDERS):
            if render > MEASURED_RENDERS:
                many_pool._forget_scene()
            many_copy, _ = f12_prepared(many_pool, many, (core_scene, many_settings))
            list(many_pool.render(many_copy, lambda: False, many))
            measured = many_pool.last_stats
            if render:
                (parents if render <= MEASURED_RENDERS else rewritten).append(
                    measured.parent_seconds - measured.caller_cpu)
    finally:
        many_pool.close()
    many_tiles = len(many_copy.tiles())
    many_parent = min(parents) + streaming_for(many_tiles)  # as two_parent
    rewritten_parent = min(rewritten) + streaming_for(many_tiles)
    for label, rebuilt in ((f"F12 cold, strict, measured on {many} worker processes (the least of "
                            f"{MEASURED_RENDERS} F12s: {' / '.join(f'{p * 1e3:.1f}' for p in parents)} ms before "
                            f"streaming; {many_tiles} tiles, {measured.shares} shares)", cold_wait),
                           (f"F12 warm, strict, measured on {many} worker processes", warm_wait)):
        projections.append((label, many_parent + rebuilt, many_parent + rebuilt, cpu_one))
        strict_measured.append(projections[-1])
    projections.append((f"F12 cold, strict, measured on {many} worker processes, every array written again "
                        f"(the least of {MEASURED_RENDERS} F12s: {' / '.join(f'{p * 1e3:.1f}' for p in rewritten)} ms "
                        f"before streaming)", rewritten_parent + cold_wait, rewritten_parent + cold_wait, cpu_one))
    rewritten_x16 = amdahl(projections[-1][2], cpu_one, 16)
    two_parent = two.parent_seconds - two.caller_cpu + streaming_per_tile * tiles + warm_wait
    projections.append((f"F12, strict, measured with two workers (this process's own work in processes x2, "
                        f"{two.shares} shares)", two_parent, two_parent, cpu_one))
    rows = []
    for label, serial8, serial16, work in projections:
        serial_ms = f"{serial16 * 1e3:.1f}" if serial8 == serial16 else f"{serial8 * 1e3:.1f} / {serial16 * 1e3:.1f}"
        rows.append([label, serial_ms, f"{serial16 / (serial16 + work):.2%}", f"{amdahl(serial8, work, 8):.1f}x",
                     f"{amdahl(serial16, work, 16):.1f}x"])
    sec.table(["serial share and Amdahl projection", "serial ms", "share", "8 cores", "16 cores"], rows)
    sec.add(f"- this process per share {per_share * 1e3:.3f} ms (the loop and the workers' messages), "
            f"per tile {streaming_per_tile * 1e3:.3f} ms (the engine's streaming, at {streamed} tiles; for 8 / 16 "
            f"workers' {' / '.join(str(count) for count, _ in counts.values())} tiles "
            f"{' / '.join(f'{streaming_for(count) * 1e3:.1f}' for count, _ in counts.values())} ms, fitted to F12s "
            f"at {settings.tile_size} and {halved} px tiles: "
            f"{' and '.join(f'{min(runs)[0] * 1e3:.1f} ms for {min(runs)[1]} tiles' for _, runs in sizes)}); "
            f"with two workers: "
            f"loop {two.loop_cpu * 1e3:.1f} ms, messages {two.receiving_cpu * 1e3:.1f} ms for {two.shares} shares")
    sec.add()
    sec.add(f"Shares dealt: {two.shares} for 2 workers, {len(workers.share_out(prepared.tiles(), 8))} for 8, "
            f"{len(workers.share_out(prepared.tiles(), 16))} for 16 ({tiles} tiles).")
    sec.add()
    sec.add(f"- peak RSS of the tuned workers so far: "
            f"{', '.join(f'{peak_rss_mb(pid):.0f} MB' for pid in tuned.pids)}")
    sec.add()

    (_, _, cold16, cold_work), (_, _, warm16, warm_work) = strict
    cold_x16, warm_x16 = amdahl(cold16, cold_work, 16), amdahl(warm16, warm_work, 16)
    sec.number(f"{key}_strict16_cold", cold_x16)
    sec.number(f"{key}_strict16_warm", warm_x16)
    sec.number(f"{key}_overlapped16_cold", amdahl(*overlapped_cold[2:], 16))
    sec.number(f"{key}_serial_ms_cold16", cold16 * 1e3)
    (_, _, measured_cold, _), (_, _, measured_warm, _) = strict_measured
    measured_cold_x16, measured_warm_x16 = (amdahl(serial, cpu_one, 16) for serial in (measured_cold, measured_warm))
    sec.number(f"{key}_strict16_measured_cold", measured_cold_x16)
    sec.number(f"{key}_strict16_measured_warm", measured_warm_x16)
    sec.number(f"{key}_strict16_measured_rewritten", rewritten_x16)
    sec.number(f"{key}_bit_identical", same)
    sec.goals.append(Goal(f"two cores / one core, worker processes, {short}", f">= {TWO_CORES_GOAL:g}",
                          f"{processes_x2:.2f}x ({processes_x2 / ceiling:.0%} of the machine's own scaling below)",
                          processes_x2 >= TWO_CORES_GOAL))
    sec.goals.append(Goal(f"the machine's own two-process scaling in the same run, {short}: two independent "
                          "one-worker renders at once / one (the ceiling of the row above)", "measure",
                          f"{ceiling:.2f}x", None))
    measured_x16 = min(measured_cold_x16, measured_warm_x16)
    sec.goals.append(Goal(f"strict serial share projected to 16 cores (this process's CPU in a render on 16 worker "
                          f"processes), {short}", f">= {PROJECTION_GOAL:g}",
                          f"{measured_x16:.1f}x (first F12, cold: {measured_cold_x16:.1f}x, {measured_cold * 1e3:.1f} ms "
                          f"of {cpu_one:.2f} CPU s; warm: {measured_warm_x16:.1f}x); scaled from one worker's cost per "
                          f"share, which counts the loop's cost per render again for every share: "
                          f"{min(cold_x16, warm_x16):.1f}x ({cold16 * 1e3:.1f} ms cold); an F12 writing every "
                          f"array of the scene again (none unchanged since the last F12): {rewritten_x16:.1f}x",
                          measured_x16 >= PROJECTION_GOAL))


def run(ctx: Context, repeats: int | None = None) -> Section:
    """Section 10 of the report: every scene of SCENES, threads against worker processes."""
    from restframe_addon.core import workers
    from restframe_addon.core.prepared import prepare

    register_addon()
    repeats = repeats or ctx.pick(3, 1)
    sec = Section("10. Two cores and the 16-core projection: threads against worker processes")
    sec.add_paragraphs(__doc__.split("\n\n", 2)[2])  # after the title and the commands
    pools = {"tuned": workers.WorkerPool(),
             "untuned": workers.WorkerPool(environment={**os.environ, "OPENBLAS_NUM_THREADS": "1"}),
             "twin": workers.WorkerPool()}  # twin: a second, independent render at once (the machine's scaling)
    try:
        t0 = time.perf_counter()
        list(pools["tuned"].render(prepare(*export_blend("moving_sphere.blend", (8, 8), 1, None)), lambda: False, 2))
        start_up = time.perf_counter() - t0
        list(pools["untuned"].render(prepare(*export_blend("moving_sphere.blend", (8, 8), 1, None)), lambda: False, 2))
        list(pools["twin"].render(prepare(*export_blend("moving_sphere.blend", (8, 8), 1, None)), lambda: False, 1))
        sec.add(f"Host: {os.cpu_count()} cores; load average at start {os.getloadavg()[0]:.2f} "
                f"(a shared machine: other work runs alongside). Two warm workers started and rendered an "
                f"8x8 image in {start_up:.2f} s. {repeats} interleaved repeats of every variant (of a short "
                f"render more: each scene says how many).")
        sec.add()
        for name, spec in SCENES.items():
            ctx.log(f"  {name}")
            scene_report(sec, name, spec, pools, repeats, ctx.smoke)
    finally:
        for pool in pools.values():
            pool.close()
    return sec


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="small images (a check that the script runs)")
    parser.add_argument("--checkout", help="render with the restframe_addon of this checkout (a git worktree), "
                                           "to compare it with this one's by the same measurements")
    args = parser.parse_args()
    print_section(run(standalone_context(args.quick), args.repeats))


if __name__ == "__main__":
    main()
    if "bpy" in sys.modules and sys.modules["bpy"].app.version < (4, 3, 0):
        os._exit(0)  # bpy 4.2 as a module crashes in its exit handlers (see tests/blender/conftest.py)

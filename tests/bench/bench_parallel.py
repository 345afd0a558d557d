"""Scaling from one core to two: threads against worker processes (core.workers).

    tools/dev.sh tests/bench/bench_parallel.py [--repeats N] [--quick]

Each scene is exported from its .blend and prepared once; every timed render then renders a
fresh copy of the prepared scene (a pickle round trip, untimed), so the process renders pay
what an F12 pays: pickling the scene, sending it and rebuilding it in every worker.  The
workers are started before timing (they stay warm across renders; their start-up is reported
on its own).  CPU seconds (this process and its workers, Linux) are given next to the wall
times: unlike those, they do not grow when other work takes the cores.  Variants run interleaved in one process, rotating their order each repeat, with
the load average noted: the machine may be shared.  Prints a markdown report.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import pickle
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

SCENES = {  # name: (.blend, resolution or None for the file's, samples or None, tile size or None)
    "moving_sphere": ("moving_sphere.blend", (960, 540), 8, None),
    "bars_sideways (11x11 bars, 11 velocities)": ("bars_sideways.blend", None, None, 64),
}


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


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="small images (a check that the script runs)")
    args = parser.parse_args()

    import restframe_addon
    from restframe_addon.core import workers
    from restframe_addon.core.prepared import prepare
    from restframe_addon.core.render import render_tiles

    restframe_addon.register()
    tuned = workers.WorkerPool()
    untuned = workers.WorkerPool(environment={**os.environ, "OPENBLAS_NUM_THREADS": "1"})
    t0 = time.perf_counter()
    list(tuned.render(prepare(*export_blend("moving_sphere.blend", (8, 8), 1, None)), lambda: False, 2))
    start_up = time.perf_counter() - t0
    list(untuned.render(prepare(*export_blend("moving_sphere.blend", (8, 8), 1, None)), lambda: False, 2))

    print(f"Host: {os.cpu_count()} cores; load average at start {os.getloadavg()[0]:.2f} "
          f"(a shared machine: other work runs alongside). Two warm workers started and rendered an "
          f"8x8 image in {start_up:.2f} s.\n")
    for name, (blend, resolution, samples, tile_size) in SCENES.items():
        if args.quick:
            resolution, samples = (96, 54), 1
        core_scene, settings = export_blend(blend, resolution, samples, tile_size)
        prepared = prepare(core_scene, settings)
        t0 = time.perf_counter()
        data = pickle.dumps(prepared)
        pickling = time.perf_counter() - t0
        t0 = time.perf_counter()
        pickle.loads(data)
        rebuild = time.perf_counter() - t0
        payload = len(data)

        def threads(count, prepared=prepared):
            copy = pickle.loads(pickle.dumps(prepared))
            copy = dataclasses.replace(copy, settings=dataclasses.replace(copy.settings, parallelism="THREADS"))
            return lambda: list(render_tiles(copy, threads=count))

        def processes(count, pool, prepared=prepared):
            copy = pickle.loads(pickle.dumps(prepared))
            return lambda: list(pool.render(copy, lambda: False, count))

        variants = {
            "threads x1": lambda: threads(1),
            "threads x2": lambda: threads(2),
            "processes x1": lambda: processes(1, tuned),
            "processes x2": lambda: processes(2, tuned),
            "processes x1, glibc malloc untuned": lambda: processes(1, untuned),
            "processes x2, glibc malloc untuned": lambda: processes(2, untuned),
        }
        times = {variant: [] for variant in variants}
        cpu = {variant: [] for variant in variants}
        images = {}
        loads = []
        names = list(variants)
        for repeat in range(args.repeats):
            order = names[repeat % len(names):] + names[:repeat % len(names)]
            for variant in order:
                run = variants[variant]()  # the untimed copy
                loads.append(os.getloadavg()[0])
                pids = tuned.pids + untuned.pids
                c0, t0 = cpu_seconds(pids), time.perf_counter()
                tiles = run()
                times[variant].append(time.perf_counter() - t0)
                cpu[variant].append(cpu_seconds(pids) - c0)
                images[variant] = {(t.x0, t.y0): t.passes["Combined"] for t in tiles}
        reference = images["threads x1"]
        same = all(v.keys() == reference.keys() and all(np.array_equal(v[k].view(np.uint32), reference[k].view(np.uint32))
                                                        for k in v) for v in images.values())
        width, height = prepared.settings.resolution
        print(f"### {name}: {width}x{height}, {prepared.settings.samples} samples, "
              f"{len(prepared.tiles())} tiles of {prepared.settings.tile_size} px, pickled scene {payload / 1e6:.2f} MB "
              f"(pickled in {pickling:.2f} s, rebuilt from it in {rebuild:.2f} s: what each process render adds)\n")
        print(f"Load average during the runs: {min(loads):.2f}-{max(loads):.2f}. "
              f"Every variant's Combined pass bit-identical to threads x1: {same}.\n")
        print("| variant | min s | median s | vs threads x1 (min) | CPU s (min; this process and the workers) "
              "| cores used (CPU s / wall s, fastest run) |")
        print("|---|---|---|---|---|---|")
        base = min(times["threads x1"])
        for variant, values in times.items():
            fastest = int(np.argmin(values))
            print(f"| {variant} | {min(values):.2f} | {np.median(values):.2f} | {base / min(values):.2f}x "
                  f"| {min(cpu[variant]):.2f} | {cpu[variant][fastest] / values[fastest]:.2f} |")
        print()
        for mode in ("threads", "processes", "processes x{}, glibc malloc untuned"):
            one, two = (mode.format(n) if "{}" in mode else f"{mode} x{n}" for n in (1, 2))
            print(f"- {mode.replace(' x{}', '')}: 2 cores / 1 core = {min(times[one]) / min(times[two]):.2f}x "
                  f"(medians {np.median(times[one]) / np.median(times[two]):.2f}x)")
        print(f"- malloc tuning, one worker: {min(times['processes x1, glibc malloc untuned']) / min(times['processes x1']):.2f}x "
              f"faster; two workers: {min(times['processes x2, glibc malloc untuned']) / min(times['processes x2']):.2f}x")
        serial = (pickling + rebuild) / min(cpu["processes x1"])
        print(f"- per-render cost every worker pays whatever the worker count (pickling + rebuild) / CPU s of "
              f"processes x1: {serial:.1%}; Amdahl with it: {1 / (serial + (1 - serial) / 8):.1f}x on 8 cores, "
              f"{1 / (serial + (1 - serial) / 16):.1f}x on 16 (tile count permitting: {len(prepared.tiles())} tiles)")
        print(f"- peak RSS of the tuned workers so far: "
              f"{', '.join(f'{peak_rss_mb(pid):.0f} MB' for pid in tuned.pids)}\n")
    tuned.close()
    untuned.close()


if __name__ == "__main__":
    main()
    if "bpy" in sys.modules and sys.modules["bpy"].app.version < (4, 3, 0):
        os._exit(0)  # bpy 4.2 as a module crashes in its exit handlers (see tests/blender/conftest.py)

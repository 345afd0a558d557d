"""Section 3: throughput against the floor (raw embreex on the same rays), scaling with
rest frames, triangles, resolution and threads; export time and memory for 1M triangles."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from bench_common import (ROOT, Goal, Section, ball_scene, box, interleaved, look_at_camera, settings, timed,
                          uv_sphere)
from restframe_addon.core.prepared import PreparedScene, prepare
from restframe_addon.core.render import render_image
from restframe_addon.core.scene import Light, Material, Mesh, RenderSettings, Scene, Velocity
from restframe_addon.core.tracer import TraceCache, trace_nearest

TILE = RenderSettings().tile_size  # the renderer's default tile (128: 16384 rays per batch)


def tiles(res, size=TILE):
    return [(x, y, min(x + size, res[0]), min(y + size, res[1]))
            for y in range(0, res[1], size) for x in range(0, res[0], size)]


def pipeline_primary(prepared: PreparedScene, rects):
    """What the renderer does for primary visibility: camera rays per tile, then trace_nearest."""
    cache = TraceCache()  # as a render thread keeps it
    hit = 0
    for rect in rects:
        tau, x, d, s_lo, s_hi = prepared.centre_rays(rect)
        hits = trace_nearest(prepared.frames, prepared.frames.camera, tau, x, d, s_lo, s_hi, cache)
        hit += int(np.count_nonzero(hits.frame >= 0))
    return hit


def raw_batches(prepared: PreparedScene, rects):
    """The same camera rays, mapped into each geometry frame once and stored as embree's float32
    input: the floor is one ``embree.run`` per tile and frame with nothing else around it."""
    frames = prepared.frames
    batches = []
    for rect in rects:
        tau, x, d, _, _ = prepared.centre_rays(rect)
        for k in frames.geometry:
            fmap = frames.map(frames.camera, k)
            _, origin = fmap.events(tau, x)
            dk, _ = fmap.rays(d)
            frame = frames.frames[k]
            origin, dk = frame.to_local(origin, dk)
            geometry = frame.geometry
            batches.append((geometry.embree, np.ascontiguousarray(origin - geometry.anchor, dtype=np.float32),
                            np.ascontiguousarray(dk, dtype=np.float32)))
    return batches


def raw_primary(batches):
    hit = 0
    for embree, o, d in batches:
        hit += int(np.count_nonzero(embree.run(o, d, output=1)["primID"] >= 0))
    return hit


def primary_study(name, scene, res, repeats):
    s = settings(res)
    prepared = prepare(scene, s)
    rects = tiles(res)
    batches = raw_batches(prepared, rects)
    t = interleaved({
        "raw": lambda: raw_primary(batches),
        "pipeline": lambda: pipeline_primary(prepared, rects),
        "render": lambda: render_image(scene, s),
    }, repeats)
    n = res[0] * res[1]
    tris = sum(len(m.triangles) for m in scene.meshes)
    return {"name": name, "rays": n, "frames": len(prepared.frames.geometry), "triangles": tris,
            "raw": t["raw"]["min"], "pipeline": t["pipeline"]["min"], "render": t["render"]["min"],
            "raw_hits": t["raw"]["result"], "pipe_hits": t["pipeline"]["result"]}


# --------------------------------------------------------------------------- 11 x 11 bars
def bars_scene(row_velocities, rows_used=None, lights=True):
    """121 bars in 11 rows (paper's figure): row i moves along x with row_velocities[i]."""
    meshes = []
    for i in range(11):
        if rows_used is not None and i not in rows_used:
            continue
        vel = Velocity((row_velocities[i], 0.0, 0.0))
        y = 2.0 * i
        for j in range(11):
            centre = (-10.0 + 2.0 * j, y, 0.0)
            v, t = box(centre, (0.5, 0.5, 2.5))
            meshes.append(Mesh(f"bar{i}_{j}", v, t, velocity=vel, pivot=centre))
    camera = look_at_camera((0.0, -14.0, 9.0), (0.0, 9.0, 0.0), aspect=4 / 3, fov_half_tan=0.7)
    light_list = [Light("sun", "SUN", (0, 0, 10), matrix=np.array([[1, 0, 0], [0, 0.8, -0.6], [0, 0.6, 0.8]]).T,
                        power=3.0)] if lights else []
    return Scene(camera=camera, meshes=meshes, materials=[Material(base_color=(0.7, 0.7, 0.7))], lights=light_list)


def frames_study(res, repeats):
    one = [0.5] * 11
    many = [0.05 + 0.08 * i for i in range(11)]
    s = settings(res)
    scene1, scene11 = bars_scene(one), bars_scene(many)
    r1, r11 = prepare(scene1, s), prepare(scene11, s)
    rects = tiles(res)
    funcs = {
        "trace 1 frame": lambda: pipeline_primary(r1, rects),
        "trace 11 frames": lambda: pipeline_primary(r11, rects),
        "render 1 frame": lambda: render_image(scene1, s),
        "render 11 frames": lambda: render_image(scene11, s),
    }
    t = interleaved(funcs, repeats)
    return {k: v["min"] for k, v in t.items()}, len(r1.frames.geometry), len(r11.frames.geometry)


# --------------------------------------------------------------------------- triangles, resolution, threads
def sphere_scene(segments, beta=0.0):
    v, t = uv_sphere((0.0, 0.0, 0.0), 1.0, segments, max(segments // 2, 3))
    camera = look_at_camera((0.0, -3.2, 0.0), (0.0, 0.0, 0.0), fov_half_tan=0.45)
    return Scene(camera=camera, meshes=[Mesh("ball", v, t, velocity=Velocity((beta, 0.0, 0.0)))],
                 lights=[Light("lamp", "POINT", (2.0, -3.0, 3.0), power=1000.0)])


def triangle_study(segments_list, res, repeats, ctx):
    rows = []
    for segments in segments_list:
        scene = sphere_scene(segments, beta=0.5)
        s = settings(res)
        build, prepared = timed(lambda: prepare(scene, s))
        rects = tiles(res)
        batches = raw_batches(prepared, rects)
        t = interleaved({"raw": lambda: raw_primary(batches), "pipeline": lambda: pipeline_primary(prepared, rects),
                         "render": lambda: render_image(scene, s)}, repeats)
        tris = len(scene.meshes[0].triangles)
        n = res[0] * res[1]
        rows.append([tris, build, n / t["raw"]["min"], n / t["pipeline"]["min"], n / t["render"]["min"],
                     t["raw"]["min"] / t["pipeline"]["min"]])
        ctx.log(f"  triangles {tris}: build {build:.2f} s, ratio {rows[-1][-1]:.2f}")
    return rows


def resolution_study(sizes, repeats, ctx):
    rows = []
    scene = ball_scene(beta=0.9, segments=64)
    for size in sizes:
        res = (size, size * 3 // 4)
        s = settings(res)
        t = interleaved({"render": lambda: render_image(scene, s)}, repeats)
        n = res[0] * res[1]
        rows.append([f"{res[0]}x{res[1]}", n, t["render"]["min"], n / t["render"]["min"]])
        ctx.log(f"  resolution {res}: {t['render']['min']:.2f} s")
    return rows


def thread_study(res, repeats):
    scene = ball_scene(beta=0.9, segments=64)
    s1, s2 = settings(res, threads=1), settings(res, threads=2)
    t = interleaved({"1 thread": lambda: render_image(scene, s1), "2 threads": lambda: render_image(scene, s2)}, repeats)
    return t["1 thread"]["min"], t["2 threads"]["min"]


def raw_thread_study(repeats, res):
    """The floor for threads: raw embreex on two Python threads (it releases the GIL)."""
    import threading

    v, t = uv_sphere((0.0, 0.0, 0.0), 1.0, 256, 128)
    scene = Scene(camera=look_at_camera((0, -3, 0), (0, 0, 0)), meshes=[Mesh("ball", v, t)])
    prepared = prepare(scene, settings(res))
    batches = raw_batches(prepared, tiles(res))

    def two():
        halves = [batches[0::2], batches[1::2]]
        threads = [threading.Thread(target=raw_primary, args=(h,)) for h in halves]
        for th in threads:
            th.start()
        for th in threads:
            th.join()

    r = interleaved({"1": lambda: raw_primary(batches), "2": two}, repeats)
    return r["1"]["min"], r["2"]["min"]


# --------------------------------------------------------------------------- where the time goes
def hotspots(func, top=8):
    """cProfile of one call: rows (function, own time share, cumulative share), by own time."""
    import cProfile
    import pstats

    profile = cProfile.Profile()
    profile.enable()
    func()
    profile.disable()
    stats = pstats.Stats(profile).stats
    total = sum(v[2] for v in stats.values())
    rows = []
    for (path, line, name), (_, _, own, cum, _) in sorted(stats.items(), key=lambda kv: -kv[1][2])[:top]:
        where = f"{Path(path).parent.name}/{Path(path).name}:{line}" if path.startswith("/") else path
        rows.append([f"`{name}` ({where})", own / total, cum / total])
    return rows


# --------------------------------------------------------------------------- export (bpy, subprocess)
def export_study(subdivisions):
    worker = Path(__file__).with_name("bench_export_worker.py")
    python = sys.executable
    out = subprocess.run([python, str(worker), str(subdivisions)], capture_output=True, text=True, cwd=ROOT,
                         timeout=1800)
    if out.returncode != 0:
        raise RuntimeError(f"export worker failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def run(ctx) -> Section:
    sec = Section("3. Throughput against the floor")
    import matplotlib.pyplot as plt

    repeats = ctx.pick(5, 1)
    res = ctx.pick((256, 192), (32, 24))
    sec.add("### Primary rays against raw embreex")
    sec.add("")
    sec.add(f"{res[0]}x{res[1]} pixel-centre rays in {TILE}x{TILE} tiles, one thread. **raw** = only "
            "`frame.embree.run(origins, directions, output=1)` per tile and geometry frame on the same rays, "
            "already mapped into each frame and converted to float32 beforehand (the floor); **pipeline** = "
            "what the renderer does for visibility: camera ray generation + `trace_nearest` (frame maps, "
            "bounds clipping, float32 conversion, embree, nearest-hit merge); **render** = `render_image` "
            "with shading, one point light and its shadow rays, passes (threads=1). Ratio = raw time / "
            "pipeline time (goal >= 0.8). Min of "
            f"{repeats} interleaved repeats.")
    sec.add("")
    big = ctx.pick(256, 24)
    cases = [("static ball + floor, 2.3k triangles", ball_scene(0.0, segments=48)),
             (f"static ball + floor, {big * big // 2 // 1000}k triangles", ball_scene(0.0, segments=big)),
             (f"0.9c ball + floor, {big * big // 2 // 1000}k triangles (2 frames)", ball_scene(0.9, segments=big))]
    rows = []
    worst = 1e9
    for name, scene in cases:
        r = primary_study(name, scene, res, repeats)
        ratio = r["raw"] / r["pipeline"]
        worst = min(worst, ratio)
        rows.append([name, r["frames"], r["rays"] / r["raw"] / 1e6, r["rays"] / r["pipeline"] / 1e6,
                     r["rays"] / r["render"] / 1e6, ratio, r["raw"] / r["render"], f"{r['pipe_hits']} / {r['raw_hits']}"])
        sec.number(f"primary_ratio_{len(rows)}", ratio)
        sec.number(f"render_ratio_{len(rows)}", r["raw"] / r["render"])
        ctx.log(f"  {name}: pipeline/raw {ratio:.2f}")
    sec.table(["scene", "frames", "raw Mrays/s", "pipeline Mrays/s", "render Mrays/s", "raw / pipeline",
               "raw / render", "hits pipeline / raw"], rows)
    sec.goals.append(Goal("primary rays: pipeline / raw embreex", ">= 0.8", f"{worst:.2f} (worst case)", worst >= 0.8,
                          "see hotspots"))
    scene0 = cases[0][1]
    prepared0 = prepare(scene0, settings(res))
    rects0 = tiles(res)
    sec.add(f"Where the time goes (cProfile, {cases[0][0]}, {res[0]}x{res[1]}): own time of the top functions as a "
            "share of the whole call (cumulative share in the last column). embreex's Cython `run` is not seen by "
            "the profiler: embree's own work is counted in the own time of its caller, `_local_query`. cProfile adds "
            "a fixed cost to every Python call, so small helpers (`_pixel_grid`, `__getitem__` of `np.mgrid`) "
            "look bigger here than they are.")
    sec.add("")
    sec.add("Primary visibility (pipeline):")
    sec.add("")
    sec.table(["function", "own time", "cumulative"],
              [[r[0], f"{100 * r[1]:.0f}%", f"{100 * r[2]:.0f}%"] for r in hotspots(lambda: pipeline_primary(prepared0, rects0))])
    sec.add("render_image (threads=1):")
    sec.add("")
    sec.table(["function", "own time", "cumulative"],
              [[r[0], f"{100 * r[1]:.0f}%", f"{100 * r[2]:.0f}%"] for r in hotspots(lambda: render_image(scene0, settings(res)))])

    # 11 x 11 bars
    res_bars = ctx.pick((256, 192), (32, 24))
    sec.add("### Rest frames: the 11x11 bars")
    sec.add("")
    sec.add(f"121 bars (0.5 x 0.5 x 2.5 boxes, 1452 triangles) in 11 rows, seen obliquely, a sun light, "
            f"{res_bars[0]}x{res_bars[1]}, one thread. **1 frame**: all rows at 0.5c; **11 frames**: row i at "
            f"(0.05 + 0.08 i)c. Goal: 11 frames <= 2x one frame (11 single-frame renders would be 11x).")
    sec.add("")
    ft, f1, f11 = frames_study(res_bars, repeats)
    rt = ft["trace 11 frames"] / ft["trace 1 frame"]
    rr = ft["render 11 frames"] / ft["render 1 frame"]
    sec.table(["", "1 frame (s)", "11 frames (s)", "11 / 1"],
              [["primary visibility (pipeline)", ft["trace 1 frame"], ft["trace 11 frames"], rt],
               ["render_image with shading", ft["render 1 frame"], ft["render 11 frames"], rr]])
    sec.number("frames_trace_ratio", rt)
    sec.number("frames_render_ratio", rr)
    sec.goals.append(Goal("11 frames vs 1 frame (11x11 bars, render)", "<= 2x", f"{rr:.2f}x (visibility only {rt:.2f}x)",
                          rr <= 2.0))

    # triangles
    seg = ctx.pick([32, 100, 316, 1000], [32, 100])
    res_t = ctx.pick((128, 128), (24, 24))
    sec.add("### Triangles")
    sec.add("")
    sec.add(f"A sphere moving at 0.5c filling most of a {res_t[0]}x{res_t[1]} view (1 point light), "
            "tessellated from 1e3 to 1e6 triangles; build = `prepare(...)` (frames, embree BVH); rates in "
            "million camera rays per second, one thread.")
    sec.add("")
    rows = triangle_study(seg, res_t, repeats, ctx)
    sec.table(["triangles", "build (s)", "raw Mrays/s", "pipeline Mrays/s", "render Mrays/s", "raw / pipeline"],
              [[r[0], r[1], r[2] / 1e6, r[3] / 1e6, r[4] / 1e6, r[5]] for r in rows])
    for r in rows:
        sec.number(f"tris_{r[0]}_ratio", r[5])
        sec.number(f"tris_{r[0]}_build", r[1])
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.3))
    tris = [r[0] for r in rows]
    for col, name in ((2, "raw embreex"), (3, "pipeline (trace)"), (4, "render_image")):
        axes[0].loglog(tris, [r[col] / 1e6 for r in rows], "o-", label=name)
    axes[0].set_xlabel("triangles")
    axes[0].set_ylabel("Mrays/s (1 thread)")
    axes[0].legend(fontsize=7)
    axes[0].grid(True, which="both", alpha=0.3)
    axes[0].set_title("Scaling with triangles", fontsize=9)

    # resolution
    sizes = ctx.pick([64, 128, 256, 512], [16, 32])
    rows_r = resolution_study(sizes, max(repeats // 2, 1), ctx)
    axes[1].loglog([r[1] for r in rows_r], [r[3] / 1e6 for r in rows_r], "o-")
    axes[1].set_xlabel("pixels")
    axes[1].set_ylabel("render Mrays/s (1 thread)")
    axes[1].grid(True, which="both", alpha=0.3)
    axes[1].set_title("Scaling with resolution (0.9c ball scene)", fontsize=9)
    fig.tight_layout()
    fig.savefig(ctx.out_dir / "throughput.png", dpi=80)
    plt.close(fig)
    sec.add("### Resolution")
    sec.add("")
    sec.add("The ball scene with the ball at 0.9c (2 frames, 4k triangles, point light), render_image, one thread.")
    sec.add("")
    sec.table(["resolution", "pixels", "time (s)", "Mrays/s"], [[r[0], r[1], r[2], r[3] / 1e6] for r in rows_r])
    for r in rows_r:
        sec.number(f"res_{r[1]}_rate", r[3])
    sec.add(f"![triangles and resolution]({ctx.plot_prefix}/throughput.png)")
    sec.add("")

    # threads
    res_th = ctx.pick((512, 384), (32, 24))
    sec.add("### One core against two")
    sec.add("")
    t1, t2 = thread_study(res_th, repeats)
    load_now = os.getloadavg()[0]
    r1, r2 = raw_thread_study(repeats, ctx.pick((1024, 512), (64, 64)))  # 8 batches: 4 per thread
    speedup, raw_speedup = t1 / t2, r1 / r2
    sec.add(f"render_image of the 0.9c ball scene at {res_th[0]}x{res_th[1]}, {TILE}x{TILE} tiles (the default), threads=1 vs threads=2 "
            f"(min of {repeats} interleaved): {t1:.2f} s vs {t2:.2f} s, **speed-up {speedup:.2f}x**. The floor: raw "
            f"embreex primary rays (a 33k-triangle sphere, {TILE * TILE}-ray batches) on one vs two Python threads: speed-up "
            f"{raw_speedup:.2f}x. 1-minute load average during this test: {load_now:.2f}"
            # the benchmark's own busy thread adds about 1 to the load average
            + (" (other jobs share the 2 cores: this speed-up is not meaningful)." if load_now > 1.5 else
               " (about 1 of it is this benchmark itself)."))
    sec.add("")
    sec.number("thread_speedup", speedup)
    sec.number("raw_thread_speedup", raw_speedup)
    sec.goals.append(Goal("1 -> 2 threads", ">= 1.7x", f"{speedup:.2f}x (raw embreex {raw_speedup:.2f}x)", speedup >= 1.7))

    # export
    sub = ctx.pick(708, 20)
    sec.add("### Export of a 1M-triangle scene (bpy)")
    sec.add("")
    e = export_study(sub)
    sec.add(f"A grid primitive with {sub} subdivisions ({e['triangles']:,} triangles, moving at 0.5c), a camera "
            "and a point light built with bpy in a fresh subprocess; `restframe_addon.export.export_scene` on the "
            "evaluated depsgraph, then `prepare(...)` (frames + embree BVH), then a 64x48 render_image, one thread. "
            "Times are untraced; the steps are then repeated under tracemalloc for the peak of Python/numpy "
            "allocations (tracemalloc itself slows them 7-20x, so it is never timed); peak RSS = the worker's "
            "VmHWM (embree's BVH is not seen by tracemalloc but is in the RSS).")
    sec.add("")
    sec.table(["step", "time (s)", "tracemalloc peak (MB)", "peak RSS after the timed step (MB)"],
              [["scene built with bpy", e["build_s"], "-", e["rss_built_mb"]],
               ["export_scene", e["export_s"], e["export_peak_mb"], e["rss_export_mb"]],
               ["prepare (frames, BVH)", e["prepare_s"], e["prepare_peak_mb"], e["rss_prepare_mb"]],
               ["render_image 64x48 (its own preparation included)", e["render_s"], "-", e["rss_render_mb"]]])
    for k in ("export_s", "prepare_s", "export_peak_mb", "prepare_peak_mb", "rss_render_mb"):
        sec.number(f"export_{k}", e[k])
    sec.goals.append(Goal("export of 1M triangles", "measure",
                          f"{e['export_s']:.2f} s, {e['export_peak_mb']:.0f} MB peak; prepare {e['prepare_s']:.2f} s; "
                          f"peak RSS {e['rss_render_mb']:.0f} MB", None))
    return sec


def bars_spread(runs: int, repeats: int, res=(256, 192)) -> list[dict]:
    """The 11x11 bars' renders alone, ``runs`` times over, each the min of ``repeats`` interleaved
    repeats of wall-clock and of CPU time (one thread: CPU time is what the render itself took,
    the less disturbed by a shared machine): how stable the 11-frames / 1-frame ratio is."""
    import time

    s = settings(res)
    scenes = {"1": bars_scene([0.5] * 11), "11": bars_scene([0.05 + 0.08 * i for i in range(11)])}
    for scene in scenes.values():
        render_image(scene, s)  # warm
    studies = []
    for _ in range(runs):
        wall, cpu = {k: [] for k in scenes}, {k: [] for k in scenes}
        for r in range(repeats):
            for k in (list(scenes) if r % 2 == 0 else list(scenes)[::-1]):
                w, c = time.perf_counter(), time.process_time()
                render_image(scenes[k], s)
                wall[k].append(time.perf_counter() - w)
                cpu[k].append(time.process_time() - c)
        studies.append({"wall 1": min(wall["1"]), "wall 11": min(wall["11"]), "cpu 1": min(cpu["1"]),
                        "cpu 11": min(cpu["11"])})
    return studies


if __name__ == "__main__":  # the 11x11 bars alone: python bench_throughput.py --bars [RUNS] [REPEATS]
    import statistics
    import time

    if sys.argv[1:2] != ["--bars"]:
        raise SystemExit("usage: bench_throughput.py --bars [RUNS] [REPEATS] (the whole section runs from run.py)")
    runs, repeats = (int(a) for a in (sys.argv[2:] + ["5", "5"][len(sys.argv[2:]):])[:2])
    print(f"# 11x11 bars, render 11 frames / 1 frame (256x192, one thread): {runs} runs, each the min of {repeats} "
          f"interleaved repeats; {time.strftime('%H:%M:%S')} UTC, load {os.getloadavg()[0]:.2f}")
    studies = bars_spread(runs, repeats)
    for st in studies:
        print(f"wall {st['wall 11'] / st['wall 1']:.2f} ({st['wall 11']:.3f} / {st['wall 1']:.3f} s), "
              f"CPU {st['cpu 11'] / st['cpu 1']:.2f} ({st['cpu 11']:.3f} / {st['cpu 1']:.3f} s)")
    for kind in ("wall", "cpu"):
        ratios = sorted(st[f"{kind} 11"] / st[f"{kind} 1"] for st in studies)
        print(f"{kind}: median {statistics.median(ratios):.2f}, range {ratios[0]:.2f}-{ratios[-1]:.2f}")
    print(f"load at the end {os.getloadavg()[0]:.2f}")

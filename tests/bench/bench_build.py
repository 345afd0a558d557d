"""Section 6: building a mesh's rest frame against Embree building the same triangles (issue 20).

    tools/dev.sh tests/bench/bench_build.py            # this section alone, printed (Markdown)
    tools/dev.sh tests/bench/bench_build.py --smoke    # tiny sizes

**RESTframe** = `build_frames` of a scene with one UV sphere moving at (0.5, 0.2, 0) c: the
mesh checked and placed in its rest frame, handed to embree in pieces (Esc is polled between
them), the BVH built; with a static floor (a second frame) also the culling
clusters.  **Embree** = the fastest way to build the same
float32 triangles: one geometry whose buffers are filled by one memory copy each
(`core.embree_direct`), and the commit (of which **BVH** is the commit alone).  **embreex** =
the same through embreex's own `TriangleMesh(scene, vertices, indices)`, which copies both
arrays element by element through Python indexing whatever their dtype or layout (RESTframe's
fallback where the direct route is unavailable).
"""

from __future__ import annotations

import sys
import threading
import time

import numpy as np

from bench_common import Context, Goal, Section, interleaved, load, look_at_camera, print_section, quad, standalone_context, uv_sphere
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh
from restframe_addon.core import embree_direct, frames
from restframe_addon.core.scene import Mesh, Scene, Velocity

GOAL = 2.0  # RESTframe's build at most this many times Embree's


def sphere_scene(segments: int, floor: bool = False) -> Scene:
    """The sphere alone, or on a static floor (a second frame: culling clusters are built)."""
    v, t = uv_sphere((0.0, 0.0, 0.0), 1.0, segments, segments // 2)
    camera = look_at_camera((0.0, -3.2, 0.0), (0.0, 0.0, 0.0), fov_half_tan=0.45)
    meshes = [Mesh("ball", v, t, velocity=Velocity((0.5, 0.2, 0.0)))]
    if floor:
        meshes.append(Mesh("floor", *quad((0.0, 0.0, -1.5), (20.0, 20.0))))
    return Scene(camera=camera, meshes=meshes)


def raw_build(vertices: np.ndarray, triangles: np.ndarray, direct: bool) -> float:
    """Build an embree scene of the triangles (one geometry); returns how long the commit
    (Embree's BVH build) took."""
    device = frames._embree_device()
    scene = rtcore_scene.EmbreeScene(device)
    if not (direct and embree_direct.attach(scene, device, vertices, triangles)):
        TriangleMesh(scene, vertices, triangles)
    t0 = time.perf_counter()
    scene.run(np.zeros((1, 3), np.float32), np.array([[1.0, 0.0, 0.0]], np.float32))  # commits
    return time.perf_counter() - t0


def with_cpu(times: list, work):
    """``work``, appending the process's CPU time it took (every thread's: embree's and the build's) to ``times``."""
    def timed():
        started = time.process_time()
        try:
            return work()
        finally:
            times.append(time.process_time() - started)
    return timed


def longest_stretch_without_esc(scene: Scene) -> tuple[float, int]:
    """(longest time between two ``should_stop`` polls of one build, the number of polls)."""
    polls = []
    frames.build_frames(scene, should_stop=lambda: polls.append(time.perf_counter()) and False)
    polls.append(time.perf_counter())
    return float(np.max(np.diff(polls))), len(polls) - 1


def longest_gil_hold(scene: Scene) -> float:
    """Longest gap of a thread ticking every millisecond during one build: how long the build
    kept the GIL (plus the machine's scheduling delays), which is what the engine's Esc, polled
    from its main thread while a worker builds, waits for."""
    ticks, done = [], threading.Event()

    def tick():
        while not done.is_set():
            ticks.append(time.perf_counter())
            time.sleep(0.001)

    ticker = threading.Thread(target=tick)
    ticker.start()
    start = time.perf_counter()
    frames.build_frames(scene)
    end = time.perf_counter()
    done.set()
    ticker.join()
    return float(np.max(np.diff([start, *(t for t in ticks if start < t < end), end])))


def run(ctx: Context) -> Section:
    sec = Section("6. Building rest frames against Embree")
    repeats = ctx.pick(5, 1)
    rows = []
    worst = 0.0
    load_start = load()
    for segments, floor in ctx.pick(((512, False), (1024, False), (1024, True)), ((32, False), (64, False), (64, True))):
        scene = sphere_scene(segments, floor)
        geometry = frames.build_frames(scene).frames[-1].geometry  # the sphere's (the floor's frame is S)
        vertices = (geometry.vertices - geometry.anchor).astype(np.float32)  # the frame's own triangles
        triangles = geometry.triangles.astype(np.int32)
        commits, cpu = [], {"restframe": [], "embree": []}
        t = interleaved({"restframe": with_cpu(cpu["restframe"], lambda: frames.build_frames(scene)),
                         "embree": with_cpu(cpu["embree"], lambda: commits.append(raw_build(vertices, triangles, direct=True))),
                         "embreex": lambda: raw_build(vertices, triangles, direct=False)}, repeats)
        stretch, polls = longest_stretch_without_esc(scene)
        held = longest_gil_hold(scene)
        best = {name: t[name]["min"] for name in t}
        ratio = best["restframe"] / best["embree"]
        worst = max(worst, ratio)
        n = len(triangles)
        cpu_ratio = min(cpu["restframe"]) / min(cpu["embree"])
        rows.append([f"{n:,}".replace(",", " ") + (" + floor" if floor else ""), best["restframe"], best["embree"], min(commits), best["embreex"], ratio,
                     min(cpu["restframe"]), min(cpu["embree"]), cpu_ratio, best["restframe"] / best["embreex"], stretch, polls, held])
        name = f"{n}{'_floor' if floor else ''}"
        sec.number(f"build_ratio_{name}", ratio)
        sec.number(f"build_esc_gap_{name}", stretch)
        sec.number(f"build_gil_hold_{name}", held)
        ctx.log(f"  {n} triangles{' + floor' if floor else ''}: restframe {best['restframe']:.3f} s, embree {best['embree']:.3f} s, "
                f"embreex {best['embreex']:.3f} s, ratio {ratio:.2f} (CPU {min(cpu['restframe']):.3f} s / {min(cpu['embree']):.3f} s = "
                f"{cpu_ratio:.2f}), longest without Esc {stretch * 1e3:.0f} ms, "
                f"GIL held up to {held * 1e3:.0f} ms")
    sec.add(" ".join(__doc__.split("\n\n", 2)[2].split()))
    sec.add("")
    sec.add(f"Min of {repeats} interleaved repeats (wall clock; **CPU** = the process's CPU time, every thread's, min of the same repeats); load average {load_start:.2f} at the start, {load():.2f} at the "
            "end. **longest without Esc** = the longest stretch of one build between two polls of "
            "`should_stop`: the BVH build, last, cannot be split. **GIL held** = the longest gap of a thread "
            "ticking every millisecond during a build: the engine builds in a worker and polls Esc from its "
            "main thread, so this is what Esc waits for (handed to embree directly, copies and BVH build let "
            "go of the GIL).")
    sec.add("")
    sec.table(["triangles", "RESTframe (s)", "Embree (s)", "of which BVH (s)", "embreex (s)", "RESTframe / Embree",
               "RESTframe CPU (s)", "Embree CPU (s)", "CPU: RESTframe / Embree", "RESTframe / embreex", "longest without Esc (s)", "Esc polls", "GIL held (s)"], rows)
    sec.goals.append(Goal("rest-frame build / Embree's build of the same triangles", f"<= {GOAL:g}",
                          f"{worst:.2f} (worst)", worst <= GOAL))
    return sec


if __name__ == "__main__":
    print_section(run(standalone_context("--smoke" in sys.argv)))

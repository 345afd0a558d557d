"""Persistent data across frames (issue 20): what frames 2..N of an animation cost against frame 1,
with the rest-frame geometry reused (the command line's default) and built afresh
(``--no-persistent-data``), and where a frame's time goes.

    tools/dev.sh tests/bench/bench_persistent.py [--repeats 3] [--frames 1-25] [--no-heavy]   # printed (Markdown)
    tools/dev.sh tests/bench/run.py --only 11 --out FILE                                       # section 11 of the report

Each run is a fresh process rendering the frames through the command line's own loop
(``python -m restframe_addon render FILE -o OUT --frames A-B``), so frame 1 is the first render
of a session; runs with and without persistent data alternate (on, off, on, off, ...) so both
see the same machine load, and the ratio of a run is taken within that run.  Scenes:
``sample_blends/bars_sideways.blend`` (the 11x11 bars at 11 velocities, 255x255, 4 samples,
1452 triangles) and, unless ``--no-heavy``, a 261k-triangle sphere at (0.5, 0.2, 0)c with a sun,
320x240, 1 sample, whose build is a large share of a frame.

Per frame: the whole frame as the command line times it (frame change, render, image save);
inside the engine, the export, the preparation (rest frames, of which the embree builds) and the
rest (tiles into Blender's result).  Goal: frames 2..N at most 60% of frame 1 with persistent data,
the median of the runs, for each scene.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

from bench_common import ROOT, Context, Goal, Section, print_section, standalone_context

BARS = ROOT / "sample_blends" / "bars_sideways.blend"
STEPS = ("frame", "engine", "export", "prepare", "builds")
HEAVY_SEGMENTS = 512  # the heavy sphere's segments (and half as many rings): 261 120 triangles
LATER_GOAL = 0.6  # frames 2..N at most this share of frame 1


def worker(blend: str, frames: str, out: str, persistent: bool) -> None:
    """Render the frames with the command line's loop, timing each step; one JSON line on stdout."""
    sys.path.insert(0, str(ROOT))
    import restframe_addon
    from restframe_addon import __main__ as cli
    from restframe_addon import engine, export, headless
    from restframe_addon.core import frames as frames_module

    restframe_addon.register()
    times: list[dict] = []

    def timed(owner, name, step):
        original = getattr(owner, name)

        def wrapper(*args, **kwargs):
            started = time.perf_counter()
            try:
                return original(*args, **kwargs)
            finally:
                if times:
                    times[-1][step] += time.perf_counter() - started

        setattr(owner, name, wrapper)

    original_frame = headless.render_frame

    def render_frame(*args, **kwargs):
        times.append(dict.fromkeys(STEPS, 0.0))
        started = time.perf_counter()
        original_frame(*args, **kwargs)
        times[-1]["frame"] = time.perf_counter() - started

    headless.render_frame = render_frame
    timed(engine.RestframeRenderEngine, "_render", "engine")
    timed(export, "export_scene", "export")
    timed(engine, "prepare", "prepare")
    timed(frames_module, "_geometry", "builds")
    argv = ["render", blend, "-o", os.path.join(out, "frame_####.png"), "--frames", frames]
    if not persistent:
        argv.append("--no-persistent-data")
    sys.stdout, real_stdout = sys.stderr, sys.stdout  # the CLI's and Blender's prints go to the log
    status = cli.main(argv)
    sys.stdout = real_stdout
    print(json.dumps({"status": status, "times": times}), flush=True)
    sys.stdout.flush()
    os._exit(0)  # bpy 4.2's exit handlers crash once the add-on registered (see __main__)


def sphere_triangles(segments: int) -> int:
    """Triangles of Blender's UV sphere of ``segments`` segments and half as many rings: quads
    between the rings, triangle fans at the poles."""
    return segments * 2 * (segments // 2 - 1)


def make_heavy(path: str, segments: int) -> None:
    """The heavy scene: a UV sphere (512 segments: 261k triangles) at (0.5, 0.2, 0)c, a sun, 320x240."""
    sys.path[:0] = [str(ROOT), str(ROOT / "sample_blends")]
    import bpy
    import samplelib as lib

    lib.ensure_registered()
    scene = lib.new_scene("Heavy sphere", 10.0, resolution=(320, 240), samples=1)
    lib.add_camera(scene, (0.0, -10.0, 0.0), (90.0, 0.0, 0.0), angle_deg=40.0)
    lib.add_light(scene, "Sun", 'SUN', (0, 0, 10), power=3.0, rotation_deg=(40.0, 0.0, 20.0))
    bpy.ops.mesh.primitive_uv_sphere_add(segments=segments, ring_count=segments // 2, radius=2.0)
    sphere = bpy.context.active_object
    sphere.restframe.velocity = (0.5, 0.2, 0.0)
    sphere.data.materials.append(lib.material("Sphere", (0.8, 0.5, 0.3)))
    bpy.ops.wm.save_as_mainfile(filepath=path)
    sys.stdout.flush()
    os._exit(0)


def render_frames(blend: str, frames: str, persistent: bool) -> list[dict]:
    """The frames rendered by a fresh process through the command line; each frame's step times."""
    with tempfile.TemporaryDirectory(prefix="restframe-persist-") as out:
        done = subprocess.run([sys.executable, __file__, "--worker", blend, frames, out, str(int(persistent))],
                              capture_output=True, text=True, timeout=3600)
    lines = [line for line in done.stdout.splitlines() if line.startswith("{")]
    if done.returncode or not lines or json.loads(lines[-1])["status"]:
        raise SystemExit(f"the worker failed on {blend}:\n{done.stderr[-3000:]}")
    return json.loads(lines[-1])["times"]


def summary(runs: list[list[dict]]) -> dict:
    """Per run: frames 2..N's mean frame time / frame 1's; and the mean of every step (ms)."""
    ratios = [statistics.fmean(f["frame"] for f in times[1:]) / times[0]["frame"] for times in runs]
    first = {step: statistics.median(times[0][step] for times in runs) * 1e3 for step in STEPS}
    later = {step: statistics.median(statistics.fmean(f[step] for f in times[1:]) for times in runs) * 1e3
             for step in STEPS}
    return {"ratios": ratios, "first": first, "later": later}


def scene_report(sec: Section, name: str, results: dict[bool, dict]) -> float:
    """One scene's ratios and step times; returns the median ratio with persistent data."""
    sec.add(f"### {name}")
    sec.add()
    for persistent, label in ((True, "persistent data (default)"), (False, "--no-persistent-data")):
        r = results[persistent]
        ratios = ", ".join(f"{x:.2f}" for x in r["ratios"])
        sec.add(f"- {label}: frames 2..N / frame 1 = {ratios} (median {statistics.median(r['ratios']):.2f})")
    sec.add()
    rows = []
    for persistent, label in ((True, "persistent"), (False, "fresh")):
        for which in ("first", "later"):
            row = results[persistent][which]
            title = f"{label}, frame 1" if which == "first" else f"{label}, frames 2..N (mean)"
            rows.append([title, *(f"{row[step]:.0f}" for step in STEPS),
                         f"{row['engine'] - row['export'] - row['prepare']:.0f}"])
    sec.table(["ms, median over runs", *STEPS, "tiles (engine - export - prepare)"], rows)
    return statistics.median(results[True]["ratios"])


def run(ctx: Context, repeats: int | None = None, frames: str | None = None, heavy_frames: str | None = None,
        heavy: bool = True) -> Section:
    """Section 11 of the report: the bars' animation and, unless not ``heavy``, the heavy sphere's."""
    repeats = repeats or ctx.pick(3, 1)
    frames = frames or ctx.pick("1-25", "1-2")
    heavy_frames = heavy_frames or ctx.pick("1-6", "1-2")
    segments = ctx.pick(HEAVY_SEGMENTS, 32)
    sec = Section("11. Persistent data across frames")
    sec.add_paragraphs(__doc__.split("\n\n", 2)[2])  # after the title and the commands
    sec.add(f"{repeats} runs per scene and mode; load average {os.getloadavg()[0]:.2f} at the start, {os.cpu_count()} cores.")
    sec.add()
    with tempfile.TemporaryDirectory(prefix="restframe-heavy-") as scratch:
        scenes = [("11x11 bars (bars_sideways.blend)", "11x11 bars", str(BARS), frames)]
        if heavy:
            path = os.path.join(scratch, "heavy.blend")
            subprocess.run([sys.executable, __file__, "--make-heavy", path, str(segments)], capture_output=True,
                           timeout=600, check=True)
            triangles = sphere_triangles(segments)
            scenes.append((f"{triangles / 1e3:.0f}k-triangle sphere at (0.5, 0.2, 0)c", f"{triangles / 1e3:.0f}k-triangle sphere",
                           path, heavy_frames))
        for name, short, blend, scene_frames in scenes:
            ctx.log(f"  {name}, frames {scene_frames}")
            runs: dict[bool, list] = {True: [], False: []}
            for _ in range(repeats):
                for persistent in (True, False):
                    runs[persistent].append(render_frames(blend, scene_frames, persistent))
            results = {persistent: summary(times) for persistent, times in runs.items()}
            later = scene_report(sec, f"{name}, frames {scene_frames}", results)
            fresh = statistics.median(results[False]["ratios"])
            key = short.split()[0].replace("-", "_")
            sec.number(f"later_over_first_{key}", later)
            sec.number(f"later_over_first_fresh_{key}", fresh)
            sec.goals.append(Goal(f"frames 2..N / frame 1 with persistent data, {short} (frames {scene_frames})",
                                  f"<= {LATER_GOAL:g}", f"{later:.2f} (median of {repeats}; without: {fresh:.2f})",
                                  later <= LATER_GOAL))
    sec.add(f"Load average at the end: {' '.join(f'{x:.1f}' for x in os.getloadavg())}.")
    return sec


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=3, help="runs per scene and mode (default 3)")
    parser.add_argument("--frames", default="1-25",
                        help="frames of the bars animation (default 1-25, the file's range)")
    parser.add_argument("--heavy-frames", default="1-6", help="frames of the heavy sphere (default 1-6)")
    parser.add_argument("--no-heavy", action="store_true", help="only the bars")
    parser.add_argument("--worker", nargs=4, help=argparse.SUPPRESS)
    parser.add_argument("--make-heavy", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        blend, frames, out, persistent = args.worker
        worker(blend, frames, out, persistent == "1")
    if args.make_heavy:
        make_heavy(args.make_heavy[0], int(args.make_heavy[1]))
    print(f"# bench_persistent: {time.strftime('%Y-%m-%d %H:%M:%S %Z')}")
    print_section(run(standalone_context(False), args.repeats, args.frames, args.heavy_frames, not args.no_heavy))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""How long Esc takes to stop a heavy render, per stage (issue 9).  Not part of the test run.

    tools/dev.sh tests/robustness/measure_cancel.py [--subdivisions 708]

A 1M-triangle grid at 0.5c (as measure_memory.py), 1920x1080 at 16 samples, rendered through the
engine (bpy.ops.render.render) with Esc simulated at several moments (``should_stop`` patched to turn
true then).  Prints, per moment, the stage that was running and the seconds from Esc to the return
(Blender polls ``test_break`` through ``should_stop``; a stage that does not poll delays the stop).
"""

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from big_grid import build_grid_scene  # noqa: E402


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--subdivisions", type=int, default=708)
    parser.add_argument("--at", type=float, nargs="*", default=[0.2, 1.0, 3.0, 8.0, 14.0])
    args = parser.parse_args()
    import bpy

    import restframe_addon
    from restframe_addon import engine

    restframe_addon.register()
    scene = build_grid_scene(args.subdivisions)
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 1920, 1080, 100
    scene.restframe.samples = 16
    state = {}

    def staged(name, function):
        def wrapper(*a, **k):
            state["stages"].append((time.monotonic(), name))
            return function(*a, **k)
        return wrapper

    engine.export.export_scene = staged("export", engine.export.export_scene)
    engine.prepare = staged("building frames and BVH", engine.prepare)
    engine.render_tiles = staged("tiles", engine.render_tiles)
    for at in args.at:
        state.update(start=time.monotonic(), seen=None, stages=[])

        def should_stop(self):
            if time.monotonic() - state["start"] >= at:
                state["seen"] = state["seen"] or time.monotonic()
                return True
            return False

        engine.RestframeRenderEngine.should_stop = should_stop
        state["start"] = time.monotonic()
        bpy.ops.render.render()
        end = time.monotonic()
        esc = state["start"] + at
        stage = ([name for t, name in state["stages"] if t <= esc] or ["before export"])[-1]
        if end <= esc:
            print(f"Esc at {at:5.1f} s: the render had already ended after {end - state['start']:.1f} s")
            continue
        print(f"Esc at {at:5.1f} s during {stage}: render returned {end - esc:.2f} s later", flush=True)


if __name__ == "__main__":
    main()

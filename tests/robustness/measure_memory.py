"""Peak memory of a 4K frame of a 1M-triangle scene at 16 samples (issue 9), through the engine's path.

    tools/dev.sh tests/robustness/measure_memory.py [--tiles N] [--subdivisions 708]

Builds a 1,002,528-triangle grid moving at 0.5c with bpy, exports it (export_scene), prepares it
(prepare: rest frames, embree BVH) and streams the 3840x2160 frame's 64x64 tiles at 16 samples,
one thread, exactly as the render engine does (tiles go to Blender's render result, never into one
big array).  ``--tiles N`` stops after N tiles (0 = the whole frame): memory per tile is constant, so
the peak after a few hundred tiles is the peak of the frame; the script prints the RSS after every
stage and the time per tile so the full-frame time can be extrapolated.  Prints one final line:
``peak_rss_mb=...``.  Not part of the test run (minutes).  Blender's own render result for the
frame (added by Blender, not RESTframe) is reported as a computed figure.
"""

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from big_grid import build_grid_scene, rss_mb  # noqa: E402


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--tiles", type=int, default=400, help="tiles to render (0 = all 2040)")
    parser.add_argument("--subdivisions", type=int, default=708)
    parser.add_argument("--samples", type=int, default=16)
    args = parser.parse_args()

    import bpy

    import restframe_addon
    from restframe_addon import export
    from restframe_addon.core.passes import ALL_PASSES
    from restframe_addon.core.prepared import prepare
    from restframe_addon.core.render import render_tiles

    restframe_addon.register()
    t0 = time.perf_counter()
    scene = build_grid_scene(args.subdivisions)
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 3840, 2160, 100
    scene.restframe.samples = args.samples
    scene.render.threads_mode, scene.render.threads = 'FIXED', 1
    depsgraph = bpy.context.evaluated_depsgraph_get()
    print(f"scene built: {time.perf_counter() - t0:.1f} s, rss {rss_mb('VmRSS:'):.0f} MB, peak {rss_mb():.0f} MB",
          flush=True)

    t0 = time.perf_counter()
    core_scene, settings = export.export_scene(depsgraph, warn=lambda m: print("warning:", m))
    triangles = sum(len(m.triangles) for m in core_scene.meshes)
    print(f"export: {triangles} triangles, {time.perf_counter() - t0:.1f} s, peak {rss_mb():.0f} MB", flush=True)
    t0 = time.perf_counter()
    prepared = prepare(core_scene, settings)
    print(f"prepare (frames, BVH): {time.perf_counter() - t0:.1f} s, peak {rss_mb():.0f} MB", flush=True)
    total = len(prepared.tiles())
    limit = args.tiles or total
    t0 = time.perf_counter()
    count = 0
    for tile in render_tiles(prepared, lambda: count >= limit):
        count += 1
        if count in (1, 10) or count % 100 == 0 or count == limit:
            print(f"tile {count}/{total}: {time.perf_counter() - t0:.1f} s, rss {rss_mb('VmRSS:'):.0f} MB, "
                  f"peak {rss_mb():.0f} MB", flush=True)
    seconds = time.perf_counter() - t0
    result_mb = 3840 * 2160 * sum(ALL_PASSES.values()) * 4 / 2**20
    print(f"rendered {count} of {total} tiles at {settings.samples} samples in {seconds:.1f} s "
          f"({seconds / count:.2f} s per tile, full frame ~{seconds / count * total / 60:.0f} min on one thread)")
    print(f"Blender's render result for all passes at 4K (float32, allocated by Blender): {result_mb:.0f} MB")
    print(f"peak_rss_mb={rss_mb():.0f}")


if __name__ == "__main__":
    main()

"""Subprocess of the benchmark: build a big grid with bpy, export it, prepare and render it.

    python tests/bench/bench_export_worker.py SUBDIVISIONS   -> one JSON line on stdout
"""

import json
import sys
import time
import tracemalloc
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path[:0] = [str(ROOT), str(ROOT / "tests" / "robustness")]

from big_grid import build_grid_scene, rss_mb  # noqa: E402


def main():
    subdivisions = int(sys.argv[1])
    import bpy

    import restframe_addon
    from restframe_addon import export
    from restframe_addon.core.prepared import prepare
    from restframe_addon.core.render import render_image

    restframe_addon.register()
    t0 = time.perf_counter()
    build_grid_scene(subdivisions, camera_location=(0.0, -12.0, 8.0))
    depsgraph = bpy.context.evaluated_depsgraph_get()
    depsgraph.update()
    build = time.perf_counter() - t0
    rss_built = rss_mb()

    # times without tracemalloc (it slows numpy-heavy code 7-20x here), then the same steps again traced
    t0 = time.perf_counter()
    core_scene, settings = export.export_scene(depsgraph, resolution=(64, 48), warn=lambda m: None)
    export_s = time.perf_counter() - t0
    rss_export = rss_mb()
    settings.threads = 1
    t0 = time.perf_counter()
    prepared = prepare(core_scene, settings)
    prepare_s = time.perf_counter() - t0
    rss_prepare = rss_mb()
    del prepared, core_scene
    tracemalloc.start()
    core_scene, settings = export.export_scene(depsgraph, resolution=(64, 48), warn=lambda m: None)
    export_peak = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.reset_peak()
    settings.threads = 1
    prepared = prepare(core_scene, settings)
    prepare_peak = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
    del prepared
    t0 = time.perf_counter()
    render_image(core_scene, settings)
    render_s = time.perf_counter() - t0
    triangles = sum(len(m.triangles) for m in core_scene.meshes)
    print(json.dumps({"triangles": triangles, "build_s": build, "export_s": export_s, "export_peak_mb": export_peak,
                      "prepare_s": prepare_s, "prepare_peak_mb": prepare_peak, "render_s": render_s,
                      "rss_built_mb": rss_built, "rss_export_mb": rss_export, "rss_prepare_mb": rss_prepare,
                      "rss_render_mb": rss_mb()}))


if __name__ == "__main__":
    main()

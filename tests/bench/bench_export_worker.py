"""Subprocess of the benchmark: build a big grid with bpy, export it, prepare and render it.

    python tests/bench/bench_export_worker.py SUBDIVISIONS   -> one JSON line on stdout
"""

import json
import resource
import sys
import time
import tracemalloc
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))


def rss_mb():
    """Peak resident memory of this process (VmHWM: unlike ru_maxrss it does not inherit the parent's
    peak across fork + exec)."""
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024.0
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def main():
    subdivisions = int(sys.argv[1])
    import bpy

    import restframe_addon
    from restframe_addon import export
    from restframe_addon.core.render import Renderer, render_image

    restframe_addon.register()
    t0 = time.perf_counter()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = 'RESTFRAME'
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=subdivisions, y_subdivisions=subdivisions, size=10.0)
    grid = bpy.context.active_object
    grid.restframe.velocity = (0.5, 0.0, 0.0)
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    cam.location = (0.0, -12.0, 8.0)
    cam.rotation_euler = (0.9, 0.0, 0.0)
    scene.collection.objects.link(cam)
    scene.camera = cam
    lamp = bpy.data.objects.new("Lamp", bpy.data.lights.new("Lamp", 'POINT'))
    lamp.location = (2.0, -2.0, 5.0)
    scene.collection.objects.link(lamp)
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
    renderer = Renderer(core_scene, settings)
    prepare_s = time.perf_counter() - t0
    rss_prepare = rss_mb()
    del renderer, core_scene
    tracemalloc.start()
    core_scene, settings = export.export_scene(depsgraph, resolution=(64, 48), warn=lambda m: None)
    export_peak = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.reset_peak()
    settings.threads = 1
    renderer = Renderer(core_scene, settings)
    prepare_peak = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
    del renderer
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

"""Path Tracing against Cycles at rest, equal noise: the Cornell box of tests/blender/test_blender_path.py.

    tools/dev.sh tests/bench/bench_path_cycles.py SIZE SAMPLES REFERENCE_SAMPLES   (e.g. 32 64 1024)

Each engine renders SAMPLES and REFERENCE_SAMPLES per pixel (same bounce limits, box pixels, CPU,
2 threads); the error is the relative RMSE against the engine's own reference; the time ratio at
equal noise assumes error ~ time^-1/2.
"""
import sys, pathlib, tempfile, time
sys.path[:0] = [str(__import__("pathlib").Path(__file__).resolve().parents[1] / "blender")]
import numpy as np, bpy, restframe_addon
restframe_addon.register()
import test_blender_path as t
from blender_helpers import render_rgba
scene = t.cornell_box()
size = int(sys.argv[1]); spp = int(sys.argv[2]); ref_spp = int(sys.argv[3])
tmp = pathlib.Path(tempfile.mkdtemp())
t.SIZE = size
t.render_pair(scene, tmp, samples=1, bounces=4, seeds=(1,))  # set everything up (and warm caches)
out = {}
for engine in ("CYCLES", "RESTFRAME"):
    scene.render.engine = engine
    for n in (spp, ref_spp):
        if engine == "CYCLES": scene.cycles.samples = n; scene.cycles.seed = 7 if n == ref_spp else 3
        else: scene.restframe.samples = n
        t0 = time.perf_counter(); img = render_rgba(scene, tmp / f"{engine}{n}.exr")[..., :3]; dt = time.perf_counter() - t0
        out[(engine, n)] = (img, dt)
for engine in ("CYCLES", "RESTFRAME"):
    img, dt = out[(engine, spp)]; ref, dref = out[(engine, ref_spp)]
    err = np.sqrt(np.mean((img - ref) ** 2)) / ref.mean()
    print(engine, f"{spp} spp {dt:.2f} s rel RMSE {err:.4f}; ref {ref_spp} spp {dref:.2f} s")
    out[engine] = (err, dt)
(ec, tc), (er, tr) = out["CYCLES"], out["RESTFRAME"]
print("time at equal noise RESTframe / Cycles:", tr * (er / ec) ** 2 / tc)
print("references differ (rel):", np.sqrt(np.mean((out[('CYCLES', ref_spp)][0] - out[('RESTFRAME', ref_spp)][0])**2)) / out[('CYCLES', ref_spp)][0].mean())

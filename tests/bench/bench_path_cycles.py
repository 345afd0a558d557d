"""Path Tracing against Cycles at rest, equal noise: the Cornell box of tests/blender/test_blender_path.py.

    tools/dev.sh tests/bench/bench_path_cycles.py SIZE SAMPLES REFERENCE_SAMPLES   (e.g. 32 64 1024)

Each engine renders SAMPLES and REFERENCE_SAMPLES per pixel (same bounce limits, box pixels, CPU,
2 threads); the error is the relative RMSE against the engine's own reference; the time ratio at
equal noise assumes error ~ time^-1/2.
"""

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path[:0] = [str(ROOT), str(ROOT / "tests" / "blender")]


def main():
    import restframe_addon
    import test_blender_path as path_tests
    from blender_helpers import render_rgba

    size, samples, reference_samples = (int(a) for a in sys.argv[1:4])
    restframe_addon.register()
    scene = path_tests.cornell_box()
    folder = Path(tempfile.mkdtemp())
    path_tests.SIZE = size
    path_tests.render_pair(scene, folder, samples=1, bounces=4, seeds=(1,))  # both engines set up alike
    results = {}
    for engine in ("CYCLES", "RESTFRAME"):
        scene.render.engine = engine
        images = {}
        for count in (samples, reference_samples):
            if engine == "CYCLES":
                scene.cycles.samples, scene.cycles.seed = count, 7 if count == reference_samples else 3
            else:
                scene.restframe.samples = count
            started = time.perf_counter()
            images[count] = render_rgba(scene, folder / f"{engine}{count}.exr")[..., :3], time.perf_counter() - started
        (image, seconds), (reference, reference_seconds) = images[samples], images[reference_samples]
        error = float(np.sqrt(np.mean((image - reference) ** 2)) / reference.mean())
        results[engine] = error, seconds, reference
        print(f"{engine}: {samples} spp {seconds:.2f} s, rel. RMSE {error:.4f}; "
              f"{reference_samples} spp {reference_seconds:.2f} s")
    cycles_error, cycles_seconds, cycles_reference = results["CYCLES"]
    error, seconds, reference = results["RESTFRAME"]
    print(f"time at equal noise, RESTframe / Cycles: {seconds * (error / cycles_error) ** 2 / cycles_seconds:.2f}")
    difference = np.sqrt(np.mean((reference - cycles_reference) ** 2)) / cycles_reference.mean()
    print(f"the references differ by a relative RMSE of {difference:.4f}")


if __name__ == "__main__":
    main()

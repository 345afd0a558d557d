"""Peak memory of a prepare + one small render of a scene with an 8192x4096 float32 environment
and two 4096^2 textures, in this process (Path Tracing) and in an unpickled copy (a worker):
    tools/dev.sh tools/texel_memory.py [raw]   ("raw": the images as plain arrays, as before)"""
import pickle
import resource
import sys
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]  # the checkout, whatever the working directory
sys.path[:0] = [str(ROOT), str(ROOT / "tests" / "core")]
from shapes import look_at_camera, quad  # noqa: E402

from restframe_addon.core.prepared import prepare  # noqa: E402
from restframe_addon.core.render import render_tile  # noqa: E402
from restframe_addon.core.scene import Material, Mesh, RenderSettings, Scene, WorldTexture  # noqa: E402

try:
    from restframe_addon.core.world import texel_image
except ImportError:
    texel_image = None
raw = len(sys.argv) > 1 or texel_image is None
layout = (lambda a: a) if raw else texel_image
rng = np.random.default_rng(0)
tracemalloc.start()
images = [layout(rng.random((4096, 4096, 3), dtype=np.float32)) for _ in range(2)]
environment = layout(rng.random((4096, 8192, 3), dtype=np.float32))
held = tracemalloc.get_traced_memory()[0]
tracemalloc.reset_peak()
materials = [Material("a", base_color_texture=images[0]), Material("b", base_color_texture=images[1])]
meshes = [Mesh("a", *quad(center=(-1, 0, 0))), Mesh("b", *quad(center=(1, 0, 0)), material_indices=np.ones(2, int))]
scene = Scene(camera=look_at_camera((0, -3, 2), (0, 0, 0)), meshes=meshes, materials=materials,
              world_texture=WorldTexture(environment, strength=1.5))
settings = RenderSettings(resolution=(16, 16), samples=1, integrator="PATH")
prepared = prepare(scene, settings)
render_tile(prepared, prepared.region)
now, peak = tracemalloc.get_traced_memory()
print(f"{'raw' if raw else 'texel'}: images {held / 2**20:.0f} MiB; parent prepared+render: "
      f"held {now / 2**20:.0f} MiB, peak {peak / 2**20:.0f} MiB")
payload = pickle.dumps(prepared, protocol=pickle.HIGHEST_PROTOCOL)
del prepared, scene, materials, images, environment
tracemalloc.stop()
tracemalloc.start()
worker = pickle.loads(payload)
del payload
render_tile(worker, worker.region)
now, peak = tracemalloc.get_traced_memory()
print(f"   worker unpickle+render: held {now / 2**20:.0f} MiB, peak {peak / 2**20:.0f} MiB; "
      f"ru_maxrss {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB")

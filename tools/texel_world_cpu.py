"""Run from the clone, base worktree at /tmp/texmem-base (git worktree add /tmp/texmem-base 26ff983):
CPU time of EnvironmentWorld.radiance (strength 1.5 and 1) on a 1024x2048 float32 image, before
(/tmp/texmem-base) and after (this clone), interleaved, min of 7 repeats of 20 calls of 2^18 rays."""
import importlib.util, sys, time
import numpy as np
def load(root):
    for name in [m for m in sys.modules if m.startswith("restframe_addon")]:
        del sys.modules[name]
    sys.path.insert(0, root)
    import restframe_addon.core.world as world
    sys.path.pop(0)
    return world
rng = np.random.default_rng(0)
image = rng.random((1024, 2048, 3), dtype=np.float32)
d = rng.normal(size=(1 << 18, 3)); d /= np.linalg.norm(d, axis=1)[:, None]
worlds = {}
for label, root in (("before", "/tmp/texmem-base"), ("after", ".")):
    w = load(root)
    worlds[label] = {s: w.EnvironmentWorld(image, s) for s in (1.5, 1.0)}
assert all(np.array_equal(worlds["before"][s].radiance(d), worlds["after"][s].radiance(d)) for s in (1.5, 1.0))
best = {}
for _ in range(7):
    for label in ("before", "after"):
        for s, world in worlds[label].items():
            t = time.process_time()
            for _ in range(20):
                world.radiance(d)
            best[label, s] = min(best.get((label, s), 1e9), time.process_time() - t)
for s in (1.5, 1.0):
    print(f"strength {s}: before {best['before', s]:.3f} s, after {best['after', s]:.3f} s, "
          f"ratio {best['after', s] / best['before', s]:.3f}")

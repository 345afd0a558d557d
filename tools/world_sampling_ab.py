"""An environment's importance sampling before (a base checkout) and after (this one), in one run:

    git worktree add /tmp/base origin/main
    tools/dev.sh tools/world_sampling_ab.py /tmp/base            # bits, CPU, world-lit renders
    tools/dev.sh tools/world_sampling_ab.py /tmp/base --size 1024 2048

1. Bits: ``EnvironmentWorld.sample`` of 2M random number pairs and ``pdf`` of the sampled directions,
   Linear and Closest, on random HDRIs (pixels ``random^8 x 50`` and a 1e5 sun) of three sizes: whether
   the directions are bit-identical, and the largest relative difference of the densities.
2. CPU seconds (this process, one thread, interleaved, min of 5) of building the sampling map of a
   float32 environment (default 8192x4096, Linear), of 8 x 2^20 samples and 8 x 2^20 pdf lookups.
3. Renders (each checkout in its own process): a moving matte ball over a glossy floor under a rotated
   HDRI with a sun, Path Tracing and Direct Light, Linear and Closest, 48x36, 16 samples; every pass
   compared (float32 images, as saved).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve()
ROOT = HERE.parents[1]


def _world_module(root: str):
    """``restframe_addon.core.world`` of the checkout at ``root``, imported afresh."""
    for name in [name for name in sys.modules if name.startswith("restframe_addon")]:
        del sys.modules[name]
    sys.path.insert(0, root)
    import restframe_addon.core.world as world
    sys.path.pop(0)
    return world


def _hdri(rng, shape):
    image = (rng.random(shape + (3,), dtype=np.float32) ** 8) * 50
    image[3, 7] = 1e5
    return image


def compare_bits(modules: dict) -> None:
    rng = np.random.default_rng(5)
    for shape in ((96, 200), (1024, 2048), (2048, 4096)):
        image = _hdri(rng, shape)
        for interpolation in ("Linear", "Closest"):
            before, after = (modules[side].EnvironmentWorld(image, 1.5, interpolation=interpolation)
                             for side in ("before", "after"))
            u1, u2 = rng.random(2_000_000), rng.random(2_000_000)
            (d_before, pdf_before), (d_after, pdf_after) = before.sample(u1, u2), after.sample(u1, u2)
            relative = np.abs(pdf_after - pdf_before) / np.maximum(pdf_before, 1e-300)
            pdf_of_before = before.pdf(d_before)
            looked_up = np.abs(after.pdf(d_before) - pdf_of_before) / np.maximum(pdf_of_before, 1e-300)
            print(f"{shape[0]}x{shape[1]} {interpolation}: directions bit-identical {np.array_equal(d_before, d_after)}; "
                  f"densities differing {np.count_nonzero(pdf_before != pdf_after)} of {len(u1)}, largest relative "
                  f"difference {relative.max():.2g} (pdf(): {looked_up.max():.2g})")


def compare_cpu(modules: dict, shape) -> None:
    rng = np.random.default_rng(2)
    image = rng.random(tuple(shape) + (3,), dtype=np.float32)
    u1, u2 = rng.random(1 << 20), rng.random(1 << 20)
    d = rng.normal(size=(1 << 20, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    best = {}
    for repeat in range(5):
        for side in (("before", "after") if repeat % 2 == 0 else ("after", "before")):
            t0 = time.process_time()
            world = modules[side].EnvironmentWorld(image, 1.5)
            steps = {"build": time.process_time() - t0}
            for step, call in (("sample", lambda: world.sample(u1, u2)), ("pdf", lambda: world.pdf(d))):
                t0 = time.process_time()
                for _ in range(8):
                    call()
                steps[step] = time.process_time() - t0
            for step, seconds in steps.items():
                best[side, step] = min(best.get((side, step), np.inf), seconds)
            del world
    print(f"{shape[0]}x{shape[1]} float32, Linear; CPU s, min of 5 interleaved")
    print("| | build | 8 x 2^20 samples | 8 x 2^20 pdf |\n|---|---|---|---|")
    for side in ("before", "after"):
        print(f"| {side} | " + " | ".join(f"{best[side, step]:.3f}" for step in ("build", "sample", "pdf")) + " |")


def render(root: str, out: str) -> None:
    """The world-lit scenes' passes rendered by the checkout at ``root``, saved to ``out`` (.npz)."""
    sys.path[:0] = [root, root + "/tests/core"]
    from shapes import look_at_camera, quad, uv_sphere

    from restframe_addon.core.render import render_image
    from restframe_addon.core.scene import Material, Mesh, RenderSettings, Scene, Velocity, WorldTexture

    rng = np.random.default_rng(3)
    image = (rng.random((128, 256, 3)) ** 6 * 4).astype(np.float32)
    image[40:43, 60:64] = 3e3
    meshes = [Mesh("ball", *uv_sphere(radius=1.0, segments=32, rings=16), velocity=Velocity((0.5, 0.2, 0.0))),
              Mesh("floor", *quad((0, 0, -1.2), (8, 8)), material_indices=np.ones(2, int))]
    materials = [Material("matte", base_color=(0.8, 0.7, 0.6), roughness=1.0),
                 Material("gloss", base_color=(0.3, 0.4, 0.5), roughness=0.3, metallic=0.5)]
    passes = {}
    for interpolation in ("Linear", "Closest"):
        world = WorldTexture(image, strength=1.3, rotation=(0.2, 0.1, 0.7), interpolation=interpolation)
        scene = Scene(camera=look_at_camera((0, -5, 1.5), (0, 0, -0.3)), meshes=meshes, materials=materials,
                      world_texture=world)
        for integrator in ("PATH", "DIRECT"):
            settings = RenderSettings(resolution=(48, 36), samples=16, integrator=integrator, threads=1)
            for name, array in render_image(scene, settings).items():
                passes[f"{interpolation} {integrator} {name}"] = array
    np.savez(out, **passes)


def compare_renders(base: str) -> None:
    with tempfile.TemporaryDirectory() as folder:
        saved = {}
        for side, root in (("before", base), ("after", str(ROOT))):
            saved[side] = str(Path(folder) / f"{side}.npz")
            subprocess.run([sys.executable, str(HERE), "--render", root, saved[side]], check=True)
        before, after = np.load(saved["before"]), np.load(saved["after"])
        differing = [name for name in before.files if not np.array_equal(before[name], after[name])]
        print(f"world-lit renders: {len(before.files) - len(differing)} of {len(before.files)} passes bit-identical"
              + "".join(f"; {name}: largest difference {np.abs(before[name] - after[name]).max():.2g}"
                        for name in differing))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("base", nargs="?", help="the checkout to compare against (a git worktree)")
    parser.add_argument("--size", type=int, nargs=2, default=(4096, 8192), metavar=("H", "W"))
    parser.add_argument("--render", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.render:
        render(*args.render)
        return 0
    if args.base is None:
        parser.error("the base checkout is needed")
    modules = {"before": _world_module(str(Path(args.base).resolve())), "after": _world_module(str(ROOT))}
    compare_bits(modules)
    compare_cpu(modules, args.size)
    compare_renders(args.base)
    return 0


if __name__ == "__main__":
    sys.exit(main())

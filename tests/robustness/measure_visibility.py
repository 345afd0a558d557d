"""What holdout, ray visibility and cut-outs cost the direct-light renderer.  Not part of the test run.

    tools/dev.sh tests/robustness/measure_visibility.py [--size 160] [--samples 4]

A 20k-triangle ball at 0.5c over a floor, a sun and a point lamp, rendered by the core (one thread)
as it is, and with one feature at a time on the ball: holdout, hidden from the camera, hidden from
shadow rays, 10 hidden sheets in front of the camera, and alpha 0.5 (camera and shadow rays decide
by chance).  Prints seconds per frame (best of three) and the ratio to the plain scene.
"""

import argparse
import dataclasses
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "core"))

from shapes import look_at_camera, quad, uv_sphere  # noqa: E402

from restframe_addon.core.render import render_image  # noqa: E402
from restframe_addon.core.scene import (RAY_ALL, RAY_CAMERA, RAY_SHADOW, Light, Material, Mesh,  # noqa: E402
                                        RenderSettings, Scene, Velocity)


def scene(**ball):
    sphere = Mesh("ball", *uv_sphere((0, 0, 1.0), 1.0, 128, 80), velocity=Velocity((0.5, 0, 0)), **ball)
    floor = Mesh("floor", *quad((0, 0, 0), (40, 40)), material_indices=[1, 1])
    return Scene(camera=look_at_camera((0, -6, 3), (0, 0, 1)), meshes=[sphere, floor],
                 materials=[Material("ball", base_color=(0.8, 0.3, 0.2)), Material("floor")],
                 lights=[Light("sun", "SUN", (0, 0, 9), power=3.0), Light("lamp", "POINT", (2, -2, 4))])


def timed(render, repeats=3):
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        render()
        best = min(best, time.perf_counter() - start)
    return best


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--size", type=int, default=160)
    parser.add_argument("--samples", type=int, default=4)
    args = parser.parse_args()
    settings = RenderSettings(resolution=(args.size, args.size * 3 // 4), samples=args.samples, threads=1)
    sheets = [Mesh(f"sheet{i}", *quad((0, -4.0 + 0.1 * i, 1.5), (8, 8), normal_axis=1), visibility=RAY_ALL & ~RAY_CAMERA)
              for i in range(10)]
    plain = scene()
    cases = {
        "plain": plain,
        "holdout": scene(holdout=True),
        "hidden from camera": scene(visibility=RAY_ALL & ~RAY_CAMERA),
        "hidden from shadows": scene(visibility=RAY_ALL & ~RAY_SHADOW),
        "10 camera-hidden sheets": dataclasses.replace(plain, meshes=plain.meshes + sheets),
        "alpha 0.5": dataclasses.replace(plain, materials=[Material("ball", base_color=(0.8, 0.3, 0.2), alpha=0.5),
                                                          Material("floor")]),
    }
    reference = None
    for name, case in cases.items():
        seconds = timed(lambda: render_image(case, settings))
        reference = reference or seconds
        print(f"{name:>24}: {seconds:6.2f} s  x{seconds / reference:.2f}")


if __name__ == "__main__":
    main()

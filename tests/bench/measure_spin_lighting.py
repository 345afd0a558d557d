"""Measure the lighting approximation of spinning bodies (docs/motion.md).

A spinning surface is lit in the axis frame: the sunlight it receives is not aberrated
or Doppler-shifted by its own local speed v = omega x r.  In each point's momentary rest
frame the exact irradiance from a sun of strength S is S D^2 cos(theta'), with D and the
direction theta' from the boost by v.  This compares that with the axis-frame S cos(theta)
over the lit half of a unit sphere spinning about z under a sun along x, for several rim speeds.

    tools/dev.sh tests/bench/measure_spin_lighting.py
"""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from restframe_addon.core.lorentz import Boost  # noqa: E402


def irradiance_errors(rim_speed: float, points: int = 4000):
    rng = np.random.default_rng(1)
    normals = rng.normal(size=(points, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    sun = np.array([1.0, 0.0, 0.0])  # backward direction toward the sun, axis frame
    lit = normals @ sun > 0.05
    normals = normals[lit]
    axis_frame = normals @ sun  # cos(theta) in the axis frame
    exact = np.empty(len(normals))
    for i, n in enumerate(normals):
        velocity = np.cross([0.0, 0.0, rim_speed], n)  # unit sphere: r = n
        boost = Boost.from_velocity(tuple(velocity))
        d_local, w = boost.rays(sun[None])  # direction and s'/s of the sunlight in the point's frame
        doppler = w[0]  # light frame (axis) -> surface frame: D = s_surface / s_light
        # the normal is perpendicular to v, so the boost leaves it unchanged
        exact[i] = doppler**2 * max(float(d_local[0] @ n), 0.0)
    relative = np.abs(axis_frame - exact) / np.maximum(exact, 1e-12)
    return float(np.max(relative)), float(np.sqrt(np.mean(relative**2)))


def main():
    lines = ["| rim speed (c) | largest relative irradiance error | RMS over the lit side |", "|---|---|---|"]
    for v in (0.001, 0.01, 0.1, 0.3, 0.6, 0.9):
        worst, rms = irradiance_errors(v)
        lines.append(f"| {v:g} | {worst:.3g} | {rms:.3g} |")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

"""Pinhole camera rays: the arithmetic that leaves out zero terms gives the literal formula's bits."""

import numpy as np
import pytest
from shapes import look_at_camera

from restframe_addon.core.camera import CameraRays


def literal_rays(rays: CameraRays, u, v):
    """Directions and clip range of pinhole rays through image-plane points (corner + v up) + u across
    (world axes for the directions, camera depth for the range), every term computed."""
    points = [(corner + up * v) + across * u for corner, across, up in rays.world_plane]
    inverse = 1.0 / np.sqrt(points[0] * points[0] + np.square(points[1]) + np.square(points[2]))
    corner, across, up = rays.plane
    per_depth = -1.0 / (((corner[2] + up[2] * v) + across[2] * u) * inverse)
    return (np.stack([p * inverse for p in points], axis=1), rays.camera.clip_start * per_depth,
            rays.camera.clip_end * per_depth)


@pytest.mark.parametrize("plane", [None, ((-0.0, 0.0, -0.5), (0.0, 0.0, -0.0), (0.3, -0.2, 0.0)),
                                   ((-0.0, -1.0, 0.0), (0.0, 0.5, 0.25), (-0.7, 0.0, 0.0)),
                                   ((-0.5, 1.0, 0.0), (0.9, 0.0, 0.08), (-0.0, 1.0, 0.0))])
def test_pinhole_rays_are_the_bits_of_the_literal_formula(plane):
    """A camera without roll (zero components in its image plane: the terms left out), a rolled
    one (none), planes whose corners are 0 or -0 (where adding a zero could flip a sign), and
    one whose width lies along a world axis (a factor of 1 left out)."""
    camera = look_at_camera((0.3, -4.0, 1.2), (0.0, 0.0, 0.4))
    rays = CameraRays(camera, (64, 36))
    if plane is not None:
        rays.world_plane = [tuple(np.float64(c) for c in axis) for axis in plane]
    rng = np.random.default_rng(5)
    px, py = rng.uniform(0.0, 64.0, 500), rng.uniform(0.0, 36.0, 500)
    px[:3], py[:3] = 0.0, 0.0  # (u = v = 0: products that are 0)
    _, d, s_lo, s_hi, _ = rays(px, py)
    for got, want in zip((d, s_lo, s_hi), literal_rays(rays, px / 64, py / 36)):
        assert got.tobytes() == want.tobytes()
    rolled = CameraRays(look_at_camera((0.3, -4.0, 1.2), (0.0, 0.0, 0.4), up=(0.3, 0.1, 1.0)), (64, 36))
    assert plane is not None or all(across != 0.0 and up != 0.0 for _, across, up in rolled.world_plane)
    _, d, s_lo, s_hi, _ = rolled(px, py)
    for got, want in zip((d, s_lo, s_hi), literal_rays(rolled, px / 64, py / 36)):
        assert got.tobytes() == want.tobytes()


@pytest.mark.parametrize("up", [(0.0, 0.0, 1.0), (0.3, 0.1, 1.0)])
def test_run_bounds_hold_every_ray_through_the_runs_pixels_and_little_more(up):
    """A tile's run bounds (culled once for all its samples) hold the ray through any point of
    each run's pixels, pixel corners included, for a plain and a rolled camera, a share of a
    tile that starts on a run and stops inside one; they are not much wider than the rays' own."""
    from dataclasses import replace

    rays = CameraRays(look_at_camera((0.3, -4.0, 1.2), (0.0, 0.0, 0.4), up=up), (640, 360))
    rect, pixels = (16, 4, 48, 30), slice(48, 32 * 26 - 5)  # 32 pixels wide: two runs a row
    low, high = rays.run_bounds(rect, pixels, 16)
    count = (pixels.stop - pixels.start) // 16
    assert low.shape == high.shape == (3, count)
    index = np.arange(pixels.start, pixels.start + 16 * count)
    xs, ys, run = rect[0] + index % 32, rect[1] + index // 32, np.arange(16 * count) // 16
    rng = np.random.default_rng(3)
    seen_low, seen_high = np.full((3, count), np.inf), np.full((3, count), -np.inf)
    for jitter in [(0.0, 0.0), (1.0, 1.0), (1.0, 0.0), (0.0, 1.0)] + [None] * 40:
        jx, jy = (rng.uniform(0.0, 1.0, len(index)), rng.uniform(0.0, 1.0, len(index))) if jitter is None else jitter
        d = rays(xs + jx, ys + jy)[1].T
        assert np.all(d >= low[:, run]) and np.all(d <= high[:, run])
        for r in range(count):
            seen_low[:, r] = np.minimum(seen_low[:, r], d[:, run == r].min(axis=1))
            seen_high[:, r] = np.maximum(seen_high[:, r], d[:, run == r].max(axis=1))
    assert np.all(high - low <= 2.0 * (seen_high - seen_low) + 1e-6)  # (per axis of p, |p| bounded apart)
    assert rays.run_bounds(rect, slice(8, 64), 16) is None  # runs would span two rows
    assert rays.run_bounds((16, 4, 40, 30), slice(0, 48), 16) is None
    ortho = CameraRays(replace(rays.camera, kind="ORTHO"), (640, 360))
    assert ortho.run_bounds(rect, pixels, 16) is None

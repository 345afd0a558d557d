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

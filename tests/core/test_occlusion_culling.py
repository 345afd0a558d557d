"""Shadow rays are culled per ray against a moving body's box before they are mapped into its
frame (tracer._near_body): the cull may only drop rays that could not be blocked there."""

from __future__ import annotations

import numpy as np
import pytest
from shapes import box, look_at_camera, quad

from restframe_addon.core import tracer
from restframe_addon.core.frames import build_frames
from restframe_addon.core.scene import Mesh, Scene, Velocity

VELOCITY = np.array([0.6, -0.3, 0.2])
SIZE = np.array([1.0, 2.0, 0.5])
CENTRE = np.array([3.0, -2.0, 1.0])  # the box's centre at tau = 0 (its pivot)


def frames():
    v, t = box(CENTRE, SIZE)
    meshes = [Mesh("box", v, t, velocity=Velocity(tuple(VELOCITY)), pivot=tuple(CENTRE)), Mesh("floor", *quad((0.0, 0.0, -30.0), (4.0, 4.0)))]
    return build_frames(Scene(camera=look_at_camera((0.0, -8.0, 0.0), (0.0, 0.0, 0.0)), meshes=meshes))


def rays_past_the_box(count: int, seed: int, spread: float):
    """Backward rays (world frame) that pass the moving box at a random path length s* in
    [2, 8]: through a point of the box (widened by ``spread``) at the time tau0 - s*."""
    rng = np.random.default_rng(seed)
    tau0 = rng.uniform(-5.0, 5.0, count)
    s_star = rng.uniform(2.0, 8.0, count)
    d = rng.normal(size=(count, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    centre = CENTRE + np.outer(tau0 - s_star, VELOCITY)  # the box's centre at the time the ray passes it
    target = centre + rng.uniform(-0.5, 0.5, (count, 3)) * SIZE * spread
    return tau0, target - s_star[:, None] * d, d


@pytest.mark.parametrize("s_hi", [12.0, np.inf])
def test_culled_shadow_rays_are_exactly_those_that_could_not_be_blocked(monkeypatch, s_hi):
    frame_set = frames()
    tau0, x0, d = rays_past_the_box(20000, 1, spread=3.0)
    culled = []
    near_body = tracer._near_body

    def counting(*args):
        near = near_body(*args)
        culled.append(int(np.count_nonzero(~near)))
        return near

    monkeypatch.setattr(tracer, "_near_body", counting)
    blocked = tracer.occluded(frame_set, frame_set.world, tau0, x0, d, 1e-6, s_hi)
    monkeypatch.setattr(tracer, "_near_body", lambda *args: np.ones(len(args[6]), dtype=bool))
    every_ray_traced = tracer.occluded(frame_set, frame_set.world, tau0, x0, d, 1e-6, s_hi)
    assert np.array_equal(blocked, every_ray_traced)
    assert 0.05 < blocked.mean() < 0.8  # many rays blocked, many passing close by
    assert sum(culled) > 0.1 * len(d)  # and the cull did drop rays


def test_rays_grazing_the_body_are_kept():
    """Rays through the box's own surface at the time they pass it are never culled."""
    frame_set = frames()
    tau0, x0, d = rays_past_the_box(5000, 2, spread=1.0)
    k = next(k for k in frame_set.geometry if k != frame_set.world)
    s_lo, s_hi = np.full(len(d), 1e-6), np.full(len(d), 12.0)
    extent = (float(np.max(np.abs(x0))) + 50.0, float(np.max(np.abs(tau0))))
    near = tracer._near_body(frame_set, frame_set.world, k, None, extent, tau0, x0, d, s_lo, s_hi)
    assert near.all()
    far = tracer._near_body(frame_set, frame_set.world, k, None, extent, tau0, x0 + 50.0, d, s_lo, s_hi)
    assert not far.any()

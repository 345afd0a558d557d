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


def test_parallel_rays_clip_and_reach_bit_for_bit_as_rays_of_their_own():
    """A bundle along one broadcast direction (a sharp sun's) takes shortcuts: one inverse per axis
    for the bounds' slab test, its reach from the extremes of x0.  Both must give exactly the
    numbers of the same rays as contiguous rows of their own, whatever the signs of the direction;
    a direction with a 0 component takes the general test."""
    frame_set = frames()
    geometry = next(frame_set.frames[k].geometry for k in frame_set.geometry if k != frame_set.world)
    rng = np.random.default_rng(7)
    n = 300
    x0 = 0.5 * (geometry.lo + geometry.hi) + rng.uniform(-3.0, 3.0, (n, 3))
    tau0 = rng.uniform(-3.0, 3.0, n)
    t_lo, t_hi = tracer._per_ray(1e-4, n), tracer._per_ray(np.inf, n)
    # (the last: a subnormal component, whose inverse overflows)
    for direction, shortcut in (([0.3, -0.2, 0.9], True), ([-0.6, 0.5, -0.1], True), ([0.0, -0.6, 0.8], False),
                                ([-1e-310, 0.6, 0.8], False)):
        direction = np.array(direction) / np.linalg.norm(direction)
        one, own = np.broadcast_to(direction, (n, 3)), np.tile(direction, (n, 1))
        assert (tracer._one_inverse(one) is not None) == shortcut
        with np.errstate(over="ignore"):  # (the general test's 1 / d overflows for the subnormal component)
            enter, leave = tracer._clip_to_bounds(geometry, x0, one, t_lo, t_hi)
            plain = tracer._clip_to_bounds(geometry, x0, own, np.full(n, 1e-4), np.full(n, np.inf))
        np.testing.assert_array_equal(enter, plain[0])
        np.testing.assert_array_equal(leave, plain[1])
        assert 0 < np.count_nonzero(enter <= leave) < n  # rays both into and past the bounds
        fast = tracer._bundle_reach(tau0, x0, one, t_lo, t_hi)
        plain = tracer._bundle_reach(tau0, x0, own, np.full(n, 1e-4), np.full(n, np.inf))
        for field in ("lo", "hi", "earliest", "latest", "direction"):
            np.testing.assert_array_equal(getattr(fast, field), getattr(plain, field))


def test_a_kept_sun_direction_is_the_caches_own_array():
    """TraceCache.direction_in keeps a read-only array of its own, also where the map into the frame
    is the identity and hands back the caller's direction, which stays as the caller made it."""
    frame_set = frames()
    moving = next(k for k in frame_set.geometry if k != frame_set.world)
    cache = tracer.TraceCache()
    for k in (frame_set.world, moving):
        direction = np.array([0.3, -0.2, 0.9]) / np.linalg.norm([0.3, -0.2, 0.9])
        d_k, w = cache.direction_in(frame_set, frame_set.world, k, direction)
        want = tracer._direction_in(frame_set, frame_set.world, k, np.array(direction))
        assert direction.flags.writeable and d_k is not direction and not d_k.flags.writeable
        assert d_k.tobytes() == want[0].tobytes() and w == want[1]
        assert cache.direction_in(frame_set, frame_set.world, k, direction)[0] is d_k  # kept


class _CountingScene:
    """Stands in for a geometry's embree scene, counting the rays it is asked about."""

    def __init__(self, scene):
        self.scene, self.rays = scene, 0

    def run(self, origins, directions, **kwargs):
        self.rays += len(origins)
        return self.scene.run(origins, directions, **kwargs)


@pytest.mark.parametrize("axis, plane, side", [(2, 0.0, 1.0), (2, 0.0, -1.0), (0, 2.5, 1.0), (1, -30.0, -1.0)])
def test_shadow_rays_leaving_a_flat_body_ask_embree_nothing_and_none_is_blocked(monkeypatch, axis, plane, side):
    """Rays that start on one side of a flat body (every vertex at one coordinate) and run away
    from it cannot meet it (tracer._leave_flat_body): embree is not asked, and asked anyway it
    finds nothing, for starts from far off down to an ulp of the plane (1e-30 where the plane is
    at 0) and directions down to grazing ones.  One ray on the plane, or toward it, and the
    bundle is asked as before."""
    centre = np.zeros(3)
    centre[axis] = plane
    mesh = Mesh("floor", *quad(centre, (4.0, 6.0), normal_axis=axis))
    frame_set = build_frames(Scene(camera=look_at_camera((0.0, -8.0, 5.0), (0.0, 0.0, 0.0)), meshes=[mesh]))
    frame = frame_set.frames[frame_set.geometry[0]]
    rng = np.random.default_rng(11)
    n = 4000
    x0 = rng.uniform(-1.5, 1.5, (n, 3))
    height = np.maximum(10.0 ** rng.uniform(-30.0, 0.5, n), 4 * np.spacing(abs(plane)))
    x0[:, axis] = plane + side * height
    d = rng.normal(size=(n, 3))
    d[:, axis] = side * 10.0 ** rng.uniform(-6.0, 0.0, n)
    d /= np.linalg.norm(d, axis=1)[:, None]
    tau0 = rng.uniform(-1.0, 1.0, n)
    counting = _CountingScene(frame.geometry.embree)
    monkeypatch.setattr(frame.geometry, "embree", counting)
    s_lo, s_hi = np.zeros(n), np.full(n, np.inf)
    assert not tracer._query(frame, tau0, x0, d, s_lo, s_hi, occlusion=True).any()  # embree's own answer
    asked = counting.rays
    assert not tracer.occluded(frame_set, frame.index, tau0, x0, d, 0.0, np.inf, tracer.TraceCache()).any()
    assert counting.rays == asked  # not asked again
    x0[0, axis] = plane  # one ray on the plane, one straight toward it (and blocked)
    d[1] = 0.0
    d[1, axis] = -side
    blocked = tracer.occluded(frame_set, frame.index, tau0, x0, d, 0.0, np.inf, tracer.TraceCache())
    assert counting.rays > asked and blocked[1] and not blocked[2:].any()
    assert np.array_equal(blocked, tracer.occluded(frame_set, frame.index, tau0, x0, d, 0.0, np.inf))


def test_only_flat_bodies_have_a_flat_side():
    """The box is not flat; the floor is, across its normal's axis."""
    frame_set = frames()
    sides = [tracer._flat_side(frame_set.frames[k].geometry) for k in frame_set.geometry]
    assert sorted(side is None for side in sides) == [False, True]
    assert next(side for side in sides if side is not None)[0] == 2


@pytest.mark.parametrize("s_hi", [12.0, np.inf])
def test_blocks_of_shadow_rays_dropped_whole_hold_no_ray_the_per_ray_test_keeps(monkeypatch, s_hi):
    """``_near_body`` tests blocks of consecutive rays first (``_blocks_near``): the mask must be the
    per-ray test's, ray for ray, for blocks far off (dropped), passing the box, grazing it, of
    widely spread speeds, with a NaN start (its block kept), and a ray with a component of e = d + v that is 0."""
    frame_set = frames()
    k = next(k for k in frame_set.geometry if k != frame_set.world)
    block = tracer._NEAR_BLOCK
    rng = np.random.default_rng(5)
    parts = []
    for i in range(14):  # blocks 0 and 4 pass the box, the others run off near-parallel from far away
        tau0, x0, d = rays_past_the_box(block, 20 + i, spread=(1.0, 3.0)[i % 2])
        if i not in (0, 4):
            x0 = x0 + (60.0, -60.0, 20.0)[i % 3]
            d = np.array([1.0, 0.5, -0.3]) * (i % 2 * 2 - 1) + rng.uniform(-1e-3, 1e-3, (block, 3))
        parts.append((tau0, x0, d))
    # block 6: near-parallel rays through the box and around it; block 2: rays that hardly move
    # against the box (e = d + v about 0, of both signs), passing it only after a long way
    tau0, x0, d = parts[6]
    d = np.array([0.3, 0.8, -0.5]) + rng.uniform(-1e-3, 1e-3, (block, 3))
    s_star = rng.uniform(2.0, 8.0, block)
    target = CENTRE + np.outer(tau0 - s_star, VELOCITY) + rng.uniform(-1.5, 1.5, (block, 3)) * SIZE
    parts[6] = (tau0, target - s_star[:, None] * d, d)
    tau0, x0, d = parts[2]
    d = -VELOCITY + rng.uniform(-1e-4, 1e-4, (block, 3))
    s_star = 10.0 ** rng.uniform(3.0, 5.0, block)
    target = CENTRE + np.outer(tau0 - s_star, VELOCITY) + rng.uniform(-0.5, 0.5, (block, 3)) * SIZE
    parts[2] = (tau0, target - s_star[:, None] * d, d)
    tau0, x0, d = parts[8]  # block 8: rays of widely spread speeds against the box, each of one sign
    d = -VELOCITY + rng.uniform(0.2, 1.2, (block, 3)) * (1.0, -1.0, 1.0)
    s_star = rng.uniform(5.0, 8.0, block)
    target = CENTRE + np.outer(tau0 - s_star, VELOCITY) + rng.uniform(-0.5, 0.5, (block, 3)) * SIZE
    parts[8] = (tau0, target - s_star[:, None] * d, d)
    tau0, x0, d = (np.concatenate([p[j] for p in parts]) for j in range(3))
    tau0, x0, d = tau0[:-100], x0[:-100], d[:-100]  # and rays past the last whole block
    x0[3 * block + 5] = np.nan
    d[5 * block + 7, 0] = -VELOCITY[0]
    s_lo, s_hi = np.full(len(d), 1e-6), np.full(len(d), s_hi)
    extent = (float(np.nanmax(np.abs(x0))), float(np.max(np.abs(tau0))))
    args = (frame_set, frame_set.world, k, None, extent, tau0, x0, d, s_lo, s_hi)
    tested = []
    blocks_near = tracer._blocks_near
    monkeypatch.setattr(tracer, "_blocks_near", lambda *a: tested.append(blocks_near(*a)) or tested[-1])
    near = tracer._near_body(*args)
    monkeypatch.setattr(tracer, "_blocks_near", lambda *a: None)
    assert np.array_equal(near, tracer._near_body(*args))
    assert tested[0] is not None and len(tested[0]) < 0.5 * len(d)  # blocks were dropped
    assert near[3 * block + 5] and near.sum() > 0.2 * block
    assert set(np.flatnonzero(near)) <= set(tested[0])
    assert {2, 3, 6, 8} <= {int(i) // block for i in tested[0]} and len(tested[0]) < 7 * block  # (3: the NaN's)
    assert 0.1 * block < near[6 * block:7 * block].sum() < 0.9 * block
    assert near[2 * block:3 * block].all() == np.isinf(s_hi[0])  # (they pass it at s > 1000)


def test_blocks_dropped_on_the_first_axes_leave_the_other_axes_to_the_rays_past_the_last_block(monkeypatch):
    """Every whole block far off along x (dropped on the first axis): ``_blocks_near`` asks for no
    other axis, and the rays past the last whole block, some through the box and some off it,
    get the per-ray test's mask ray for ray, from those axes worked out for them alone."""
    frame_set = frames()
    k = next(k for k in frame_set.geometry if k != frame_set.world)
    block = tracer._NEAR_BLOCK
    tau0, x0, d = rays_past_the_box(3 * block + 700, 11, spread=3.0)
    x0[:3 * block, 0] += 80.0  # (the whole blocks' rays pass it far off along x)
    d[:3 * block] = np.array([0.0, 0.6, 0.8]) + np.random.default_rng(3).uniform(-1e-3, 1e-3, (3 * block, 3))
    s_lo, s_hi = np.full(len(d), 1e-6), np.full(len(d), 12.0)
    extent = (float(np.max(np.abs(x0))), float(np.max(np.abs(tau0))))
    args = (frame_set, frame_set.world, k, None, extent, tau0, x0, d, s_lo, s_hi)
    asked = []
    blocks_near = tracer._blocks_near
    monkeypatch.setattr(tracer, "_blocks_near", lambda column, *rest: blocks_near(
        lambda axis: asked.append(axis) or column(axis), *rest))
    near = tracer._near_body(*args)
    assert asked == [0]
    monkeypatch.setattr(tracer, "_blocks_near", lambda *a: None)
    assert np.array_equal(near, tracer._near_body(*args))
    assert not near[:3 * block].any() and 0.1 < near[3 * block:].mean() < 0.9

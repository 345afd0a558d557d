"""A ray's nearest hit does not depend on the bundle it is traced in: the tracer's shortcuts for
whole bundles (every ray hitting the first frame, no frame left after the cull) give each ray
the bits the general merge gives it."""

from __future__ import annotations

from dataclasses import fields

import numpy as np
from shapes import box, look_at_camera, quad

from restframe_addon.core import tracer
from restframe_addon.core.frames import build_frames
from restframe_addon.core.scene import Mesh, Scene, Velocity

EYE = np.array([0.0, -6.0, 3.0])


def _frames():
    floor = Mesh("floor", *quad((0.0, 0.0, 0.0), (400.0, 400.0)))
    moving = Mesh("box", *box((0.0, -1.0, 1.0), (1.0, 1.0, 1.0)), velocity=Velocity((0.05, -0.03, 0.0)),
                  pivot=(0.0, -1.0, 1.0))
    return build_frames(Scene(camera=look_at_camera(EYE, (0.0, 0.0, 0.0)), meshes=[floor, moving]))


def _down(count: int, seed: int):
    """Unit directions from the eye down to the floor, some of them through the box."""
    rng = np.random.default_rng(seed)
    target = np.column_stack([rng.uniform(-4.0, 4.0, count), rng.uniform(-5.0, 5.0, count), np.zeros(count)])
    target[: count // 4] = (0.0, -1.0, 1.0) + rng.uniform(-0.6, 0.6, (count // 4, 3))  # (toward the box)
    d = target - EYE
    return d / np.linalg.norm(d, axis=1)[:, None]


def _trace(frame_set, d, s_hi=1e3):
    n = len(d)
    return tracer.trace_nearest(frame_set, frame_set.camera, np.broadcast_to(0.0, (n,)), np.broadcast_to(EYE, (n, 3)),
                                d, np.zeros(n), np.full(n, s_hi), tracer.TraceCache())


def _rows(hits, index):
    return [np.asarray(getattr(hits, f.name))[index].tobytes() for f in fields(hits)]


def test_a_bundle_whose_rays_all_hit_the_first_frame_gives_each_ray_the_general_merges_bits():
    frame_set = _frames()
    first = frame_set.candidates(frame_set.camera, None, None)[0]
    d = _down(400, 1)
    alone = _trace(frame_set, d)  # every ray hits the floor, the first frame, nearer than its bound
    assert np.all(alone.frame >= 0) and 0 < np.count_nonzero(alone.frame != first) < len(d)  # (the box's too)
    mixed = _trace(frame_set, np.concatenate([d, -d[:40]]))  # and rays that miss everything: the merge selects
    assert np.all(mixed.frame[400:] == -1)
    assert _rows(alone, slice(0, 400)) == _rows(mixed, slice(0, 400))
    # a bound nearer than some of the hits: those rays miss, the others keep their bits
    bound = float(np.median(alone.s))
    near = _trace(frame_set, d, s_hi=bound)
    kept = np.flatnonzero(alone.s < bound)
    assert 0 < len(kept) < len(d) and np.all(np.delete(near.frame, kept) == -1)
    assert _rows(alone, kept) == _rows(near, kept)


def test_a_bundle_left_with_no_frame_gets_read_only_misses():
    frame_set = _frames()
    d = -_down(64, 2)  # up, away from the floor and the box
    hits = _trace(frame_set, d)
    expected = tracer.no_hits(len(d))
    for f in fields(hits):
        value = getattr(hits, f.name)
        assert not value.flags.writeable
        np.testing.assert_array_equal(value, getattr(expected, f.name))


def test_a_flat_meshs_hits_on_its_flat_axis_are_the_per_hit_sums_bit_for_bit():
    """A thread's kept triangle tables leave out the axis along which a flat mesh's corners and
    edges are all +0: its hits' coordinate there is the per-hit sum's +0 (plus the frame's offset),
    whatever the signs of u and v."""
    rng = np.random.default_rng(7)
    for axis in range(3):
        # a static plane and a moving one (boosted along the plane: its coordinate across stays),
        # through the frame's origin (the axis left out) and off it
        for plane, velocity in ((0.0, (0.0, 0.0, 0.0)), (-2.5, (0.0, 0.0, 0.0)), (0.0, (0.3, -0.2, 0.1)),
                                (1.25, (0.3, -0.2, 0.1))):
            centre, velocity = np.zeros(3), np.array(velocity)
            centre[axis], velocity[axis] = plane, 0.0
            mesh = Mesh("quad", *quad(tuple(centre), (3.0, 2.0), normal_axis=axis), velocity=Velocity(tuple(velocity)),
                        pivot=tuple(centre + 0.75))
            frame_set = build_frames(Scene(camera=look_at_camera(EYE, (0.0, 0.0, 0.0)), meshes=[mesh]))
            frame = frame_set.frames[frame_set.geometry[0]]
            cache = tracer.TraceCache()
            assert (cache.hit_table(frame.geometry)[0][axis] is None) == (plane == 0.0)
            prim = rng.integers(0, 2, 2000)
            u, v = (rng.uniform(-1e-7, 1.0, len(prim)).astype(np.float32) for _ in range(2))
            u[:3], v[3:6] = -0.0, -1e-30
            per_hit = tracer.hit_geometry(frame, prim, u, v)
            kept = tracer.hit_geometry(frame, prim, u, v, cache=cache)
            for a, b in zip(per_hit, kept):
                assert np.asarray(a).tobytes() == np.ascontiguousarray(np.broadcast_to(b, np.shape(a))).tobytes()

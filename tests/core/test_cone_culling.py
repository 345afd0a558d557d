"""Rays from one event are culled against the cones that each frame's bounding spheres subtend
there (tracer._toward), first run by run (the cone of a run of consecutive rays against each
sphere cone) and then ray by ray: the cull may only drop rays that the per-ray cone test drops,
and a culled trace finds the very hits of an unculled one."""

from __future__ import annotations

from dataclasses import fields

import numpy as np
from shapes import box, look_at_camera

from restframe_addon.core import tracer
from restframe_addon.core.frames import build_frames
from restframe_addon.core.scene import Mesh, Scene, Velocity

EYE = np.array([0.0, -12.0, 3.0])


def frames():
    meshes = []
    for i, speed in enumerate((0.1, 0.4, 0.7, -0.5)):
        centre = (-6.0 + 4.0 * i, 2.0 * i, 0.0)
        v, t = box(centre, (1.0, 1.0, 2.0))
        meshes.append(Mesh(f"bar{i}", v, t, velocity=Velocity((speed, 0.1 * i, 0.0)), pivot=centre))
    return build_frames(Scene(camera=look_at_camera(tuple(EYE), (0.0, 0.0, 0.0)), meshes=meshes))


def rays_on_cone_rims(frame_set, seed: int):
    """Directions from the eye close to the rims of every frame's sphere cones (runs that straddle
    a rim, lie just inside or just outside it), among random directions and runs of opposite rays."""
    rng = np.random.default_rng(seed)
    shared = (0.0, EYE)
    batches = []
    for k in frame_set.geometry:
        cones = tracer._cones(frame_set, frame_set.world, [k], shared)[0]
        for axis, spread in zip(*cones):
            t1 = np.cross(axis, [0.0, 0.0, 1.0])
            t1 /= np.linalg.norm(t1)
            t2 = np.cross(axis, t1)
            phi = rng.uniform(0.0, 2 * np.pi, (64, 1))
            angle = spread + rng.choice([-1.0, 1.0], (64, 1)) * rng.uniform(0.0, 1.0, (64, 1)) * 10.0 ** rng.integers(-9, -1, (64, 1))
            angle = angle + np.linspace(-1e-3, 1e-3, tracer._RUN)[None, :] * rng.uniform(0.0, 1.0, (64, 1))
            ring = (np.cos(angle)[..., None] * axis + np.sin(angle)[..., None]
                    * (np.cos(phi)[..., None] * t1 + np.sin(phi)[..., None] * t2))
            batches.append(ring.reshape(-1, 3))
    batches.append(rng.normal(size=(3000, 3)))
    opposite = rng.normal(size=(8, 3))
    batches.append(np.repeat(np.concatenate([opposite, -opposite]), tracer._RUN // 2, axis=0))
    d = np.concatenate(batches)
    d /= np.linalg.norm(d, axis=1)[:, None]
    return d[:(len(d) // tracer._RUN - 1) * tracer._RUN + 5]  # and some rays past the last whole run


def test_run_by_run_cull_keeps_every_ray_the_per_ray_test_keeps():
    frame_set = frames()
    d = rays_on_cone_rims(frame_set, 3)
    shared = (0.0, EYE)
    bundle = (*tracer._bundle_cone(d), tracer._sub_bundle_cones(d))
    dropped = 0
    for cones in tracer._cones(frame_set, frame_set.world, list(frame_set.geometry), shared):
        axes, spread = cones
        per_ray = np.flatnonzero((axes @ d.T >= np.cos(spread)[:, None]).any(axis=0))
        kept = tracer._toward(cones, d, bundle)
        assert kept is not None
        assert np.isin(per_ray, kept).all()
        dropped += len(d) - len(kept)
    assert dropped > 0


def test_cones_of_frames_at_once_are_those_of_each_frame():
    frame_set = frames()
    ks = list(frame_set.geometry)
    together = tracer._cones(frame_set, frame_set.world, ks, (0.0, EYE))
    for k, cones in zip(ks, together):
        alone = tracer._cones(frame_set, frame_set.world, [k], (0.0, EYE))[0]
        assert all(np.array_equal(a, b) for a, b in zip(cones, alone))
    inside = tracer._cones(frame_set, frame_set.world, ks, (0.0, np.array([-6.0, 0.0, 0.0])))  # in bar0
    assert inside[0] is None and all(cones is not None for cones in inside[1:])


def test_culled_trace_finds_the_hits_of_an_unculled_one(monkeypatch):
    frame_set = frames()
    d = rays_on_cone_rims(frame_set, 4)
    n = len(d)
    tau0, x0 = np.broadcast_to(0.0, (n,)), np.broadcast_to(EYE, (n, 3))
    culled = tracer.trace_nearest(frame_set, frame_set.world, tau0, x0, d, 1e-6, np.inf)
    monkeypatch.setattr(tracer, "_toward", lambda *args: None)
    unculled = tracer.trace_nearest(frame_set, frame_set.world, tau0, x0, d, 1e-6, np.inf)
    assert np.array_equal(culled.frame, unculled.frame)
    hit = culled.frame >= 0
    assert 0.05 < hit.mean() < 0.95
    for f in fields(culled):  # (what a missing ray carries besides is no result)
        assert np.array_equal(getattr(culled, f.name)[hit], getattr(unculled, f.name)[hit]), f.name


def test_a_full_cone_cache_starts_afresh(monkeypatch):
    frame_set = frames()
    ks = list(frame_set.geometry)
    cache = tracer.TraceCache()
    kept = tracer._frame_cones(frame_set, frame_set.world, ks[:2], (0.0, EYE), cache)
    monkeypatch.setattr(tracer.TraceCache, "_MAX_CONES", 3)
    more = tracer._frame_cones(frame_set, frame_set.world, ks, (0.0, EYE), cache)  # two kept, the rest past the limit
    assert len(more) == len(ks)
    assert all(np.array_equal(a, b) for cones, again in zip(kept, more[:2]) for a, b in zip(cones, again))

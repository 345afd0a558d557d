"""Rays from one event are culled against each frame's body box run by run (tracer._runs_near_bodies:
blocks of runs, then runs) and, where a frame's bounding spheres hold it more tightly than its
box, against the cones they subtend there (tracer._toward), first run by run (the cone of a run
of consecutive rays against each sphere cone) and then ray by ray: the cull may only drop rays
that the per-ray tests drop, and a culled trace finds the very hits of an unculled one."""

from __future__ import annotations

from dataclasses import fields

import numpy as np
import pytest
from shapes import box, look_at_camera, uv_sphere

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
    bundle = (*tracer._bundle_cone(d), tracer._sub_bundle_cones(tracer._run_bounds(d)))
    dropped = 0
    for cones in tracer._cones(frame_set, frame_set.world, list(frame_set.geometry), shared):
        axes, spread = cones
        per_ray = np.flatnonzero((axes @ d.T >= np.cos(spread)[:, None]).any(axis=0))
        kept = tracer._toward(cones, d, bundle, np.arange(len(d) // tracer._RUN))
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


def unculled(monkeypatch):
    """Trace every ray in every frame from now on."""
    monkeypatch.setattr(tracer, "_cull_bundle", lambda frame_set, src, ks, *args: (list(ks), [None] * len(ks)))


def cones_always(monkeypatch):
    """Cull every frame by its sphere cones too from now on, whether or not they pay."""
    monkeypatch.setattr(tracer, "_cones_pay", lambda frame_set, src, ks, cache: [True] * len(ks))


@pytest.mark.parametrize("cones", [False, True])
def test_culled_trace_finds_the_hits_of_an_unculled_one(monkeypatch, cones):
    frame_set = frames()
    d = rays_on_cone_rims(frame_set, 4)
    n = len(d)
    tau0, x0 = np.broadcast_to(0.0, (n,)), np.broadcast_to(EYE, (n, 3))
    if cones:
        cones_always(monkeypatch)
    culled = tracer.trace_nearest(frame_set, frame_set.world, tau0, x0, d, 1e-6, np.inf)
    unculled(monkeypatch)
    everything = tracer.trace_nearest(frame_set, frame_set.world, tau0, x0, d, 1e-6, np.inf)
    assert np.array_equal(culled.frame, everything.frame)
    hit = culled.frame >= 0
    assert 0.05 < hit.mean() < 0.95
    for f in fields(culled):  # (what a missing ray carries besides is no result)
        assert np.array_equal(getattr(culled, f.name)[hit], getattr(everything, f.name)[hit]), f.name


def test_a_full_cone_cache_starts_afresh(monkeypatch):
    frame_set = frames()
    ks = list(frame_set.geometry)
    cache = tracer.TraceCache()
    kept = tracer._frame_cones(frame_set, frame_set.world, ks[:2], (0.0, EYE), cache)
    monkeypatch.setattr(tracer.TraceCache, "_MAX_CONES", 3)
    more = tracer._frame_cones(frame_set, frame_set.world, ks, (0.0, EYE), cache)  # two kept, the rest past the limit
    assert len(more) == len(ks)
    assert all(np.array_equal(a, b) for cones, again in zip(kept, more[:2]) for a, b in zip(cones, again))


def runs_across_body_boxes(frame_set, seed: int, count: int = 400):
    """Runs of ``_RUN`` directions from the eye, each sweeping between two points about a frame's
    body box (where the box is when the light passes it): many runs straddle a box's faces."""
    rng = np.random.default_rng(seed)
    t_box, x_box, velocity, half = frame_set.body_boxes(frame_set.world)
    runs = []
    for _ in range(count):
        slot = rng.integers(len(t_box))
        s = np.linalg.norm(x_box[slot] - EYE)
        for _ in range(3):  # the box's centre at the time tau0 - s its light passes it (tau0 = 0)
            centre = x_box[slot] + velocity[slot] * (-s - t_box[slot])
            s = np.linalg.norm(centre - EYE)
        ends = centre + half[slot] * rng.uniform(-1.6, 1.6, (2, 3))
        sweep = ends[0] + np.linspace(0.0, 1.0, tracer._RUN)[:, None] * (ends[1] - ends[0])
        runs.append(sweep - EYE)
    d = np.concatenate(runs + [rng.normal(size=(5, 3))])  # and some rays past the last whole run
    return d / np.linalg.norm(d, axis=1)[:, None]


def near_masks(frame_set, d, s_hi, eye=EYE):
    """_runs_near_bodies's runs of every geometry frame as masks over the runs of d."""
    extent = (float(np.max(np.abs(eye))), 0.0)
    near = tracer._runs_near_bodies(frame_set, frame_set.world, list(frame_set.geometry), None, extent, (0.0, eye),
                                    tracer._run_bounds(d), (1e-6, s_hi))
    masks = np.zeros((len(near), len(d) // tracer._RUN), dtype=bool)
    for mask, runs in zip(masks, near):
        assert np.all(np.diff(runs) > 0)
        mask[runs] = True
    return masks


@pytest.mark.parametrize("s_hi", [np.inf, 14.0])
def test_runs_the_body_box_test_drops_hold_no_ray_the_per_ray_test_keeps(s_hi):
    frame_set = frames()
    d = runs_across_body_boxes(frame_set, 5)
    n, count = len(d), len(d) // tracer._RUN
    tau0, x0 = np.broadcast_to(0.0, (n,)), np.broadcast_to(EYE, (n, 3))
    s_lo, s_hi = np.full(n, 1e-6), np.full(n, s_hi)
    extent = (float(np.max(np.abs(EYE))), 0.0)
    dropped = kept = 0
    for k, per_run in zip(frame_set.geometry, near_masks(frame_set, d, float(s_hi[0]))):
        per_ray = tracer._near_body(frame_set, frame_set.world, k, None, extent, tau0, x0, d, s_lo, s_hi)
        assert per_run[per_ray[:count * tracer._RUN].reshape(count, tracer._RUN).any(axis=1)].all()
        dropped += int(np.count_nonzero(~per_run))
        kept += int(np.count_nonzero(per_run & ~per_ray[:count * tracer._RUN].reshape(count, -1).all(axis=1)))
    assert dropped > count and kept > 0.1 * count  # runs dropped whole, and runs straddling a box kept


@pytest.mark.parametrize("width", [384, 376])
def test_blocks_of_runs_drop_only_runs_that_miss_a_body_box_each(width):
    """The blocks of runs tested first drop only runs that the run test itself drops: the runs
    kept are those of each run tested alone (a camera bundle, the last block short or not)."""
    frame_set = rows_of_bars()
    d = camera_bundle(width)
    count = len(d) // tracer._RUN
    low, high = tracer._run_bounds(d)
    extent = (float(np.max(np.abs(EYE))), 0.0)
    ks = list(frame_set.geometry)
    t_box, x_box, velocity, widen = tracer._body_boxes(frame_set, frame_set.world, ks, None, extent)
    blocks = near_masks(frame_set, d, np.inf)
    for i in range(len(ks)):
        offset = EYE - ((0.0 - t_box[i]) * velocity[i] + x_box[i])
        alone = [tracer._slabs_pass((-widen[i] - offset)[:, None], (widen[i] - offset)[:, None], velocity[i][:, None],
                                    low[:, [run]], high[:, [run]], (1e-6, np.inf))[0] for run in range(count)]
        np.testing.assert_array_equal(blocks[i], alone)
        assert 0.01 * count < np.count_nonzero(alone) < 0.5 * count


def rows_of_bars_meshes():
    """Three rows of five thin bars, each row one mesh moving along x: a row's bounding sphere
    (one culling cluster: the row has under 64 triangles) is far wider than its box."""
    meshes = []
    for i, speed in enumerate((0.1, 0.3, 0.5)):
        parts = [box((-4.0 + 2.0 * j, 3.0 * i, 0.0), (0.4, 0.4, 2.0)) for j in range(5)]
        v = np.concatenate([p[0] for p in parts])
        t = np.concatenate([p[1] + 8 * j for j, p in enumerate(parts)])
        meshes.append(Mesh(f"row{i}", v, t, velocity=Velocity((speed, 0.0, 0.0)), pivot=(0.0, 3.0 * i, 0.0)))
    return meshes


def rows_of_bars():
    return build_frames(Scene(camera=look_at_camera(tuple(EYE), (0.0, 0.0, 0.0)), meshes=rows_of_bars_meshes()))


def camera_bundle(width: int = 384, height: int = 64, rise=(-0.3, 0.2)):
    """Pixel rays of a wide perspective camera at the eye looking at the bars (or at ``rise``, the
    lowest and highest pixel rows, another height), row by row as in a tile."""
    forward = -EYE / np.linalg.norm(EYE)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    px, py = np.meshgrid(np.linspace(-0.8, 0.8, width), np.linspace(*rise, height))
    d = forward + px.reshape(-1, 1) * right + py.reshape(-1, 1) * up
    return d / np.linalg.norm(d, axis=1)[:, None]


def from_the_eye(d):
    """(tau0, x0) of rays d from the eye at time 0, as a perspective camera's (broadcast views)."""
    return np.broadcast_to(0.0, (len(d),)), np.broadcast_to(EYE, (len(d), 3))


def queried_rays(monkeypatch) -> list:
    """The number of rays of each frame query from now on (``tracer._query`` counted)."""
    queried = []
    query = tracer._query
    monkeypatch.setattr(tracer, "_query", lambda frame, tau, origin, dk, *rest, **kw: queried.append(len(dk))
                        or query(frame, tau, origin, dk, *rest, **kw))
    return queried


def test_camera_rays_that_miss_a_body_box_are_not_traced_in_its_frame(monkeypatch):
    """The runs of a camera bundle that pass no part of a frame's body box are dropped before
    being mapped into the frame: fewer rays queried than with the sphere cones alone (a row's
    sphere is far wider than its box), the very same hits as without culling."""
    frame_set = rows_of_bars()
    d = camera_bundle()
    tau0, x0 = from_the_eye(d)
    queried = queried_rays(monkeypatch)
    assert tracer._cones_pay(frame_set, frame_set.world, list(frame_set.geometry), None) == [False] * 3
    culled = tracer.trace_nearest(frame_set, frame_set.world, tau0, x0, d, 1e-6, np.inf)
    box_culled, queried[:] = sum(queried), []
    cones_always(monkeypatch)
    monkeypatch.setattr(tracer, "_runs_near_bodies", lambda frame_set, src, ks, cache, extent, shared, bounds, path:
                        [np.arange(bounds[0].shape[1])] * len(ks))  # every run to the cone test
    cones_only = tracer.trace_nearest(frame_set, frame_set.world, tau0, x0, d, 1e-6, np.inf)
    assert sum(queried) > 1.5 * box_culled
    unculled(monkeypatch)
    everything = tracer.trace_nearest(frame_set, frame_set.world, tau0, x0, d, 1e-6, np.inf)
    for traced in (culled, cones_only):
        assert np.array_equal(traced.frame, everything.frame)
    hit = culled.frame >= 0
    assert len(np.unique(culled.frame[hit])) == 3 and hit.mean() > 0.02  # every row seen
    for f in fields(culled):
        for traced in (culled, cones_only):
            assert np.array_equal(getattr(traced, f.name)[hit], getattr(everything, f.name)[hit]), f.name


def diagonal_rod():
    """A thin rod of 16 small boxes along a space diagonal, moving, and a row of bars: the rod's
    box is far larger than its culling clusters' spheres, the row's far smaller."""
    parts = [box(tuple(np.full(3, -4.0 + 0.5 * j)), (0.5, 0.5, 0.5)) for j in range(16)]
    v = np.concatenate([p[0] for p in parts])
    t = np.concatenate([p[1] + 8 * j for j, p in enumerate(parts)])
    meshes = [Mesh("rod", v, t, velocity=Velocity((0.4, 0.0, 0.1))), *rows_of_bars_meshes()[:1]]
    return build_frames(Scene(camera=look_at_camera(tuple(EYE), (0.0, 0.0, 0.0)), meshes=meshes))


def test_sphere_cones_cull_the_frames_they_hold_more_tightly_than_their_box(monkeypatch):
    frame_set = diagonal_rod()
    rod, row = frame_set.geometry
    assert len(frame_set.frames[rod].geometry.clusters) == 4
    assert tracer._cones_pay(frame_set, frame_set.world, [rod, row], None) == [True, False]
    d = camera_bundle(128, 128, (-0.7, 0.7))
    n = len(d)
    tau0, x0 = np.broadcast_to(0.0, (n,)), np.broadcast_to(EYE, (n, 3))
    culls = []
    cull = tracer._cull_bundle
    monkeypatch.setattr(tracer, "_cull_bundle", lambda *args: culls.append(cull(*args)) or culls[-1])
    culled = tracer.trace_nearest(frame_set, frame_set.world, tau0, x0, d, 1e-6, np.inf)
    monkeypatch.setattr(tracer, "_cones_pay", lambda frame_set, src, ks, cache: [False] * len(ks))
    boxes_only = tracer.trace_nearest(frame_set, frame_set.world, tau0, x0, d, 1e-6, np.inf)
    (kept, with_cones), (_, without) = culls
    assert kept == [rod, row]
    assert len(with_cones[0]) < 0.5 * len(without[0]) and np.array_equal(with_cones[1], without[1])
    assert np.isin(with_cones[0], without[0]).all()
    unculled(monkeypatch)
    everything = tracer.trace_nearest(frame_set, frame_set.world, tau0, x0, d, 1e-6, np.inf)
    hit = everything.frame >= 0
    assert np.count_nonzero(everything.frame == rod) > 50
    for traced in (culled, boxes_only):
        assert np.array_equal(traced.frame, everything.frame)
        for f in fields(traced):
            assert np.array_equal(getattr(traced, f.name)[hit], getattr(everything, f.name)[hit]), f.name


def test_a_lone_frame_is_culled_too(monkeypatch):
    """A lone moving body (no culling clusters: one sphere around it) still has the rays of a
    camera bundle that miss its sphere's cone dropped before they are mapped into its frame and
    queried, and a bundle whose cone misses it whole queries nothing; the very same hits."""
    v, t = uv_sphere((0.0, 0.0, 0.0), 1.0, 24, 12)
    frame_set = build_frames(Scene(camera=look_at_camera(tuple(EYE), (0.0, 0.0, 0.0)),
                                   meshes=[Mesh("ball", v, t, velocity=Velocity((0.5, 0.2, 0.0)))]))
    assert len(frame_set.geometry) == 1 and frame_set.frames[frame_set.geometry[0]].geometry.clusters is None
    d = camera_bundle()
    n = len(d)
    tau0, x0 = from_the_eye(d)
    queried = queried_rays(monkeypatch)
    culled = tracer.trace_nearest(frame_set, frame_set.world, tau0, x0, d, 1e-6, np.inf)
    culled_rays, queried[:] = sum(queried), []
    away = tracer.trace_nearest(frame_set, frame_set.world, tau0[:64], x0[:64], -d[:64], 1e-6, np.inf)
    assert queried == [] and (away.frame < 0).all()
    unculled(monkeypatch)
    everything = tracer.trace_nearest(frame_set, frame_set.world, tau0, x0, d, 1e-6, np.inf)
    assert queried == [n] and culled_rays < 0.5 * n
    hit = culled.frame >= 0
    assert np.array_equal(hit, everything.frame >= 0) and 0.02 < hit.mean() < 0.5
    for f in fields(culled):
        assert np.array_equal(getattr(culled, f.name)[hit], getattr(everything, f.name)[hit]), f.name


@pytest.mark.parametrize("share", [0.45, 0.6])
def test_a_lone_moving_frames_bundle_is_gathered_up_to_its_boosted_share(monkeypatch, share):
    """A lone moving body's camera bundle whose cull keeps a share of its rays between
    ``_GATHER_SHARE`` and ``_BOOSTED_GATHER_SHARE`` has only those rays boosted and queried (each
    ray traced whole would cost its boost too), under ``_GATHER_SHARE`` too; the very same hits as tracing every ray."""
    v, t = uv_sphere((0.0, 0.0, 0.0), 1.0, 24, 12)
    frame_set = build_frames(Scene(camera=look_at_camera(tuple(EYE), (0.0, 0.0, 0.0)),
                                   meshes=[Mesh("ball", v, t, velocity=Velocity((0.5, 0.2, 0.0)))]))
    wide = camera_bundle()
    toward = wide[tracer.trace_nearest(frame_set, frame_set.world, *from_the_eye(wide), wide, 1e-6, np.inf).frame >= 0]
    away = -wide  # (each outside the ball's cone)
    m = len(toward)
    d = np.concatenate([toward, away[:int(m * (1 - share) / share)]])
    tau0, x0 = from_the_eye(d)
    queried = queried_rays(monkeypatch)
    culled = tracer.trace_nearest(frame_set, frame_set.world, tau0, x0, d, 1e-6, np.inf)
    assert queried == [m] and (culled.frame[:m] >= 0).all()
    queried[:] = []
    unculled(monkeypatch)
    everything = tracer.trace_nearest(frame_set, frame_set.world, tau0, x0, d, 1e-6, np.inf)
    assert queried == [len(d)]
    hit = culled.frame >= 0
    assert np.array_equal(hit, everything.frame >= 0)
    for f in fields(culled):
        assert np.array_equal(getattr(culled, f.name)[hit], getattr(everything, f.name)[hit]), f.name


@pytest.mark.parametrize("ufunc", [np.minimum, np.maximum])
def test_per_run_reductions_are_those_of_each_run(ufunc):
    values = np.random.default_rng(2).normal(size=(37 * tracer._RUN, 3))  # runs along the first axis
    expected = ufunc.reduce(values.reshape(-1, tracer._RUN, 3), axis=1)
    np.testing.assert_array_equal(tracer._per_run(ufunc, values), expected)


def test_run_bounds_are_those_of_each_run():
    d = np.random.default_rng(2).normal(size=(37 * tracer._RUN + 5, 3))  # and some rays past the last whole run
    low, high = tracer._run_bounds(d)
    runs = d[:37 * tracer._RUN].reshape(37, tracer._RUN, 3)
    np.testing.assert_array_equal(low, runs.min(axis=1).T)
    np.testing.assert_array_equal(high, runs.max(axis=1).T)


def test_each_run_lies_in_its_cone():
    """The cone of a run is drawn about its box: every direction of the run is within it, the
    cone is hardly wider than the run's own spread about the axis, and runs of opposite
    directions have a cone that holds every direction."""
    frame_set = frames()
    d = rays_on_cone_rims(frame_set, 6)
    count = len(d) // tracer._RUN
    axes, run_cos, run_sin = tracer._sub_bundle_cones(tracer._run_bounds(d))
    np.testing.assert_allclose(np.linalg.norm(axes[run_cos > -1.0], axis=1), 1.0, rtol=1e-15)
    np.testing.assert_allclose(run_sin, np.sqrt(1.0 - run_cos ** 2))
    runs = d[:count * tracer._RUN].reshape(count, tracer._RUN, 3)
    cosines = np.einsum("brj,bj->br", runs, axes)
    assert (cosines.min(axis=1) >= run_cos).all()
    narrow = cosines.min(axis=1) > 0.99  # runs within about 8 degrees
    assert narrow.sum() > count // 2
    spread, bound = np.arccos(cosines.min(axis=1)[narrow]), np.arccos(run_cos[narrow])
    assert (bound <= 2.0 * spread + 1e-5).all()
    half = np.random.default_rng(7).normal(size=(5, tracer._RUN // 2, 3))
    opposite = np.concatenate([half, -half], axis=1).reshape(-1, 3)  # each run: directions and their opposites
    opposite /= np.linalg.norm(opposite, axis=1)[:, None]
    assert (tracer._sub_bundle_cones(tracer._run_bounds(opposite))[1] == -1.0).all()


def test_a_trace_writes_nothing_into_the_rays_arrays():
    """The first frame's hits share the rays' own arrays (directions, start times) until a later
    frame's nearer hits are written: those go into the tracer's own copies, never the caller's."""
    wall = Mesh("wall", *box((0.0, 8.0, 0.0), (10.0, 0.5, 6.0)))  # at rest in the rays' frame, behind the bar
    v, t = box((0.0, 2.0, 0.5), (1.0, 1.0, 2.0))
    frame_set = build_frames(Scene(camera=look_at_camera(tuple(EYE), (0.0, 0.0, 0.0)),
                                   meshes=[wall, Mesh("bar", v, t, velocity=Velocity((0.6, 0.0, 0.0)),
                                                      pivot=(0.0, 2.0, 0.5))]))
    d = camera_bundle(96, 32)
    n = len(d)
    tau0, x0 = np.zeros(n), np.tile(EYE, (n, 1))  # the rays' own arrays (not one shared event)
    given = tau0.copy(), x0.copy(), d.copy()
    hits = tracer.trace_nearest(frame_set, frame_set.world, tau0, x0, d, 1e-6, np.inf)
    assert all(np.array_equal(a, b) for a, b in zip((tau0, x0, d), given))
    ks, counts = np.unique(hits.frame[hits.frame >= 0], return_counts=True)
    assert frame_set.world in ks and len(ks) == 2 and counts.min() > 20  # the wall and, in front of it, the bar
    on_wall = hits.frame == frame_set.world
    np.testing.assert_array_equal(hits.d_frame[on_wall], d[on_wall])
    assert not np.allclose(hits.d_frame[(hits.frame >= 0) & ~on_wall], d[(hits.frame >= 0) & ~on_wall])

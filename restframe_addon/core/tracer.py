"""Backward light rays traced through every rest frame (paper section 2.2).

A ray starts at an event ``(tau0, x0)`` of a source frame and runs back in time
along the unit direction ``d``: events ``(tau0 - s, x0 + s d)``.  In each
geometry frame it becomes ``(tau0' - s', x0' + s' d')`` with ``s' = w s``; the
static triangles there are intersected with an ordinary ray query.  Hits of
different frames are compared by ``s`` in the source frame -- the most recent
emission event wins -- never by ``s'``.

Embree works in float32, so each query first clips the ray to the frame's
bounds in float64 and moves the origin there (relative to the frame's anchor
point); the skipped length is added back in float64.  Rays that miss a frame's
bounds never reach embree.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .frames import FrameSet, RestFrame

_PAD = 1e-4  # bounds padding, relative to the frame's extent: float32 geometry may sit just outside
_SPIN_ITERATIONS = 24  # the hit-time iteration of spinning bodies (secant-accelerated; rim speed < c)


@dataclass
class Hits:
    """Nearest hits of a ray bundle; ``frame == -1`` where nothing is hit."""

    frame: np.ndarray  # (N,) int
    s: np.ndarray  # (N,) path length in the source frame (inf on a miss)
    s_frame: np.ndarray  # (N,) path length in the hit frame
    w: np.ndarray  # (N,) s_frame / s: 1/D between source and hit frame
    prim: np.ndarray  # (N,) triangle index within the frame
    u: np.ndarray  # (N,) barycentric coordinates from embree
    v: np.ndarray


def _clip_to_bounds(geometry, origin, d, t_lo, t_hi):
    """Slab test against the geometry's bounds (local coordinates): the parameter range inside them.

    Written per axis: numpy's reductions over a length-3 axis cost more than the arithmetic.
    """
    pad = _PAD * geometry.extent + 1e-14 * float(np.max(np.abs(geometry.anchor)))
    enter, leave = t_lo, t_hi
    with np.errstate(divide="ignore", invalid="ignore"):
        for axis in range(3):
            inv = 1.0 / d[:, axis]
            t_a = (geometry.lo[axis] - pad - origin[:, axis]) * inv
            t_b = (geometry.hi[axis] + pad - origin[:, axis]) * inv
            # fmin/fmax ignore the NaN of 0 * inf (a ray in the plane of a slab face)
            enter = np.fmax(enter, np.fmin(t_a, t_b))
            leave = np.fmin(leave, np.fmax(t_a, t_b))
    return enter, leave


def _query(frame: RestFrame, tau, origin, d, t_lo, t_hi, occlusion: bool):
    """Intersect rays (frame coordinates, float64, origin events at frame times tau) with the
    frame's triangles.

    Returns (index into the inputs, t, prim, u, v) of hits, or for occlusion the
    indices of blocked rays.
    """
    if frame.spin is not None:
        return _spin_query(frame, tau, origin, d, t_lo, t_hi, occlusion)
    origin, d = frame.to_local(origin, d)
    return _local_query(frame.geometry, origin, d, t_lo, t_hi, occlusion)


def _local_query(geometry, origin, d, t_lo, t_hi, occlusion: bool):
    enter, leave = _clip_to_bounds(geometry, origin, d, t_lo, t_hi)
    inside = enter <= leave
    if inside.all():  # every ray reaches the bounds (the common case up close): no gathers
        idx, start, origin_in, d_in, leave_in = np.arange(len(d)), enter, origin, d, leave
    else:
        idx = np.flatnonzero(inside)
        if len(idx) == 0:
            return (idx,) if occlusion else (idx, None, None, None, None)
        start, origin_in, d_in, leave_in = enter[idx], origin[idx], d[idx], leave[idx]
    start_point = origin_in + start[:, None] * d_in - geometry.anchor
    length = (leave_in - start).astype(np.float32)
    o32 = np.ascontiguousarray(start_point, dtype=np.float32)
    d32 = np.ascontiguousarray(d_in, dtype=np.float32)
    if occlusion:
        blocked = geometry.embree.run(o32, d32, dists=length, query="OCCLUDED") >= 0
        return (idx[blocked],)
    out = geometry.embree.run(o32, d32, dists=length, output=1)
    hit = out["primID"] >= 0
    t = start[hit] + out["tfar"][hit].astype(np.float64)
    return idx[hit], t, out["primID"][hit], out["u"][hit], out["v"][hit]


def _spin_query(frame: RestFrame, tau, origin, d, t_lo, t_hi, occlusion: bool):
    """A spinning body meets each ray in the pose of the ray's own hit time.

    The hit path length s solves ``F(s) = hit(s) - s = 0``, where ``hit(s)`` intersects the
    body posed at the time of path length s.  A pose change moves body points by at most
    |omega| r < 1 per unit time (rim speed below c), so plain iteration ``s <- hit(s)``
    contracts; secant steps on F speed it up where it is slow (fast rims, grazing hits)
    and are used only when they stay inside the ray's range.  Iteration stops once the
    hit moves by less than the frame's motion tolerance; a ray that misses the body in
    the pose of its latest hit time has no consistent hit.
    """
    geometry = frame.geometry
    rim = float(np.linalg.norm(frame.spin)) * geometry.radius
    # first guess: where the ray passes the pivot most closely
    guess = np.clip(-np.einsum("ij,ij->i", origin - frame.offset, d), t_lo, t_hi)
    previous = np.full(len(d), np.nan)
    previous_f = np.full(len(d), np.nan)
    found = np.zeros(len(d), dtype=bool)
    result_t = np.zeros(len(d))
    prim = np.zeros(len(d), dtype=np.int32)
    u = np.zeros(len(d))
    v = np.zeros(len(d))
    todo = np.arange(len(d))
    for _ in range(_SPIN_ITERATIONS):
        if len(todo) == 0:
            break
        o_l, d_l = frame.to_local(origin[todo], d[todo], tau[todo] - guess[todo])
        idx, t, p, uu, vv = _local_query(geometry, o_l, d_l, t_lo[todo], t_hi[todo], occlusion=False)
        hit = todo[idx]
        found[np.setdiff1d(todo, hit)] = False
        if len(hit) == 0:
            break
        found[hit], result_t[hit], prim[hit], u[hit], v[hit] = True, t, p, uu, vv
        f = t - guess[hit]
        done = np.abs(f) * rim <= frame.tolerance
        with np.errstate(divide="ignore", invalid="ignore"):
            secant = guess[hit] - f * (guess[hit] - previous[hit]) / (f - previous_f[hit])
        usable = np.isfinite(secant) & (secant >= t_lo[hit]) & (secant <= t_hi[hit])
        previous[hit], previous_f[hit] = guess[hit], f
        guess[hit] = np.where(usable, secant, t)
        todo = hit[~done]
    idx = np.flatnonzero(found)
    if occlusion:
        return (idx,)
    return idx, result_t[idx], prim[idx], u[idx], v[idx]


def _ray_range(frame: RestFrame, tau, origin, d, s_lo, s_hi):
    """Clip path lengths of rays (frame coordinates) to the stretch of spacetime where the frame's body holds."""
    if frame.window is None:
        return s_lo, s_hi
    return frame.window.clip(tau, origin, d, s_lo, s_hi)


def trace_nearest(frames: FrameSet, src: int, tau0, x0, d, s_lo, s_hi) -> Hits:
    """The visible (most recent) hit of each backward ray, over all geometry frames.

    ``tau0`` (N,), ``x0`` (N, 3), ``d`` (N, 3) unit, in frame ``src``;
    only hits with ``s_lo <= s <= s_hi`` count.
    """
    n = len(d)
    s_lo = np.broadcast_to(np.asarray(s_lo, dtype=np.float64), (n,))
    best = np.broadcast_to(np.asarray(s_hi, dtype=np.float64), (n,)).copy()
    hits = Hits(
        frame=np.full(n, -1, dtype=np.int32),
        s=np.full(n, np.inf),
        s_frame=np.full(n, np.inf),
        w=np.ones(n),
        prim=np.full(n, -1, dtype=np.int32),
        u=np.zeros(n),
        v=np.zeros(n),
    )
    candidates = frames.candidates(src, tau0, x0)
    # culling by bounding cones pays off only when several frames share the rays
    shared = _shared_origin(tau0, x0) if len(candidates) > 1 else None
    for k in candidates:
        frame = frames.frames[k]
        fmap = frames.map(src, k)
        rays = _toward(frames, src, k, shared, d) if shared is not None else None
        if rays is None:
            rays = np.arange(n)
        elif len(rays) == 0:
            continue
        if shared is not None:
            tau_k, origin = fmap.events(np.array(shared[0]), shared[1])
            tau_k, origin = np.full(len(rays), tau_k), np.broadcast_to(origin, (len(rays), 3))
        else:
            tau_k, origin = fmap.events(tau0[rays], x0[rays])
        dk, w = fmap.rays(d[rays])
        lo, hi = _ray_range(frame, tau_k, origin, dk, s_lo[rays] * w, best[rays] * w)
        idx, t, prim, u, v = _query(frame, tau_k, origin, dk, lo, hi, occlusion=False)
        if len(idx) == 0:
            continue
        s = t / w[idx]
        nearer = s < best[rays[idx]]  # ties keep the earlier frame
        sub, s, t = idx[nearer], s[nearer], t[nearer]
        idx = rays[sub]
        best[idx] = s
        hits.frame[idx] = k
        hits.s[idx] = s
        hits.s_frame[idx] = t
        hits.w[idx] = w[sub]
        hits.prim[idx] = prim[nearer]
        hits.u[idx] = u[nearer]
        hits.v[idx] = v[nearer]
    return hits


def _shared_origin(tau0, x0):
    """(tau, x) when every ray starts at the same event (a perspective camera's rays), else None."""
    if len(tau0) == 0 or not (np.all(tau0 == tau0[0]) and np.all(x0 == x0[0])):
        return None
    return float(tau0[0]), np.array(x0[0])


_CONE_SAMPLES = 16


def _toward(frames: FrameSet, src: int, k: int, origin_event, d):
    """Indices of rays from one event that point into a cone subtended there by one of the
    frame's bounding spheres, or None when the event is inside one (no culling possible).

    Each cone is built in frame k and mapped to frame src by aberration, which maps circles
    on the sky to circles: its image is found from ``_CONE_SAMPLES`` rim directions around
    the mapped axis, widened by a margin for the sampling.
    """
    frame = frames.frames[k]
    geometry = frame.geometry
    _, x_k = frames.map(src, k).events(np.array(origin_event[0]), origin_event[1])
    if frame.spin is not None:  # any pose: the sphere about the pivot
        spheres = np.array([[*frame.offset, geometry.radius]])
    else:
        spheres = geometry.clusters + np.append(frame.offset, 0.0)
    pad = 2 * _PAD * geometry.extent + 1e-9 * (1.0 + float(np.max(np.abs(spheres[:, :3]))))
    offset = spheres[:, :3] - x_k
    distance = np.linalg.norm(offset, axis=1)
    radius = spheres[:, 3] + pad
    if np.any(distance <= radius * 1.01):
        return None
    axes = offset / distance[:, None]
    half = np.arcsin(radius / distance)
    t1 = np.cross(axes, np.where(np.abs(axes[:, :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]))
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(axes, t1)
    phi = np.linspace(0.0, 2 * np.pi, _CONE_SAMPLES, endpoint=False)
    rim = (np.cos(half)[:, None, None] * axes[:, None, :]
           + np.sin(half)[:, None, None] * (np.cos(phi)[None, :, None] * t1[:, None, :]
                                            + np.sin(phi)[None, :, None] * t2[:, None, :]))
    directions = np.concatenate([axes[:, None, :], rim], axis=1).reshape(-1, 3)
    src_dirs, _ = frames.map(k, src).rays(directions)
    src_dirs = src_dirs.reshape(len(spheres), _CONE_SAMPLES + 1, 3)
    centre_dirs = src_dirs[:, 0]
    spread = np.max(np.arccos(np.clip(np.einsum("kij,kj->ki", src_dirs[:, 1:], centre_dirs), -1.0, 1.0)), axis=1)
    cos_spread = np.cos(np.minimum(spread * 1.05 + 1e-9, np.pi))
    inside = np.zeros(len(d), dtype=bool)
    for axis, limit in zip(centre_dirs, cos_spread):
        inside |= d @ axis >= limit
    return np.flatnonzero(inside)


def occluded(frames: FrameSet, src: int, tau0, x0, d, s_lo, s_hi) -> np.ndarray:
    """True where anything in any frame lies on the backward ray with s_lo <= s <= s_hi."""
    n = len(d)
    s_lo = np.broadcast_to(np.asarray(s_lo, dtype=np.float64), (n,))
    s_hi = np.broadcast_to(np.asarray(s_hi, dtype=np.float64), (n,))
    blocked = np.zeros(n, dtype=bool)
    reach = _bundle_reach(tau0, x0, d, s_lo, s_hi)
    for k in frames.candidates(src, tau0, x0):
        todo = np.flatnonzero(~blocked)
        if len(todo) == 0:
            break
        if reach is not None and not _may_meet(frames, src, k, *reach):
            continue
        fmap = frames.map(src, k)
        frame = frames.frames[k]
        tau_k, origin = fmap.events(tau0[todo], x0[todo])
        dk, w = fmap.rays(d[todo])
        lo, hi = _ray_range(frame, tau_k, origin, dk, s_lo[todo] * w, s_hi[todo] * w)
        (idx,) = _query(frame, tau_k, origin, dk, lo, hi, occlusion=True)
        blocked[todo[idx]] = True
    return blocked


def _bundle_reach(tau0, x0, d, s_lo, s_hi):
    """(centre, radius, earliest, latest): a ball holding every ray segment of a bundle, and the
    span of its events' times (source frame); None for unbounded rays (sunlight)."""
    if len(d) == 0 or not np.all(np.isfinite(s_hi)):
        return None
    near = x0 + s_lo[:, None] * d
    far = x0 + s_hi[:, None] * d
    points = np.concatenate([near, far])
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre = 0.5 * (lo + hi)
    return centre, 0.5 * float(np.linalg.norm(hi - lo)), float(np.min(tau0 - s_hi)), float(np.max(tau0 - s_lo))


def _may_meet(frames: FrameSet, src: int, k: int, centre, radius, earliest, latest) -> bool:
    """Can frame k's body come within reach of the bundle's ball during [earliest, latest]?

    The body's bounding sphere moves uniformly in the source frame (its centre's world line
    mapped from frame k; a Lorentz-contracted body only shrinks), so over the time span it
    sweeps a capsule: the frame matters only if the capsule meets the ball.
    """
    frame = frames.frames[k]
    geometry = frame.geometry
    if frame.spin is not None:
        body_centre, body_radius = frame.offset, geometry.radius
    else:
        body_centre, body_radius = geometry.anchor + frame.offset, 0.5 * float(np.linalg.norm(geometry.hi - geometry.lo))
    back = frames.map(k, src)
    t_a, x_a = back.events(np.array(0.0), body_centre)
    t_b, x_b = back.events(np.array(1.0), body_centre)
    velocity = (x_b - x_a) / float(t_b - t_a)
    start = x_a + velocity * (earliest - float(t_a))
    end = x_a + velocity * (latest - float(t_a))
    segment = end - start
    length2 = float(segment @ segment)
    along = 0.0 if length2 == 0.0 else min(max(float((centre - start) @ segment) / length2, 0.0), 1.0)
    gap = float(np.linalg.norm(centre - (start + along * segment)))
    slack = body_radius * (1.0 + 2 * _PAD) + 1e-9 * (1.0 + float(np.max(np.abs(centre))))
    return gap <= radius + slack


def hit_geometry(frame: RestFrame, prim, u, v, tau=None):
    """Float64 position, unit geometric normal and unit shading normal at hits of one frame
    (frame coordinates; ``tau``, the hits' frame times, poses a spinning body)."""
    geometry = frame.geometry
    tri = geometry.vertices[geometry.triangles[prim]]  # (n, 3, 3)
    u = u[:, None]
    v = v[:, None]
    position = tri[:, 0] + u * (tri[:, 1] - tri[:, 0]) + v * (tri[:, 2] - tri[:, 0])
    ng = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    ng /= np.maximum(np.linalg.norm(ng, axis=1, keepdims=True), 1e-300)
    if geometry.corner_normals is None:
        ns = ng
    else:
        cn = geometry.corner_normals[prim]
        ns = (1.0 - u - v) * cn[:, 0] + u * cn[:, 1] + v * cn[:, 2]
        ns /= np.maximum(np.linalg.norm(ns, axis=1, keepdims=True), 1e-300)
    position, ng = frame.to_frame(position, ng, tau)
    if frame.spin is not None:
        _, ns = frame.to_frame(position, ns, tau)
    return position, ng, ns

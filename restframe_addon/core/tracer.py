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

from dataclasses import dataclass

import numpy as np

from .frames import FrameSet, RestFrame

_PAD = 1e-4  # bounds padding, relative to the frame's extent: float32 geometry may sit just outside


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


def _clip_to_bounds(frame: RestFrame, origin, d, t_lo, t_hi):
    """Slab test against the frame's bounds: the parameter range each ray spends inside them."""
    pad = _PAD * float(np.max(frame.hi - frame.lo)) + 1e-9 * float(np.max(np.abs(frame.anchor)))
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t_a = (frame.lo - pad - origin) * inv
        t_b = (frame.hi + pad - origin) * inv
    # fmin/fmax ignore the NaN of 0 * inf (a ray in the plane of a slab face)
    enter = np.fmax.reduce(np.fmin(t_a, t_b), axis=1)
    leave = np.fmin.reduce(np.fmax(t_a, t_b), axis=1)
    enter = np.fmax(enter, t_lo)
    leave = np.fmin(leave, t_hi)
    return enter, leave


def _query(frame: RestFrame, origin, d, t_lo, t_hi, occlusion: bool):
    """Intersect rays (frame coordinates, float64) with the frame's triangles.

    Returns (index into the inputs, t, prim, u, v) of hits, or for occlusion the
    indices of blocked rays.
    """
    enter, leave = _clip_to_bounds(frame, origin, d, t_lo, t_hi)
    idx = np.flatnonzero(enter <= leave)
    if len(idx) == 0:
        return (idx,) if occlusion else (idx, None, None, None, None)
    start = enter[idx]
    start_point = origin[idx] + start[:, None] * d[idx] - frame.anchor
    length = (leave[idx] - start).astype(np.float32)
    o32 = np.ascontiguousarray(start_point, dtype=np.float32)
    d32 = np.ascontiguousarray(d[idx], dtype=np.float32)
    if occlusion:
        blocked = frame.embree.run(o32, d32, dists=length, query="OCCLUDED") >= 0
        return (idx[blocked],)
    out = frame.embree.run(o32, d32, dists=length, output=1)
    hit = out["primID"] >= 0
    t = start[hit] + out["tfar"][hit].astype(np.float64)
    return idx[hit], t, out["primID"][hit], out["u"][hit], out["v"][hit]


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
    for k in frames.geometry:
        frame = frames.frames[k]
        fmap = frames.map(src, k)
        _, origin = fmap.events(tau0, x0)
        dk, w = fmap.rays(d)
        idx, t, prim, u, v = _query(frame, origin, dk, s_lo * w, best * w, occlusion=False)
        if len(idx) == 0:
            continue
        s = t / w[idx]
        nearer = s < best[idx]  # ties keep the earlier frame
        idx, s, t = idx[nearer], s[nearer], t[nearer]
        best[idx] = s
        hits.frame[idx] = k
        hits.s[idx] = s
        hits.s_frame[idx] = t
        hits.w[idx] = w[idx]
        hits.prim[idx] = prim[nearer]
        hits.u[idx] = u[nearer]
        hits.v[idx] = v[nearer]
    return hits


def occluded(frames: FrameSet, src: int, tau0, x0, d, s_lo, s_hi) -> np.ndarray:
    """True where anything in any frame lies on the backward ray with s_lo <= s <= s_hi."""
    n = len(d)
    s_lo = np.broadcast_to(np.asarray(s_lo, dtype=np.float64), (n,))
    s_hi = np.broadcast_to(np.asarray(s_hi, dtype=np.float64), (n,))
    blocked = np.zeros(n, dtype=bool)
    for k in frames.geometry:
        todo = np.flatnonzero(~blocked)
        if len(todo) == 0:
            break
        fmap = frames.map(src, k)
        _, origin = fmap.events(tau0[todo], x0[todo])
        dk, w = fmap.rays(d[todo])
        (idx,) = _query(frames.frames[k], origin, dk, s_lo[todo] * w, s_hi[todo] * w, occlusion=True)
        blocked[todo[idx]] = True
    return blocked


def hit_geometry(frame: RestFrame, prim, u, v):
    """Float64 position, unit geometric normal and unit shading normal at hits of one frame."""
    tri = frame.vertices[frame.triangles[prim]]  # (n, 3, 3)
    u = u[:, None]
    v = v[:, None]
    position = tri[:, 0] + u * (tri[:, 1] - tri[:, 0]) + v * (tri[:, 2] - tri[:, 0])
    ng = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    ng /= np.maximum(np.linalg.norm(ng, axis=1, keepdims=True), 1e-300)
    if frame.corner_normals is None:
        ns = ng
    else:
        cn = frame.corner_normals[prim]
        ns = (1.0 - u - v) * cn[:, 0] + u * cn[:, 1] + v * cn[:, 2]
        ns /= np.maximum(np.linalg.norm(ns, axis=1, keepdims=True), 1e-300)
    return position, ng, ns

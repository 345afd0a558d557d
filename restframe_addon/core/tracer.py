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

Surfaces some rays pass through -- hidden from their ray type (``Mesh.visibility``) or
transparent where a caller's ``see_through`` test says so (cut-outs) -- are skipped by
tracing those rays again from just past the hit: the same backward ray with a larger
``s_lo``, so nothing is re-derived.  Scenes without them trace exactly as before.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from . import rows
from .frames import FrameSet, RestFrame, triangle_normals
from .scene import RAY_SHADOW

_PAD = 1e-4  # bounds padding, relative to the frame's extent: float32 geometry may sit just outside
_SPIN_ITERATIONS = 24  # the hit-time iteration of spinning bodies (secant-accelerated; rim speed < c)
_MAX_PASS_THROUGH = 128  # surfaces one ray may pass through (hidden or cut out); past that the last one stops it


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
    d_frame: np.ndarray  # (N, 3) the ray's direction in the hit frame (mapped once, reused by shading)
    tau_frame: np.ndarray  # (N,) the ray's start time in the hit frame

    def take(self, index) -> "Hits":
        """The hits of some of the rays (an index or slice)."""
        if isinstance(index, slice):
            return Hits(*(getattr(self, f.name)[index] for f in fields(self)))
        return Hits(*(rows.take(getattr(self, f.name), index) for f in fields(self)))


def _clip_to_bounds(geometry, origin, d, t_lo, t_hi):
    """Slab test against the geometry's bounds (local coordinates): the parameter range inside them.

    ``origin`` is (N, 3) or one shared point (3,).  Written per axis: numpy's reductions over a
    length-3 axis cost more than the arithmetic.
    """
    pad = _padding(geometry)
    n = len(d)
    enter, leave, t_a, t_b = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    inverse = _one_inverse(d)
    if inverse is not None:  # parallel rays: per axis the sign of one number says which face is entered
        for axis, (inv, lo, hi) in enumerate(zip(inverse, geometry.lo.tolist(), geometry.hi.tolist())):
            np.multiply(np.subtract(lo - pad, origin[..., axis], out=t_a), inv, out=t_a)
            np.multiply(np.subtract(hi + pad, origin[..., axis], out=t_b), inv, out=t_b)
            near, far = (t_a, t_b) if inv[0] > 0.0 else (t_b, t_a)  # (fmin and fmax of the two, as below)
            np.fmax(t_lo if axis == 0 else enter, near, out=enter)
            np.fmin(t_hi if axis == 0 else leave, far, out=leave)
        return enter, leave
    inv, near = np.empty(n), np.empty(n)
    with np.errstate(divide="ignore", invalid="ignore"):
        for axis in range(3):
            np.copyto(inv, d[:, axis])  # (numpy divides a contiguous column 2.5x faster than a strided one)
            np.divide(1.0, inv, out=inv)
            if origin.ndim == 1:  # one shared origin (camera rays): each face's distance is one number
                np.multiply(inv, geometry.lo[axis] - pad - origin[axis], out=t_a)
                np.multiply(inv, geometry.hi[axis] + pad - origin[axis], out=t_b)
            else:
                np.multiply(np.subtract(geometry.lo[axis] - pad, origin[..., axis], out=t_a), inv, out=t_a)
                np.multiply(np.subtract(geometry.hi[axis] + pad, origin[..., axis], out=t_b), inv, out=t_b)
            # fmin/fmax ignore the NaN of 0 * inf (a ray in the plane of a slab face)
            np.fmax(t_lo if axis == 0 else enter, np.fmin(t_a, t_b, out=near), out=enter)
            np.fmin(t_hi if axis == 0 else leave, np.fmax(t_a, t_b, out=near), out=leave)
    return enter, leave


def _one_inverse(d):
    """For rays along one direction (a broadcast row, no component 0 and finite inverses): 1 / d per
    axis, each a broadcast column (numpy multiplies by one faster than by a number); else None."""
    if not (len(d) and _one_row(d)):
        return None
    components = d[0].tolist()
    if not all(components):
        return None
    inverse = [1.0 / c for c in components]  # (the same division as numpy's: IEEE, correctly rounded)
    if not all(map(math.isfinite, inverse)):
        return None
    return [np.ndarray((len(d),), np.float64, np.array(v), 0, (0,)) for v in inverse]


def _padding(geometry) -> float:
    """How far float32 geometry may sit outside its float64 bounds."""
    return _PAD * geometry.extent + 1e-14 * max(map(abs, geometry.anchor.tolist()))


def _query(frame: RestFrame, tau, origin, d, t_lo, t_hi, occlusion: bool):
    """Intersect rays (frame coordinates, float64, origin events at frame times tau; one shared
    origin may be given as a (3,) point) with the frame's triangles.

    Returns, for every ray, (t, prim, u, v) with t = inf where nothing is hit, or for
    occlusion a mask of the blocked rays.
    """
    if frame.spin is not None:
        if origin.ndim == 1:
            origin = np.broadcast_to(origin, d.shape)
        return _spin_query(frame, tau, origin, d, t_lo, t_hi, occlusion)
    origin, d = frame.to_local(origin, d)
    return _local_query(frame.geometry, origin, d, t_lo, t_hi, occlusion)


def _local_query(geometry, origin, d, t_lo, t_hi, occlusion: bool):
    if origin.ndim == 1:
        direct = _direct_reach(geometry, origin, t_lo)
        if direct.all():
            # a ray with t_hi < t_lo cannot meet the bounds before t_hi: embree finds nothing for it
            return _embree_query(geometry, origin - geometry.anchor, d, t_hi, occlusion)
        if direct.any():  # each ray takes its own route, whatever else is in the bundle
            return _split_query(geometry, origin, d, t_lo, t_hi, occlusion, direct)
    enter, leave = _clip_to_bounds(geometry, origin, d, t_lo, t_hi)
    inside = enter <= leave
    if inside.all():  # every ray reaches the bounds (the common case up close): no gathers
        return _clipped_query(geometry, origin, d, enter, leave, occlusion)
    idx = np.flatnonzero(inside)
    n = len(d)
    if occlusion:
        blocked = np.zeros(n, dtype=bool)
        if len(idx):
            blocked[idx] = _clipped_query(geometry, origin if origin.ndim == 1 else rows.take(origin, idx),
                                          rows.take(d, idx), enter[idx], leave[idx], occlusion)
        return blocked
    t, prim = np.full(n, np.inf), np.full(n, -1, dtype=np.int32)
    u, v = np.zeros(n, dtype=np.float32), np.zeros(n, dtype=np.float32)
    if len(idx):
        t[idx], prim[idx], u[idx], v[idx] = _clipped_query(geometry,
                                                           origin if origin.ndim == 1 else rows.take(origin, idx),
                                                           rows.take(d, idx), enter[idx], leave[idx], occlusion)
    return t, prim, u, v


_DIRECT_REACH = 4.0  # in extents: how far a shared origin may be from the bounds' centre for unclipped queries


def _direct_reach(geometry, origin, t_lo) -> np.ndarray:
    """Which rays from one shared (local) origin can go to embree unclipped (a mask)?

    Those whose origin is near enough to the geometry that float32 coordinates relative to
    the anchor lose no more than the geometry's own float32 vertices, and for which no part
    of the bounds is nearer than the ray's start (embree starts every ray at 0).  Decided
    per ray: the two routes round differently in float32, and a ray's hit must not depend
    on the tile or batch it is traced in.
    """
    offset = (origin - geometry.anchor).tolist()
    half = (0.5 * (geometry.hi - geometry.lo)).tolist()
    reach = _DIRECT_REACH * geometry.extent
    if math.fsum(c * c for c in offset) > reach * reach:
        return np.zeros(len(t_lo), dtype=bool)
    pad = _padding(geometry)
    gap = math.sqrt(math.fsum(max(abs(c) - h - pad, 0.0) ** 2 for c, h in zip(offset, half)))
    return t_lo <= gap


def _split_query(geometry, origin, d, t_lo, t_hi, occlusion: bool, direct):
    """Rays from one shared origin, the ``direct`` ones unclipped and the others clipped."""
    n = len(d)
    parts = [(np.flatnonzero(direct), True), (np.flatnonzero(~direct), False)]
    if occlusion:
        blocked = np.zeros(n, dtype=bool)
        for idx, unclipped in parts:
            if unclipped:
                blocked[idx] = _embree_query(geometry, origin - geometry.anchor, rows.take(d, idx), t_hi[idx], occlusion)
            else:
                blocked[idx] = _local_query(geometry, origin, rows.take(d, idx), t_lo[idx], t_hi[idx], occlusion)
        return blocked
    t, prim = np.full(n, np.inf), np.full(n, -1, dtype=np.int32)
    u, v = np.zeros(n, dtype=np.float32), np.zeros(n, dtype=np.float32)
    for idx, unclipped in parts:
        if unclipped:
            part = _embree_query(geometry, origin - geometry.anchor, rows.take(d, idx), t_hi[idx], occlusion)
        else:
            part = _local_query(geometry, origin, rows.take(d, idx), t_lo[idx], t_hi[idx], occlusion)
        t[idx], prim[idx], u[idx], v[idx] = part
    return t, prim, u, v


def _clipped_query(geometry, origin, d, enter, leave, occlusion: bool):
    """Rays moved to where they enter the bounds (float64), queried from there in float32."""
    o32 = np.empty(d.shape, dtype=np.float32)
    start = np.empty(len(d))
    for axis in range(3):  # the start point (float64) one axis at a time, rounded once into embree's origins
        np.multiply(enter, d[:, axis], out=start)
        start += origin[..., axis] - geometry.anchor[axis]
        o32[:, axis] = start
    result = _embree_run(geometry, o32, d, np.subtract(leave, enter, out=np.empty(len(d), np.float32)), occlusion)
    if occlusion:
        return result
    t, prim, u, v = result
    t += enter
    return t, prim, u, v


def _embree_query(geometry, origin, d, length, occlusion: bool):
    """One embree call: rays from one shared local origin (3,) (relative to the anchor) up to path
    length ``length`` (negative: no query).  Returns (t, prim, u, v), t = inf on a miss, or the blocked mask.

    The origin goes to embree as one float32 row broadcast to every ray (embreex reads each ray's
    origin through the array's strides), and a length the same for every ray as one number filled
    in: no pass converts n copies of the same numbers (the same roundings)."""
    n = len(d)
    o32 = rows.broadcast(np.asarray(origin, dtype=np.float32)[None], n)
    lengths = np.full(n, length[0], np.float32) if n and _one_row(length) else length.astype(np.float32)
    return _embree_run(geometry, o32, d, lengths, occlusion)


def _embree_run(geometry, o32, d, dists, occlusion: bool):
    """:func:`_embree_query` from its float32 origins and lengths."""
    d32 = np.ascontiguousarray(d, dtype=np.float32)
    if occlusion:
        return geometry.embree.run(o32, d32, dists=dists, query="OCCLUDED") >= 0
    out = geometry.embree.run(o32, d32, dists=dists, output=1)
    prim = out["primID"]
    miss = prim < 0
    if len(geometry.piece_start) > 1:  # triangles were attached in pieces: number them as the geometry does
        prim = np.where(miss, np.int32(-1), geometry.piece_start[out["geomID"]] + prim)
    t = out["tfar"].astype(np.float64)
    t[miss] = np.inf
    return t, prim, out["u"], out["v"]


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
    n = len(d)
    # first guess: where the ray passes the pivot most closely
    guess = np.clip(-np.einsum("ij,ij->i", origin - frame.offset, d), t_lo, t_hi)
    previous = np.full(n, np.nan)
    previous_f = np.full(n, np.nan)
    result_t = np.full(n, np.inf)
    prim = np.full(n, -1, dtype=np.int32)
    u = np.zeros(n, dtype=np.float32)
    v = np.zeros(n, dtype=np.float32)
    todo = np.arange(n)
    for _ in range(_SPIN_ITERATIONS):
        if len(todo) == 0:
            break
        o_l, d_l = frame.to_local(origin[todo], d[todo], tau[todo] - guess[todo])
        t, p, uu, vv = _local_query(geometry, o_l, d_l, t_lo[todo], t_hi[todo], occlusion=False)
        hit = p >= 0
        result_t[todo[~hit]], prim[todo[~hit]] = np.inf, -1
        todo, t = todo[hit], t[hit]
        if len(todo) == 0:
            break
        result_t[todo], prim[todo], u[todo], v[todo] = t, p[hit], uu[hit], vv[hit]
        f = t - guess[todo]
        done = np.abs(f) * rim <= frame.tolerance
        with np.errstate(divide="ignore", invalid="ignore"):
            secant = guess[todo] - f * (guess[todo] - previous[todo]) / (f - previous_f[todo])
        usable = np.isfinite(secant) & (secant >= t_lo[todo]) & (secant <= t_hi[todo])
        previous[todo], previous_f[todo] = guess[todo], f
        guess[todo] = np.where(usable, secant, t)
        todo = todo[~done]
    if occlusion:
        return prim >= 0
    return result_t, prim, u, v


def _ray_range(frame: RestFrame, tau, origin, d, s_lo, s_hi):
    """Clip path lengths of rays (frame coordinates) to the stretch of spacetime where the frame's body holds."""
    if frame.window is None:
        return s_lo, s_hi
    return frame.window.clip(tau, origin, d, s_lo, s_hi)


class TraceCache:
    """What the tracer derives from a frame set and keeps for later bundles: the culling
    cones of frames seen from observation events (every tile of a perspective camera shares
    its event), the body boxes per source frame (and per set of candidate frames, :class:`_Boxes`),
    a parallel bundle's direction mapped into each frame (a sharp sun's: the same for every
    tile and sample) and the triangle rows of small meshes (:func:`hit_geometry`).

    Not thread-safe: each render thread (or tile) owns one and passes it explicitly; the
    frame set itself stays read-only, and so is everything handed out from here (but for the
    memo of directions in each :class:`_Boxes`, :meth:`_Boxes.along`, which only this thread reaches).
    """

    _MAX_CONES = 4096  # many observation events (animations, secondary bundles): start afresh past this
    _MAX_KEPT = 1024  # sets of candidate frames, directions mapped: start afresh past this
    _BOXES_AT_ONCE = 64  # up to this many geometry frames, the body boxes seen from each are worked out at once

    def __init__(self):
        self._cones: dict = {}
        self._body_boxes: dict[int, _Boxes] = {}  # src -> every geometry frame's boxes
        self._boxes: dict[tuple, _Boxes] = {}  # (src, some frames) -> theirs
        self._directions: dict[tuple, tuple] = {}  # (src, k, direction's bytes) -> (mapped direction, s'/s)
        self._hit_tables: dict[int, tuple] = {}  # id(geometry) -> (geometry, its rows for hit_geometry)
        self._flat: dict[int, tuple] = {}  # id(geometry) -> (geometry, _flat_side of it)
        self._uv_tables: dict[int, tuple] = {}  # id(geometry) -> (geometry, its corners' UVs for hit_uv)

    def cones(self, keys: list, compute) -> list:
        """The cones kept under each key; ``compute(missing)`` works out, at once, those of the
        keys at the indices ``missing``."""
        missing = [i for i, key in enumerate(keys) if key not in self._cones]
        if missing:
            if len(self._cones) + len(missing) > self._MAX_CONES:
                self._cones.clear()
                missing = list(range(len(keys)))
            for i, cones in zip(missing, compute(missing)):
                self._cones[keys[i]] = cones
        return [self._cones[key] for key in keys]

    def boxes(self, frames: FrameSet, src: int, ks) -> "_Boxes":
        """The :class:`_Boxes` of the frames ``ks`` seen from frame src.  The first request works out
        those of every geometry frame seen from src and, up to ``_BOXES_AT_ONCE`` frames, from each
        geometry frame too, in one pass (``FrameSet.body_boxes_of``: hit frames are where shadow and
        secondary rays start)."""
        every = self._body_boxes.get(src)
        if every is None:
            sources = [src]
            if len(frames.geometry) <= self._BOXES_AT_ONCE:
                sources += [k for k in frames.geometry if k != src and k not in self._body_boxes]
            for k, boxes in zip(sources, _boxes_of_sources(*frames.body_boxes_of(sources))):
                self._body_boxes[k] = boxes
            every = self._body_boxes[src]
        if ks is frames.geometry:
            return every
        key = (src, tuple(ks))
        kept = self._boxes.get(key)
        if kept is None:
            if len(self._boxes) >= self._MAX_KEPT:
                self._boxes.clear()
            kept = self._boxes[key] = _boxes_among(frames, ks, (every.t, every.x, every.velocity, every.half))
        return kept

    def direction_in(self, frames: FrameSet, src: int, k: int, direction) -> tuple:
        """(d', w) of one direction (3,) of frame src mapped into frame k (``FrameMap.rays``), read-only."""
        key = (src, k, direction.tobytes())
        kept = self._directions.get(key)
        if kept is None:
            if len(self._directions) >= self._MAX_KEPT:
                self._directions.clear()
            d_k, w = _direction_in(frames, src, k, direction)
            d_k = np.array(d_k)  # (its own: a map into the same frame hands back the caller's array)
            d_k.flags.writeable = False
            kept = self._directions[key] = (d_k, w)
        return kept

    def hit_table(self, geometry) -> tuple:
        """:func:`hit_geometry`'s numbers of every triangle of ``geometry``: per axis, contiguous
        (triangles,) tables of the first corner and the two edges (1-D gathers into contiguous
        columns: the gathered rows of all four were read with a 32-byte stride, twice as slow),
        the unit normals (triangles, 3) (one row gather), the one unit normal (1, 3) of all its
        triangles where they have one (a flat mesh: its hits share it), else None, and per axis
        the three corners' normals (triangles,) of a smooth mesh (else None); made at its first
        lit hit.  An axis along which every corner and edge is +0 (a flat mesh's, its vertices at
        the anchor's coordinate there) has None for its tables: its hits' coordinate is
        ``u 0 + 0 + v 0 = +0`` whatever their finite u, v, so nothing is gathered for it; a table
        of one number (a quad's first corner, shared by its two triangles) is that number."""
        kept = self._hit_tables.get(id(geometry))
        if kept is None or kept[0] is not geometry:
            corner, e1, e2, normal = _triangle_rows(geometry, np.arange(len(geometry.triangles)))
            columns = tuple(None if not np.any(corner[:, axis]) and not np.any(e1[:, axis]) and not np.any(e2[:, axis])
                            and not np.signbit(corner[:, axis]).any()
                            else tuple(_one_or_table(a[:, axis]) for a in (corner, e1, e2)) for axis in range(3))
            one = normal[:1] if len(normal) and (normal == normal[:1]).all() else None
            smooth = geometry.corner_normals
            corners = None if smooth is None else tuple(
                tuple(np.ascontiguousarray(smooth[:, k, axis]) for k in range(3)) for axis in range(3))
            kept = self._hit_tables[id(geometry)] = (geometry, columns, normal, one, corners)
        return kept[1:]

    def uv_table(self, geometry) -> tuple | None:
        """``shading.hit_uv``'s UVs of every triangle of a small mesh ``geometry`` (at most
        ``_HIT_TABLE_TRIANGLES``; else None), one contiguous (triangles,) table per corner of each
        component (U of the three corners, then V), made at its first lit hit: 1-D gathers into
        contiguous columns instead of six strided passes over (n, 3, 2) gathered rows.  A table
        whose triangles all share one value is that number (a quad's corners: no gather)."""
        if geometry.corner_uvs is None or len(geometry.triangles) > _HIT_TABLE_TRIANGLES:
            return None
        kept = self._uv_tables.get(id(geometry))
        if kept is None or kept[0] is not geometry:
            uvs = geometry.corner_uvs
            kept = self._uv_tables[id(geometry)] = (
                geometry, tuple(tuple(_one_value_or_table(uvs[:, corner, c]) for corner in range(3)) for c in range(2)))
        return kept[1]

    def flat_side(self, geometry):
        """:func:`_flat_side` of ``geometry``, worked out at its first shadow rays."""
        kept = self._flat.get(id(geometry))
        if kept is None or kept[0] is not geometry:
            kept = self._flat[id(geometry)] = (geometry, _flat_side(geometry))
        return kept[1]


def _one_value_or_table(values):
    """The one number every entry of ``values`` (1-D) is bit for bit (0.0 and -0.0 differ), else a
    contiguous copy of them."""
    values = np.ascontiguousarray(values)
    bits = values.view(f"u{values.itemsize}")
    return float(values[0]) if len(values) and bool((bits == bits[0]).all()) else values


def _flat_side(geometry):
    """(axis, least |normal component|) of a body whose vertices all share one coordinate: the
    axis, and the smallest size of that component of its triangles' normals as embree works
    them out (the cross product of float32 edges); None for any other body, or one with a
    degenerate triangle."""
    flat = np.flatnonzero(geometry.lo == geometry.hi)
    if len(flat) == 0:
        return None
    axis = int(flat[0])
    b, c = (axis + 1) % 3, (axis + 2) % 3
    local = (geometry.vertices - geometry.anchor).astype(np.float32)  # embree's vertices (Geometry.anchor)
    corners = [local[geometry.triangles[:, i]] for i in range(3)]
    e1, e2 = corners[1] - corners[0], corners[2] - corners[0]
    least = float(np.min(np.abs(e1[:, b] * e2[:, c] - e1[:, c] * e2[:, b]))) if len(e1) else 0.0
    return (axis, least) if least > 0.0 else None


_FLAT_CLEAR = 2.0 ** -100  # |normal component| x |ray's start or direction component| at least this (float32 normal numbers)


def _leave_flat_body(frame: RestFrame, cache: TraceCache | None, origin, d, s_lo) -> bool:
    """Whether every ray (frame coordinates, ``s_lo`` >= 0) starts on one side of a flat body's plane
    and runs away from it, so that embree can find none of its triangles (and need not be asked).

    Every vertex of such a body is at the anchor's coordinate, so its float32 coordinate there is
    exactly 0 and so is that component of every edge: the triangles' normals (the cross product of
    two edges) are exactly 0 in the other two components, and the signed distance and the
    denominator of embree's ray-triangle test are single products of the normal's one component
    with the ray's float32 start and direction there.  With both of one sign and not tiny
    (``_FLAT_CLEAR``), the hit's path length is negative: no hit, whatever the rounding.  The
    start a query rounds is the origin less the anchor (less the frame's offset first) plus
    ``enter d`` with enter >= s_lo >= 0; rounding is monotonic, so the least (greatest) start
    is that of the least (greatest) origin.
    """
    if cache is None or frame.spin is not None or len(d) == 0:
        return False
    flat = cache.flat_side(frame.geometry)
    if flat is None or not float(s_lo[0] if _one_row(s_lo) else s_lo.min()) >= 0.0:
        return False
    axis, least = flat
    clear = max(_FLAT_CLEAR / least, 2.0 ** -120)  # (and a start or direction float32 rounds to a normal number)
    direction, start = d[:, axis], origin[:, axis]
    offset, plane = float(frame.offset[axis]), float(frame.geometry.anchor[axis])
    if float(direction[0] if _one_row(d) else direction.min()) >= clear:
        return (float(start.min()) - offset) - plane >= clear
    if float(direction[0] if _one_row(d) else direction.max()) <= -clear:
        return (float(start.max()) - offset) - plane <= -clear
    return False


def _direction_in(frames: FrameSet, src: int, k: int, direction) -> tuple:
    """(d', w): one direction (3,) of frame src mapped into frame k (``FrameMap.rays``), w a number."""
    d_k, w = frames.map(src, k).rays(direction)
    return d_k, float(w)


def trace_nearest(frames: FrameSet, src: int, tau0, x0, d, s_lo, s_hi, cache: TraceCache | None = None,
                  ray: int | None = None, see_through=None, runs: "RunBounds | None" = None) -> Hits:
    """The visible (most recent) hit of each backward ray, over all geometry frames.

    ``tau0`` (N,), ``x0`` (N, 3), ``d`` (N, 3) unit, in frame ``src``;
    only hits with ``s_lo <= s <= s_hi`` count.  ``cache``: the calling thread's (None: keep nothing).
    ``ray``: the rays' type (a ``RAY_*`` bit; None: every surface counts): surfaces hidden from it
    are passed through.  ``see_through(hits, rays, layer)``: True where the hits (of the rays with
    indices ``rays``; ``layer`` = how many surfaces they passed already) let the ray pass (None: none do).
    ``runs``: bounds of the directions of the rays' runs that hold for every bundle traced with it
    (a tile's camera rays, all its samples: :class:`RunBounds`), which then culls them once.
    The hits' arrays are for reading: some are the rays' own, or read-only views (no frame left
    after the cull: :func:`no_hits` of the bundle, read-only).
    """
    hits = _nearest(frames, src, tau0, x0, d, s_lo, s_hi, cache, runs)
    hidden = ray is not None and bool(frames.hidden_rays & ray)
    if not hidden and see_through is None:
        return hits
    return _pass_through(frames, src, tau0, x0, d, s_hi, cache, ray if hidden else None, see_through, hits)


def _pass_through(frames: FrameSet, src: int, tau0, x0, d, s_hi, cache, ray, see_through, hits: Hits) -> Hits:
    """Trace the rays whose hits they pass through again from just past those hits, until
    every ray stops at a surface or misses (at most ``_MAX_PASS_THROUGH`` times)."""
    n = len(d)
    s_hi = _per_ray(s_hi, n)
    hits = Hits(*(np.array(getattr(hits, f.name)) for f in fields(hits)))  # our own, to write into
    rays = np.flatnonzero(hits.frame >= 0)
    for layer in range(_MAX_PASS_THROUGH):
        if len(rays) == 0:
            break
        found = hits.take(rays)
        through = np.zeros(len(rays), dtype=bool)
        if ray is not None:
            through |= ~_visible(frames, found, ray)
        if see_through is not None:
            through |= see_through(found, rays, layer)
        rays, found = rays[through], found.take(through)
        if len(rays) == 0:
            break
        # just past the hit: the frame's surface offset, in path length of the source frame
        past = found.s + frames.surface_offsets[found.frame] / found.w
        again = _nearest(frames, src, tau0[rays], rows.take(x0, rays), rows.take(d, rays), past, s_hi[rays], cache)
        for f in fields(hits):
            getattr(hits, f.name)[rays] = getattr(again, f.name)
        rays = rays[again.frame >= 0]
    return hits


def _visible(frames: FrameSet, hits: Hits, ray: int) -> np.ndarray:
    """Whether each hit's triangle is seen by rays of type ``ray``."""
    seen = np.ones(len(hits.frame), dtype=bool)
    for k in frames_hit(hits):
        visibility = frames.frames[k].geometry.tri_visibility
        if visibility is not None:
            sel = np.flatnonzero(hits.frame == k)
            seen[sel] = (visibility[hits.prim[sel]] & ray) != 0
    return seen


def _nearest(frames: FrameSet, src: int, tau0, x0, d, s_lo, s_hi, cache: TraceCache | None,
             runs: "RunBounds | None" = None) -> Hits:
    """The nearest hit of each ray, whatever surface it is (see :func:`trace_nearest`)."""
    n = len(d)
    s_lo = _per_ray(s_lo, n)
    best = _per_ray(s_hi, n)
    hits = None
    candidates = frames.candidates(src, tau0, x0)
    shared = _shared_origin(tau0, x0)
    # rays from one event are culled by the frames' body boxes and bounding cones, a lone frame's
    # too: a ray embree sends past the bounds still costs ~26 ns, more than the culling
    if shared is not None and n:
        candidates, culled = _cull_bundle(frames, src, candidates, shared, d, s_lo, best, cache, runs)
    else:
        culled = [None] * len(candidates)
    for k, rays in zip(candidates, culled):
        frame = frames.frames[k]
        fmap = frames.map(src, k)
        d_rays, lo, hi = (d, s_lo, best) if rays is None else (rows.take(d, rays), s_lo[rays], best[rays])
        if shared is not None:
            tau_k, origin = fmap.events(np.array(shared[0]), shared[1])
            tau_k = np.broadcast_to(tau_k, lo.shape)
        else:
            tau_k, origin = fmap.events(tau0, x0) if rays is None else fmap.events(tau0[rays], rows.take(x0, rays))
        if fmap.is_identity:
            dk, w = d_rays, None
        else:
            dk, w = fmap.rays(d_rays)
            lo, hi = lo * w, hi * w
        lo, hi = _ray_range(frame, tau_k, origin, dk, lo, hi)
        t, prim, u, v = _query(frame, tau_k, origin, dk, lo, hi, occlusion=False)
        first = hits is None and rays is None  # the first frame to see every ray: its hits as they are
        # a later frame's hits are merged by their indices (only a hit can be nearer: a miss's s is
        # inf), by masks over every ray where they are most of the bundle
        found = None if first else np.flatnonzero(prim >= 0)
        if rays is None and found is not None and len(found) > _MASKED_SHARE * n:
            found = None
        rest = t if found is None else rows.take(t, found)  # (path lengths in frame k of the rays compared)
        s = rest if w is None else rest / (w if found is None else rows.take(w, found))
        # ties keep the earlier frame
        nearer = s < (best if found is None else best[found if rays is None else rays[found]])
        if first:
            # every ray hit, nearer than its bound (a floor under the camera): its hits as they are,
            # nothing to select (and min(best, s) is s)
            every = bool(nearer.all())
            if not every:
                s = np.where(nearer, s, np.inf)
            # s_frame, w, d_frame and tau_frame shared (s, a broadcast 1, the rays' own arrays) until a
            # later frame writes into them
            hits = Hits(frame=np.full(n, k, np.int32) if every else np.where(nearer, np.int32(k), np.int32(-1)), s=s,
                        s_frame=s if w is None else t if every else np.where(nearer, t, np.inf),
                        w=np.broadcast_to(1.0, (n,)) if w is None else w,
                        prim=prim if every else np.where(nearer, prim, np.int32(-1)),
                        u=u, v=v, d_frame=dk, tau_frame=tau_k)
            borrowed = True
            if k != candidates[-1]:  # (the later frames' bound)
                best = s if every else np.minimum(best, s)
            continue
        if hits is None:
            hits, borrowed = no_hits(n), False
            best = best.copy()
        if not nearer.any():
            continue
        if borrowed:
            hits, borrowed = _owned(hits), False
        if found is None:
            _update(hits, best, nearer, k, s, t, w, prim, u, v, dk, tau_k)
        else:
            keep = found[nearer]  # (in this frame's rays)
            _update(hits, best, keep if rays is None else rays[keep], k, s[nearer], rest[nearer],
                    None if w is None else w[keep], prim[keep], u[keep], v[keep], rows.take(dk, keep), tau_k[keep])
    return no_hits(n, read_only=True) if hits is None else hits  # (no frame left after the cull: nothing to write)


_MASKED_SHARE = 0.5  # hits of a later frame among all rays above which _nearest merges by masks, not indices


def _owned(hits: Hits) -> Hits:
    """The first frame's hits (:func:`_nearest`) with arrays of their own to write into."""
    return Hits(hits.frame, hits.s, np.array(hits.s_frame), np.array(hits.w), hits.prim, hits.u, hits.v,
                np.array(hits.d_frame), np.array(hits.tau_frame))


def _per_ray(value, n: int) -> np.ndarray:
    """A per-ray float64 array from an array or one number (read-only then)."""
    value = np.asarray(value, dtype=np.float64)
    if value.shape == (n,):
        return value
    return rows.broadcast(value[None], n) if value.ndim == 0 else np.broadcast_to(value, (n,))


def frames_hit(hits: Hits) -> np.ndarray:
    """The frames that some ray hit, in increasing order (a count per frame: no sort of the whole bundle)."""
    frame = hits.frame
    if len(frame) == 0:
        return np.zeros(0, dtype=np.intp)
    highest = int(frame.max())
    # read as unsigned, a miss (-1) is the largest number: the minimum is the lowest frame hit
    lowest = int(frame.view(np.dtype(f"u{frame.itemsize}")).min())
    if highest < 0 or lowest == highest:  # nothing hit, or one frame (the common case): two fast reductions
        return np.arange(max(highest, 0), highest + 1, dtype=np.intp)
    return np.flatnonzero(np.bincount(frame + 1)[1:])


def no_hits(n: int, read_only: bool = False) -> Hits:
    """The hits of ``n`` rays that hit nothing (``read_only``: broadcast views, for callers that only read them)."""
    if read_only:
        return Hits(*(np.broadcast_to(getattr(_NO_HIT, f.name), (n, *getattr(_NO_HIT, f.name).shape[1:]))
                      for f in fields(Hits)))
    return Hits(frame=np.full(n, -1, dtype=np.int32), s=np.full(n, np.inf), s_frame=np.full(n, np.inf),
                w=np.ones(n), prim=np.full(n, -1, dtype=np.int32), u=np.zeros(n, dtype=np.float32),
                v=np.zeros(n, dtype=np.float32), d_frame=np.zeros((n, 3)), tau_frame=np.zeros(n))


_NO_HIT = no_hits(1)  # one ray's, for read-only views


def _update(hits: Hits, best, where, k, s, t, w, prim, u, v, d_frame, tau_frame):
    """Record the hits of frame k for the rays ``where`` (a mask over all rays, or indices with
    values already selected)."""
    if where.dtype == bool:
        for target, value in ((best, s), (hits.s, s), (hits.s_frame, t), (hits.prim, prim), (hits.u, u), (hits.v, v),
                              (hits.tau_frame, tau_frame)):
            np.copyto(target, value, where=where)
        for axis in range(3):
            np.copyto(hits.d_frame[:, axis], d_frame[:, axis], where=where)
        np.copyto(hits.frame, k, where=where)
        np.copyto(hits.w, 1.0 if w is None else w, where=where)
        return
    best[where] = hits.s[where] = s
    hits.frame[where] = k
    hits.s_frame[where] = t
    hits.prim[where] = prim
    hits.u[where] = u
    hits.v[where] = v
    hits.w[where] = 1.0 if w is None else w
    rows.put(hits.d_frame, where, d_frame)
    hits.tau_frame[where] = tau_frame


def _shared_origin(tau0, x0):
    """(tau, x) when every ray starts at the same event by construction (broadcast views: a
    perspective camera's rays), else None.  Rays that merely happen to start at one event
    (a bundle of one) are traced as any others: the shared route rounds differently, and a
    ray's hit must not depend on the bundle it is traced in."""
    if len(tau0) == 0 or not (tau0.strides[0] == 0 and x0.strides[0] == 0):
        return None
    return float(tau0[0]), np.array(x0[0])


_CONE_SAMPLES = 16


class RunBounds:
    """Bounds (low, high), each (3, b), of the directions of each run of ``_RUN`` consecutive rays
    of every bundle from one event traced with it (``camera.CameraRays.run_bounds``: a tile's
    pixels, wherever in them its samples fall), and the runs near each frame's body box worked
    out from them once, for all those bundles (:func:`_cull_bundle`)."""

    RUN = 16  # rays per run (``_RUN``)

    def __init__(self, low, high, within: "tuple[RunBounds, int] | None" = None):
        self.bounds = low, high
        self._within = within  # (the RunBounds these runs are a stretch of, the first of them there)
        self._near: dict[tuple, list] = {}  # (src, frames, event) -> the runs near each frame
        self._kept: dict[tuple, dict] = {}  # (src, frames, event, rays) -> the rays of each frame without cones

    def stretch(self, first: int, count: int) -> "RunBounds":
        """The runs ``first`` .. ``first + count - 1`` of these (a batch of some of a tile's pixels):
        their bounds, and the runs near each frame taken from those worked out for all of these (the
        same runs: each run is tested on its own bounds, whatever others are tested with it)."""
        low, high = self.bounds
        return RunBounds(low[:, first:first + count], high[:, first:first + count], (self, first))

    def near(self, key, rays: int, compute) -> tuple:
        """(:meth:`runs_near`, the rays of each frame without cones kept for bundles of ``rays`` rays)."""
        return self.runs_near(key, compute), self._kept.setdefault((*key, rays), {})

    def runs_near(self, key, compute) -> list:
        """The runs near each frame for ``key`` = (src, frames, event), worked out by
        ``compute(bounds)`` once (a stretch's from those of the runs it is a stretch of)."""
        near = self._near.get(key)
        if near is None:
            if self._within is None:
                near = compute(self.bounds)
            else:
                whole, first = self._within
                stop = first + self.bounds[0].shape[1]
                near = [runs[start:end] - first for runs in whole.runs_near(key, compute)
                        for start, end in [np.searchsorted(runs, (first, stop)).tolist()]]
            self._near[key] = near
        return near


_ANY_PATH = (0.0, math.inf)  # the path range of RunBounds' culling: any bundle's whose rays start at s >= 0


def _cull_bundle(frames: FrameSet, src: int, ks, shared, d, s_lo, s_hi, cache: TraceCache | None,
                 tile_runs: RunBounds | None = None):
    """(frames, their rays): the frames of ``ks`` that some ray from one ``shared`` event may hit
    and, for each, the indices of the rays that may (a superset of them; None: every ray).

    The runs of ``_RUN`` consecutive rays that miss a frame's body box are dropped first, every
    frame at once (:func:`_runs_near_bodies`); a frame whose bounding spheres are tighter than its
    box (:func:`_cones_pay`) then keeps only the rays of those runs that point into their cones
    (:func:`_toward`).  A frame left with no ray is left out: nothing is mapped or queried for it.
    With ``tile_runs`` (:class:`RunBounds` of these rays' runs) the runs near the body boxes, and the
    rays of frames without cones, are those worked out for the first bundle traced with it (over
    any path length from 0: a superset, so the same hits).
    """
    n = len(d)
    if len(ks) == 1 and frames.frames[ks[0]].geometry.clusters is None:
        return _cull_for_lone_frame(frames, src, ks[0], shared, d, cache)
    extent = (float(np.max(np.abs(shared[1]))), abs(shared[0]))  # (for the rounding margin of the body boxes)
    # every ray's path range, for the body boxes (of a bound broadcast to every ray, its one number: no
    # pass; the greatest only where tile_runs' any path length from 0 does not stand in for it)
    lowest = float(s_lo[0] if _one_row(s_lo) else np.min(s_lo))
    kept = None  # the rays of frames without cones, from tile_runs
    if tile_runs is not None and tile_runs.bounds[0].shape[1] == n // _RUN and lowest >= 0.0:
        run_bounds = tile_runs.bounds
        near, kept = tile_runs.near((src, tuple(ks), shared[0], shared[1].tobytes()), n,
                                    lambda bounds: _runs_near_bodies(frames, src, ks, cache, extent, shared, bounds,
                                                                     _ANY_PATH))
    else:
        run_bounds = _run_bounds(d)
        path_range = lowest, float(s_hi[0] if _one_row(s_hi) else np.max(s_hi))
        near = _runs_near_bodies(frames, src, ks, cache, extent, shared, run_bounds, path_range)
    coned = [k for k, pays in zip(ks, _cones_pay(frames, src, ks, cache)) if pays]
    cones = dict(zip(coned, _frame_cones(frames, src, coned, shared, cache))) if coned else {}
    bundle = None  # the cones of the whole bundle and of its runs, for the first frame with cones
    frames_kept, culled = [], []
    for k, runs in zip(ks, near):
        rays = None
        if cones.get(k) is not None and len(runs):
            if bundle is None:
                bundle = (*_bundle_cone(d), _sub_bundle_cones(run_bounds))
            rays = _toward(cones[k], d, bundle, runs)
        if rays is None:  # (no cones, or the bundle lies in one)
            rays = _rays_of_runs(runs, n) if kept is None else kept.get(k)
            if rays is None:
                rays = kept[k] = _rays_of_runs(runs, n)
                rays.flags.writeable = False  # (every later bundle's too)
        if len(rays):
            frames_kept.append(k)
            culled.append(_gathered(rays, n, not frames.map(src, k).is_identity))
    return frames_kept, culled


def _cull_for_lone_frame(frames: FrameSet, src: int, k: int, shared, d, cache: TraceCache | None):
    """:func:`_cull_bundle` for the one frame of a scene (no culling clusters: one sphere holds
    it, :func:`_lone_sphere`): the whole bundle's cone against the sphere's first (no pass over
    the rays where it settles them), then each ray against it (body boxes and sub-bundles cost
    more than they save with one sphere)."""
    cones = _frame_cones(frames, src, [k], shared, cache)[0]
    if cones is None:  # the event is inside the sphere
        return [k], [None]
    meeting = _cones_meeting(cones, *_bundle_cone(d))
    if meeting is None:  # the bundle lies in the sphere's cone
        return [k], [None]
    (axis,), (spread,) = cones
    rays = np.flatnonzero(d @ axis >= np.cos(spread)) if len(meeting) else np.zeros(0, dtype=np.intp)
    return ([k], [_gathered(rays, len(d), not frames.map(src, k).is_identity)]) if len(rays) else ([], [])


def _gathered(rays, n: int, boosted: bool = False):
    """The rays of a bundle of ``n`` to gather for a frame, or None (all of them) when they are
    more than ``_GATHER_SHARE`` of it (``_BOOSTED_GATHER_SHARE`` for a frame the rays are boosted
    into: each ray traced also costs its boost): gathering the kept rays and scattering their hits
    then costs more than tracing the others, which miss (the same hits)."""
    return None if len(rays) > (_BOOSTED_GATHER_SHARE if boosted else _GATHER_SHARE) * n else rays


def _rays_of_runs(runs, n: int) -> np.ndarray:
    """Indices of the rays of ``runs`` (indices of runs of ``_RUN`` consecutive rays, in
    increasing order) and of the rays past the last whole run, of ``n`` rays."""
    whole = _members(runs)
    return np.append(whole, np.arange(_RUN * (n // _RUN), n)) if n % _RUN else whole


def _members(runs) -> np.ndarray:
    """Indices of the members of ``runs`` (indices of runs of ``_RUN`` consecutive items: rays, or
    runs in blocks of runs), in the order of the runs."""
    return (runs[:, None] * _RUN + np.arange(_RUN)).ravel()


def _cones_pay(frames: FrameSet, src: int, ks, cache: TraceCache | None) -> list[bool]:
    """Whether each frame of ``ks`` is worth culling by its sphere cones after its body box: when
    its bounding spheres (a spinning body's about its pivot, else the culling clusters) hold it
    more tightly than its box, by mean projected area (over all directions: pi r^2 for a sphere,
    2 (ab + bc + ca) for a box of half-extents a, b, c).  Else they drop few of the rays the box
    keeps, for a per-frame cost of many rays' maps and queries (a row of the 11x11 bars: spheres
    4x the box).  Kept with the frames' boxes (a thread's, for all its bundles)."""
    boxes = _boxes(frames, src, ks, cache)
    if boxes.cones_pay is not None:
        return boxes.cones_pay
    pays = []
    for k, (a, b, c) in zip(ks, boxes.half.tolist()):
        frame = frames.frames[k]
        if frame.spin is not None:
            squares = frame.geometry.radius ** 2
        elif frame.geometry.clusters is not None:
            squares = float(np.sum(frame.geometry.clusters[:, 3] ** 2))
        else:
            pays.append(False)
            continue
        pays.append(math.pi * squares < 2.0 * (a * b + b * c + c * a))
    boxes.cones_pay = pays
    return pays


def _toward(cones, d, bundle, runs):
    """Indices of the rays of ``runs`` (indices of runs of ``_RUN`` consecutive rays, see below)
    and of the rays past the last whole run that point into one of a frame's sphere ``cones``
    (see :func:`_cones`, not None: the event is outside the spheres; or a superset of those rays),
    from one event; or None when every ray may (the bundle's own cone lies inside one).

    ``bundle`` = (axis, half-angle, sub-bundles) of a cone holding every ray and of cones holding
    the runs (:func:`_sub_bundle_cones`): sphere cones that miss the bundle's are skipped and,
    where one holds it whole, no ray needs testing; then each run that lies in a sphere cone is
    taken whole and one that misses them all is dropped whole, before the rays of the other runs
    are tested one by one.
    """
    axes, spread = cones
    bundle_axis, bundle_angle, (run_axes, run_cos, run_sin) = bundle
    meeting = _cones_meeting(cones, bundle_axis, bundle_angle)
    if meeting is None:
        return None
    axes, spread = axes[meeting], spread[meeting]
    inside = np.zeros(len(d), dtype=bool)
    tested = np.arange(_RUN * len(run_axes), len(d))  # the rays past the last whole run: one by one
    if len(runs):
        run_axes, run_cos, run_sin = run_axes[runs], run_cos[runs], run_sin[runs]
        # the cone of cones: each run against each sphere cone by the cosine of sums of angles
        # (m, b); a run is taken whole where it lies in a cone, dropped where it misses them all
        apart = axes @ run_axes.T
        cos_spread, sin_spread = np.cos(spread)[:, None], np.sin(spread)[:, None]
        whole = ((apart >= cos_spread * run_cos + sin_spread * run_sin) & (run_cos >= cos_spread)).any(axis=0)
        clear = spread + _RUN_MARGIN
        missable = (clear < np.pi / 2)[:, None] & (run_cos > 0.0)  # the sum of the angles below pi
        meets = ~missable | (apart >= np.cos(clear)[:, None] * run_cos - np.sin(clear)[:, None] * run_sin - 1e-12)
        partial = runs[~whole & meets.any(axis=0)]
        inside[:_RUN * (len(d) // _RUN)].reshape(-1, _RUN)[runs[whole]] = True
        tested = np.append(_members(partial), tested)
    if len(tested):
        # those rays against every cone at once: one (m, 3) x (3, r) product, reduced over the cones
        inside[tested] = (axes @ rows.take(d, tested).T >= np.cos(spread)[:, None]).any(axis=0)
    return np.flatnonzero(inside)


def _cones_meeting(cones, bundle_axis, bundle_angle: float):
    """Indices of the sphere ``cones`` (axes, half-angles) that a bundle's cone meets, or None
    when one of them holds it whole."""
    axes, spread = cones
    apart = np.arccos(np.clip(axes @ bundle_axis, -1.0, 1.0))
    if np.any(apart + bundle_angle <= spread):
        return None
    return np.flatnonzero(apart <= spread + bundle_angle)


_GATHER_SHARE = 0.5  # the share of a bundle's rays above which the culled ones are traced too (see _gathered)
# the same for a moving frame: the primary-ray floor's tiles that keep 65-67% of their rays, gathered,
# took 2-5 ms less a render (one thread, 181.3 against 183.7 ms, min of 25); those that keep 99% more
_BOOSTED_GATHER_SHARE = 0.7
_RUN = RunBounds.RUN  # rays per sub-bundle (consecutive rays: a run of pixels in a row of the tile)
_RUN_MARGIN = 1e-6  # radians: a run is dropped whole only this far clear of every cone (rounding)


def _sub_bundle_cones(run_bounds):
    """(axes (b, 3), cosines and sines of the half-angles (b,)) of cones holding each run of
    ``_RUN`` consecutive directions whose lowest and highest components are ``run_bounds``
    ((3, b), :func:`_run_bounds`).

    A run's cone is drawn about its box's centre: a unit direction d in the box [lo, hi] is at
    most ``g`` (the box corner farthest from the unit axis a, per component) away from a, so
    ``d . a = 1 - |d - a|^2 / 2 >= 1 - |g|^2 / 2``, less a margin for rounding.  No pass over the
    rays beyond the box's.
    """
    low, high = run_bounds  # (3, b): one row per axis, all runs at once
    centre = (low + high) * 0.5
    length = np.sqrt(centre[0] * centre[0] + centre[1] * centre[1] + centre[2] * centre[2])
    spread_out = length < 1e-9  # a box about the origin: no axis, the cone holds every direction
    axes = centre / np.where(spread_out, 1.0, length)
    gap = np.maximum(np.abs(low - axes), np.abs(high - axes))
    run_cos = 1.0 - 0.5 * (gap[0] * gap[0] + gap[1] * gap[1] + gap[2] * gap[2]) - _RUN_COS_MARGIN
    run_cos = np.where(spread_out, -1.0, np.clip(run_cos, -1.0, 1.0))
    return np.ascontiguousarray(axes.T), run_cos, np.sqrt(1.0 - run_cos * run_cos)


_RUN_COS_MARGIN = 1e-12  # rounding of unit directions (|d|^2 = 1 to a few ulp) and of the bound itself


def _run_bounds(d):
    """Lowest and highest direction components (3, b) of each run of ``_RUN`` consecutive
    directions d (the rays past the last whole run left out): the runs' 3 _RUN numbers as columns
    of one transposed copy, folded in halves along its rows (long contiguous rows; numpy reduces
    a short axis one row at a time, several times slower)."""
    count = len(d) // _RUN
    low = high = np.ascontiguousarray(np.reshape(d[:count * _RUN], (count, 3 * _RUN)).T)
    width = 3 * _RUN
    while width > 3:
        width //= 2
        low, high = np.minimum(low[:width], low[width:]), np.maximum(high[:width], high[width:])
    return low, high


def _per_run(ufunc, values):
    """``ufunc`` (minimum, maximum) over each run of ``_RUN`` consecutive values (along the first
    axis), by folding neighbours pairwise: numpy reduces the short last axis of a (b, _RUN)
    array one row at a time, several times slower."""
    width = 1
    while width < _RUN:
        values = ufunc(values[0::2], values[1::2])
        width *= 2
    return values


def _runs_near_bodies(frames: FrameSet, src: int, ks, cache, extent, shared, run_bounds, path_range) -> list:
    """For each frame k of ``ks``: the indices (increasing) of the runs of ``_RUN`` rays from one
    ``shared`` event that may pass through k's body box (or a superset of them):
    :func:`_near_body` (``extent`` as there) for a whole run at once.  ``run_bounds`` = the runs'
    lowest and highest direction components (3, b) (:func:`_run_bounds`); ``path_range`` =
    (lowest s_lo, highest s_hi) of the rays.

    Along each axis a ray passes the box's slab for path lengths between (+-half - offset) / e,
    e = d + v; those are monotonic in e, so for every e between a run's lowest and highest
    components they lie between their values at the two ends (floating-point rounding is
    monotonic too), unless e may be 0 there.  The run's range is the widest of its rays'.  By
    the same argument a block of ``_RUN`` runs, bounded by its runs' bounds, misses the box
    only if each of its runs does: the blocks are tested first, every frame at once, then the
    runs of the blocks that pass (all pairs of frame and run at once: the calls are what costs).
    """
    low, high = run_bounds
    count = low.shape[1]
    t_box, x_box, velocity, widen = _body_boxes(frames, src, ks, cache, extent)
    offset = shared[1] - ((shared[0] - t_box)[:, None] * velocity + x_box)  # as _near_body works it out per ray
    before, after = -widen - offset, widen - offset  # (frames, 3)
    # the blocks' bounds: the runs' folded (the last block filled up with copies of the last run)
    pad = -count % _RUN
    block_low, block_high = (_per_run(ufunc, np.concatenate([bound, np.repeat(bound[:, -1:], pad, axis=1)], axis=1).T).T
                             for ufunc, bound in ((np.minimum, low), (np.maximum, high)))
    frame, block = np.nonzero(_slabs_pass(before[:, :, None], after[:, :, None], velocity[:, :, None], block_low,
                                          block_high, path_range))
    pair_frame = np.repeat(frame, _RUN)
    pair_run = _members(block)  # the runs of those blocks
    if pad:
        real = pair_run < count
        pair_frame, pair_run = pair_frame[real], pair_run[real]
    near = _slabs_pass(*(np.take(a.T, pair_frame, axis=1) for a in (before, after, velocity)),
                       np.take(low, pair_run, axis=1), np.take(high, pair_run, axis=1), path_range)
    pair_frame, pair_run = pair_frame[near], pair_run[near]
    return np.split(pair_run, np.cumsum(np.bincount(pair_frame, minlength=len(ks)))[:-1])


def _slabs_pass(before, after, velocity, low, high, path_range) -> np.ndarray:
    """Whether runs of rays whose direction components lie between ``low`` and ``high`` (3, b)
    may pass through boxes moving with ``velocity`` whose slabs lie between ``before`` and
    ``after`` relative to the rays' event (broadcast against them; the axes second to last),
    within ``path_range``: see :func:`_runs_near_bodies`."""
    e_low, e_high = low + velocity, high + velocity
    with np.errstate(divide="ignore", invalid="ignore"):
        ends = before / e_low, after / e_low, before / e_high, after / e_high
    near = np.minimum(np.minimum(ends[0], ends[1]), np.minimum(ends[2], ends[3]))
    far = np.maximum(np.maximum(ends[0], ends[1]), np.maximum(ends[2], ends[3]))
    either_way = (e_low <= 0.0) & (e_high >= 0.0)  # e may be 0 there: any path length
    near[either_way], far[either_way] = -np.inf, np.inf
    return np.maximum(near.max(axis=-2), path_range[0]) <= np.minimum(far.min(axis=-2), path_range[1])


def _bundle_cone(d):
    """(axis, half-angle) of a cone holding every direction d."""
    axis = np.array([d[:, 0].sum(), d[:, 1].sum(), d[:, 2].sum()])  # (d.sum(axis=0) is 15x slower)
    length = float(np.linalg.norm(axis))
    if length < 1e-9 * len(d):
        return np.array([1.0, 0.0, 0.0]), np.pi
    axis /= length
    return axis, float(np.arccos(np.clip((d @ axis).min(), -1.0, 1.0)))


def misses_everything(frames: FrameSet, src: int, origin_event, cones, cache: TraceCache | None = None) -> list[bool]:
    """Per cone (axis, half-angle) of ``cones`` (None: not known to be under a right angle):
    whether every backward ray from one event (tau, x) of frame src whose direction lies in it
    misses every surface: the cone meets none of the frames' sphere cones, so the tracer's own
    cull would drop each such ray (in a scene without animated segments, whose candidate frames
    depend on the rays' events).  Every cone against each frame's spheres at once."""
    known = [i for i, cone in enumerate(cones) if cone is not None]
    missing = [False] * len(cones)
    if frames.groups or not known:
        return missing
    axes = np.array([cones[i][0] for i in known])
    angles = np.array([cones[i][1] for i in known])
    clear = np.ones(len(known), dtype=bool)
    for spheres in _frame_cones(frames, src, list(frames.geometry), origin_event, cache):
        if spheres is None:
            return missing
        sphere_axes, spread = spheres
        apart = np.arccos(np.clip(sphere_axes @ axes.T, -1.0, 1.0))  # (spheres, cones)
        clear &= (apart > spread[:, None] + angles).all(axis=0)  # as _cones_meeting finds none
    for i, gone in zip(known, clear.tolist()):
        missing[i] = gone
    return missing


def _frame_cones(frames: FrameSet, src: int, ks, origin_event, cache: TraceCache | None) -> list:
    """The cones of the frames ``ks`` seen from one event (:func:`_cones`), from the thread's
    cache where it has them: they depend on the event alone, so every tile of a perspective
    camera shares them."""
    if cache is None:
        return _cones(frames, src, ks, origin_event)
    event = (origin_event[0], *origin_event[1].tolist())
    return cache.cones([(src, k, *event) for k in ks],
                       lambda missing: _cones(frames, src, [ks[i] for i in missing], origin_event))


def _lone_sphere(geometry, offset) -> list[float]:
    """(centre, radius) in frame coordinates of a sphere holding a geometry without culling
    clusters: the smaller of the one about its local origin (a body's pivot) and the one
    around its bounds."""
    half = 0.5 * (geometry.hi - geometry.lo)
    around_bounds = float(np.linalg.norm(half))
    if geometry.radius <= around_bounds:
        return [*offset, geometry.radius]
    return [*(offset + geometry.lo + half), around_bounds]


def _cones(frames: FrameSet, src: int, ks, origin_event) -> list:
    """Per frame k of ``ks``: (axes (m, 3), half-angles (m,)) in frame src of the cones that
    frame k's bounding spheres subtend at one event, or None when the event is inside one.

    Each cone is built in frame k and mapped to frame src by aberration, which maps circles
    on the sky to circles: its image is found from ``_CONE_SAMPLES`` rim directions around
    the mapped axis, widened by a margin for the sampling.  All frames' spheres at once, but
    for the two maps of each frame.
    """
    spheres, eyes, pads = [], [], []
    for k in ks:
        frame = frames.frames[k]
        geometry = frame.geometry
        _, x_k = frames.map(src, k).events(np.array(origin_event[0]), origin_event[1])
        if frame.spin is not None:  # any pose: the sphere about the pivot
            frame_spheres = np.array([[*frame.offset, geometry.radius]])
        elif geometry.clusters is None:  # a lone frame (no clusters built): one sphere holding it
            frame_spheres = np.array([_lone_sphere(geometry, frame.offset)])
        else:
            frame_spheres = geometry.clusters + np.append(frame.offset, 0.0)
        spheres.append(frame_spheres)
        eyes.append(x_k)
        pads.append(2 * _PAD * geometry.extent + 1e-9 * (1.0 + float(np.max(np.abs(frame_spheres[:, :3])))))
    counts = np.array([len(frame_spheres) for frame_spheres in spheres])
    starts = np.concatenate([[0], np.cumsum(counts)])
    spheres = np.concatenate(spheres)
    offset = spheres[:, :3] - np.repeat(np.array(eyes), counts, axis=0)
    distance = np.linalg.norm(offset, axis=1)
    radius = spheres[:, 3] + np.repeat(pads, counts)
    inside = np.add.reduceat(distance <= radius * 1.01, starts[:-1]) > 0
    with np.errstate(divide="ignore", invalid="ignore"):  # (at a sphere's centre: the frame has no cones)
        axes = offset / distance[:, None]
        half = np.arcsin(np.minimum(radius / distance, 1.0))
        t1 = np.cross(axes, np.where(np.abs(axes[:, :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]))
        t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(axes, t1)
    phi = np.linspace(0.0, 2 * np.pi, _CONE_SAMPLES, endpoint=False)
    rim = (np.cos(half)[:, None, None] * axes[:, None, :]
           + np.sin(half)[:, None, None] * (np.cos(phi)[None, :, None] * t1[:, None, :]
                                            + np.sin(phi)[None, :, None] * t2[:, None, :]))
    directions = np.concatenate([axes[:, None, :], rim], axis=1)
    src_dirs = np.zeros_like(directions)
    for i, k in enumerate(ks):
        if not inside[i]:
            frame_dirs = directions[starts[i]:starts[i + 1]].reshape(-1, 3)
            src_dirs[starts[i]:starts[i + 1]] = frames.map(k, src).rays(frame_dirs)[0].reshape(-1, _CONE_SAMPLES + 1, 3)
    centre_dirs = src_dirs[:, 0]
    spread = np.max(np.arccos(np.clip(np.einsum("kij,kj->ki", src_dirs[:, 1:], centre_dirs), -1.0, 1.0)), axis=1)
    spread = np.minimum(spread * 1.05 + 1e-9, np.pi)
    return [None if inside[i] else (centre_dirs[starts[i]:starts[i + 1]], spread[starts[i]:starts[i + 1]])
            for i in range(len(ks))]


def occluded(frames: FrameSet, src: int, tau0, x0, d, s_lo, s_hi, cache: TraceCache | None = None,
             see_through=None) -> np.ndarray:
    """True where anything in any frame lies on the backward ray with s_lo <= s <= s_hi
    (``cache``: the calling thread's, None: keep nothing).  Surfaces hidden from shadow rays,
    and hits ``see_through`` lets pass (as for :func:`trace_nearest`), do not block."""
    if see_through is not None or frames.hidden_rays & RAY_SHADOW:
        return trace_nearest(frames, src, tau0, x0, d, s_lo, s_hi, cache, RAY_SHADOW, see_through).frame >= 0
    n = len(d)
    s_lo, s_hi = _per_ray(s_lo, n), _per_ray(s_hi, n)
    blocked = np.zeros(n, dtype=bool)
    reach = _bundle_reach(tau0, x0, d, s_lo, s_hi)
    candidates = frames.candidates(src, tau0, x0)
    if reach is not None:
        candidates = [k for k, meets in zip(candidates, _may_meet(frames, src, candidates, reach, cache)) if meets]
    todo = None  # the rays not yet blocked: None while that is every ray (no gathers)
    extent = None  # (largest |x0| coordinate, largest |tau0|) of the bundle, for the rounding margin of _near_body
    for k in candidates:
        if todo is not None and len(todo) == 0:
            break
        fmap = frames.map(src, k)
        frame = frames.frames[k]
        rays = todo  # the rays to trace in frame k (None: all)
        if not fmap.is_identity:
            # before mapping them into the frame: only rays that pass the body's box can meet it
            if extent is None:
                extent = (_largest_magnitude(x0), _largest_magnitude(tau0))
            near = _near_body(frames, src, k, cache, extent, *_rows_of(rays, tau0, x0, d, s_lo, s_hi))
            if not near.all():
                rays = np.flatnonzero(near) if rays is None else rays[near]
                if len(rays) == 0:
                    continue
        tau_k, origin, d_rays, lo, hi = _rows_of(rays, tau0, x0, d, s_lo, s_hi)
        tau_k, origin = fmap.events(tau_k, origin)
        if reach is not None and reach.direction is not None:  # parallel rays (sunlight): map one
            dk, w = (_direction_in(frames, src, k, reach.direction) if cache is None
                     else cache.direction_in(frames, src, k, reach.direction))
            dk = rows.broadcast(dk[None], len(lo))
        elif fmap.is_identity:
            dk, w = d_rays, None
        else:
            dk, w = fmap.rays(d_rays)
        if w is not None:  # (w = 1 leaves the path lengths as they are)
            lo, hi = lo * w, hi * w
        lo, hi = _ray_range(frame, tau_k, origin, dk, lo, hi)
        if fmap.is_identity and _leave_flat_body(frame, cache, origin, dk, lo):  # (a floor under its own shadow rays)
            continue
        hit = _query(frame, tau_k, origin, dk, lo, hi, occlusion=True)
        if not hit.any():
            continue
        if rays is None:
            blocked = hit
        else:
            blocked[rays[hit]] = True
        todo = np.flatnonzero(~blocked) if todo is None else todo[~blocked[todo]]
    return blocked


def _largest_magnitude(values) -> float:
    """The largest |value| of an array: two fast reductions over all of it, no array of magnitudes."""
    return max(float(values.max()), -float(values.min()))


def _rows_of(rays, tau0, x0, d, s_lo, s_hi):
    """(tau0, x0, d, s_lo, s_hi) of the rays with indices ``rays`` (None: all, as they are)."""
    if rays is None:
        return tau0, x0, d, s_lo, s_hi
    return tau0[rays], rows.take(x0, rays), rows.take(d, rays), s_lo[rays], s_hi[rays]


def _near_body(frames: FrameSet, src: int, k: int, cache, extent, tau0, x0, d, s_lo, s_hi) -> np.ndarray:
    """Which backward rays (source frame, ``s_lo <= s <= s_hi``) pass through the box that holds
    frame k's body (``FrameSet.body_boxes``, widened as for :func:`_may_meet`): a mask.
    ``extent`` = (largest |coordinate| of the rays' x0, largest |tau0|), or of a bundle they are from.

    Relative to the box's centre, moving with velocity v, the ray's event at path length s is
    at ``x0 - X(tau0) + s (d + v)``: a slab test per ray (:func:`_slabs_hold`), after one per block
    of rays (:func:`_blocks_near`).  Rays it rejects cannot meet the frame's bounds either (their
    query would find nothing), so no ray's result changes.
    """
    n = len(d)
    if n == 0:
        return np.zeros(0, dtype=bool)
    t_box, x_box, velocity, widen = _body_box(frames, src, k, cache, extent)
    since = {}  # first -> tau0 - t_box of the rays from first on, worked out once for the moving axes

    def relative(axis: int, first: int = 0):
        """x0 - X(tau0) and e = d + v along ``axis`` of the rays from ``first`` on (contiguous)."""
        v = float(velocity[axis])
        offset, e = np.empty(n - first), np.empty(n - first)
        if v == 0.0:  # (X(tau0) is x_box: (tau0 - t) 0 + x_box; d + 0 turns -0 into +0, which decides
            # only rays that stay at a constant coordinate outside the slab: they miss the box either way)
            np.subtract(x0[first:, axis], x_box[axis], out=offset)
            np.copyto(e, d[first:, axis])  # (contiguous: numpy divides by it 2.5x faster than by a strided column)
        else:
            if first not in since:
                since[first] = tau0[first:] - t_box
            np.multiply(since[first], v, out=offset)  # the box centre's displacement at the ray's start
            offset += x_box[axis]
            np.subtract(x0[first:, axis], offset, out=offset)
            np.add(d[first:, axis], v, out=e)
        return offset, e

    columns = []  # relative(axis) of every ray, axis by axis as the block test asks for them
    rays = _blocks_near(lambda axis: columns.append(relative(axis)) or columns[axis], widen, s_lo, s_hi)
    if rays is None:
        columns += [relative(axis) for axis in range(len(columns), 3)]
        return _slabs_hold([o for o, _ in columns], [e for _, e in columns], widen, s_lo, s_hi)
    near = np.zeros(n, dtype=bool)
    if len(rays):
        # the axes the block test did not ask for (every block dropped before): only the rays past the
        # last whole block are left, worked out for them alone
        first = n - len(rays)
        columns = [(o[rays], e[rays]) for o, e in columns] + [relative(axis, first) for axis in range(len(columns), 3)]
        near[rays] = _slabs_hold([o for o, _ in columns], [e for _, e in columns], widen,
                                 s_lo[:len(rays)] if _one_row(s_lo) else s_lo[rays],
                                 s_hi[:len(rays)] if _one_row(s_hi) else s_hi[rays])
    return near


def _slabs_hold(offsets, speeds, widen, s_lo, s_hi) -> np.ndarray:
    """Whether each ray ``offset + s e`` (per axis), ``s_lo <= s <= s_hi``, passes through the box
    [-widen, widen] (:func:`_near_body`): a mask."""
    n = len(s_lo)
    enter, leave, t_a, t_b, near = (np.empty(n) for _ in range(5))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for axis, (offset, e) in enumerate(zip(offsets, speeds)):
            np.divide(np.subtract(-widen[axis], offset, out=t_a), e, out=t_a)
            np.divide(np.subtract(widen[axis], offset, out=t_b), e, out=t_b)
            # fmin/fmax ignore the NaN of 0 / 0 (a ray along a slab face)
            np.fmax(s_lo if axis == 0 else enter, np.fmin(t_a, t_b, out=near), out=enter)
            np.fmin(s_hi if axis == 0 else leave, np.fmax(t_a, t_b, out=near), out=leave)
    return enter <= leave


_NEAR_BLOCK = 2048  # consecutive shadow rays (hits of a run of pixels) tested as one by _blocks_near
_NEAR_SHARE = 0.5  # the share of kept rays above which _near_body tests every ray (no gathers)


def _blocks_near(column, widen, s_lo, s_hi):
    """Indices (increasing) of the rays of :func:`_near_body` whose block of ``_NEAR_BLOCK``
    consecutive rays may pass through the box, and of the rays past the last whole block; None
    for every ray (most are kept).

    A block's slab test takes the least and greatest offset and e of its rays per axis: the
    rays' slab path lengths ``(+-widen - offset) / e`` are each monotonic in offset and, for one
    sign of e, in e, and so is their rounding, so every ray's lie between the values at the
    block's corners (unless e may be 0 there: any path length); the block's path range is the
    bundle's.  A block it drops holds no ray :func:`_slabs_hold` keeps (a NaN keeps its block).
    ``column(axis)`` = (offset, e) of every ray along that axis, asked for axis by axis: once every
    block is dropped, the other axes are not (a tile's shadow rays far from the body).
    """
    n = len(s_lo)
    count = n // _NEAR_BLOCK
    if count < 2:
        return None
    whole = count * _NEAR_BLOCK
    enter = np.full(count, float(s_lo[0] if _one_row(s_lo) else s_lo.min()))
    leave = np.full(count, float(s_hi[0] if _one_row(s_hi) else s_hi.max()))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for axis in range(3):
            offset, e = column(axis)
            blocks_offset, blocks_e = offset[:whole].reshape(count, -1), e[:whole].reshape(count, -1)
            o_lo, o_hi, e_lo, e_hi = blocks_offset.min(1), blocks_offset.max(1), blocks_e.min(1), blocks_e.max(1)
            ends = [np.subtract(bound, o, out=np.empty(count)) for bound in (-widen[axis], widen[axis])
                    for o in (o_lo, o_hi)]
            ends = [np.divide(end, speed) for end in ends for speed in (e_lo, e_hi)]
            near, far = ends[0], ends[0].copy()
            for end in ends[1:]:
                np.minimum(near, end, out=near)
                np.maximum(far, end, out=far)
            either_way = (e_lo <= 0.0) & (e_hi >= 0.0)  # e may be 0 there: any path length
            near[either_way], far[either_way] = -np.inf, np.inf
            np.maximum(enter, near, out=enter)
            np.minimum(leave, far, out=leave)
            if (enter > leave).all():
                break
    kept = np.flatnonzero(~(enter > leave))  # (NaN: kept)
    if len(kept) * _NEAR_BLOCK > _NEAR_SHARE * n:
        return None
    rays = (kept[:, None] * _NEAR_BLOCK + np.arange(_NEAR_BLOCK)).ravel()
    return np.append(rays, np.arange(whole, n)) if whole < n else rays


def _body_box(frames: FrameSet, src: int, k: int, cache, extent):
    """(t, x, velocity, widened half-extents) of frame k's body box (:func:`_body_boxes`)."""
    boxes, slot = _boxes(frames, src, frames.geometry, cache), frames.geometry_slot[k]
    return boxes.t[slot], boxes.x[slot], boxes.velocity[slot], boxes.widened(extent)[slot]


def _body_boxes(frames: FrameSet, src: int, ks, cache, extent):
    """(t, x, velocity, widened half-extents) of the body boxes (``FrameSet.body_boxes``) of the
    frames ``ks``, (len(ks),) and (len(ks), 3), for rays whose (largest |coordinate| of x0,
    largest |tau0|) is ``extent``."""
    boxes = _boxes(frames, src, ks, cache)
    return boxes.t, boxes.x, boxes.velocity, boxes.widened(extent)


def _boxes(frames: FrameSet, src: int, ks, cache: TraceCache | None) -> "_Boxes":
    """The :class:`_Boxes` of the frames ``ks`` seen from frame src, the thread's kept ones where it has them."""
    if cache is not None:
        return cache.boxes(frames, src, ks)
    return _boxes_among(frames, ks, frames.body_boxes(src))


def _boxes_among(frames: FrameSet, ks, every) -> "_Boxes":
    """The :class:`_Boxes` of the frames ``ks`` from ``every`` = (t, x, velocity, half) of every
    geometry frame's body box (``FrameSet.body_boxes``, or a kept :class:`_Boxes`' own arrays)."""
    slots = np.array([frames.geometry_slot[k] for k in ks], dtype=np.int64)
    return _boxes_of_sources(*(a[None, slots] for a in every))[0]


_BOX_FIELDS = ("t", "x", "velocity", "half", "margin", "abs_t", "x_reach", "v_reach", "axes_t", "axes_x",
               "axes_velocity", "axes_margin", "axes_half_speed")


class _Boxes:
    """Body boxes (``FrameSet.body_boxes``) of some frames seen from one source frame, (m,) and (m, 3)
    arrays, with what the tests of every bundle derive from them alone (the arrays read-only: a
    thread keeps them, :meth:`TraceCache.boxes`; only :meth:`along`'s memo of directions still
    grows, in that thread): the half-extents widened for float32 geometry (``margin``), the
    largest |coordinate| of each centre and velocity, and the boxes a row per axis (``axes_*``,
    (3, m): a bundle's slab test, :func:`_may_meet`, then takes the extremes of three rows, not of
    m short ones).  Made by :func:`_boxes_of_sources`."""

    __slots__ = _BOX_FIELDS + ("_parallel", "cones_pay")

    def __init__(self, fields: dict):
        for name, value in fields.items():
            setattr(self, name, value)
        self._parallel: dict[bytes, tuple] = {}
        self.cones_pay: list[bool] | None = None  # :func:`_cones_pay` of these frames, once worked out (read only)

    def widened(self, extent) -> np.ndarray:
        """Half-extents (m, 3) widened for rounding, for rays whose (largest |coordinate| of x0,
        largest |tau0|) is ``extent``."""
        # the rays meet the box where |s (d + v)| is about |x0 - X(tau0)|: coordinates up to this
        x_max, tau_max = extent
        scale = 1.0 + x_max + self.x_reach + self.v_reach * (tau_max + self.abs_t)
        return self.margin + 1e-9 * scale[:, None]

    def along(self, direction) -> tuple:
        """(w, w == 0, whether any w is 0) for unbounded rays along ``direction`` (3,): each body's
        centre sees them run along -w = -(direction + v); kept per direction (a sharp sun's)."""
        key = direction.tobytes()
        kept = self._parallel.get(key)
        if kept is None:
            if len(self._parallel) >= _MAX_DIRECTIONS:
                self._parallel.clear()
            w = -(direction[:, None] + self.axes_velocity)
            parallel = w == 0.0
            w.flags.writeable = parallel.flags.writeable = False
            kept = self._parallel[key] = (w, parallel, bool(parallel.any()))
        return kept


_MAX_DIRECTIONS = 64  # parallel bundles' directions kept per source frame (a sharp sun's: one per sun)


def _boxes_of_sources(t, x, velocity, half) -> list[_Boxes]:
    """The :class:`_Boxes` of each source frame from the body boxes seen from each, (sources, m) and
    (sources, m, 3) (``FrameSet.body_boxes_of``): what they derive worked out for all at once."""
    derived = {"t": t, "x": x, "velocity": velocity, "half": half, "margin": _float32_margin(half),
               "abs_t": np.abs(t), "x_reach": np.max(np.abs(x), axis=-1), "v_reach": np.max(np.abs(velocity), axis=-1),
               "axes_t": t[:, None, :]}
    for name in ("x", "velocity", "margin"):
        derived["axes_" + name] = np.ascontiguousarray(np.swapaxes(derived[name], 1, 2))
    derived["axes_half_speed"] = np.abs(derived["axes_velocity"]) * 0.5
    for a in derived.values():
        a.flags.writeable = False
    return [_Boxes({name: a[i] for name, a in derived.items()}) for i in range(len(t))]


def _float32_margin(half) -> np.ndarray:
    """Half-extents (..., m, 3) of body boxes widened for float32 geometry (:meth:`_Boxes.widened`
    adds the float64 arithmetic's share)."""
    return half * (1.0 + 2 * _PAD) + 2 * _PAD * half.max(axis=-1, keepdims=True)


@dataclass
class Reach:
    """Where the rays of a shadow-ray bundle can be (source frame): every ray starts (at s_lo)
    inside the box [lo, hi] at a time in [earliest, latest] and, for finite rays, ends in it
    too; unbounded rays (sunlight) all run along one ``direction``."""

    lo: np.ndarray
    hi: np.ndarray
    earliest: float
    latest: float
    direction: np.ndarray | None = None


def _bundle_reach(tau0, x0, d, s_lo, s_hi) -> Reach | None:
    """The bundle's :class:`Reach`; None for unbounded rays in different directions."""
    if len(d) == 0:
        return None
    bounded = math.isfinite(s_hi[0]) if _one_row(s_hi) else bool(np.all(np.isfinite(s_hi)))
    if not bounded and not (_one_row(d) or (np.array_equal(d[-1], d[0]) and np.all(d == d[0]))):  # (the ends first)
        return None
    if not bounded and _one_row(s_lo):
        # parallel rays from one path length: each axis' start is x0 + one number, and rounding is
        # monotonic, so its least (greatest) is that of the least (greatest) x0: the same bits
        s_start, step = float(s_lo[0]), float(s_lo[0]) * d[0]
        lo = np.array([float(x0[:, axis].min()) for axis in range(3)]) + step
        hi = np.array([float(x0[:, axis].max()) for axis in range(3)]) + step
        return Reach(lo, hi, float(tau0.min()) - s_start, float(tau0.max()) - s_start, np.array(d[0]))
    lo, hi = np.empty(3), np.empty(3)
    ends = np.empty(len(d))
    for axis in range(3):  # one axis at a time: numpy is slow along a length-3 last axis
        np.multiply(s_lo, d[:, axis], out=ends)
        ends += x0[:, axis]
        lo[axis], hi[axis] = ends.min(), ends.max()
        if bounded:
            np.multiply(s_hi, d[:, axis], out=ends)
            ends += x0[:, axis]
            lo[axis], hi[axis] = min(lo[axis], ends.min()), max(hi[axis], ends.max())
    start = tau0 - s_lo
    return Reach(lo, hi, float(np.min(tau0 - s_hi)) if bounded else float(np.min(start)), float(np.max(start)),
                 None if bounded else np.array(d[0]))


def _one_row(values) -> bool:
    """Whether ``values`` is one row broadcast to every ray (``_per_ray`` of one number, a shared direction)."""
    return values.strides[0] == 0


def _may_meet(frames: FrameSet, src: int, ks, reach: Reach, cache: TraceCache | None) -> np.ndarray:
    """Which of the frames ``ks`` have a body that can come within reach of the bundle (a mask)?

    Every body lies in a box moving uniformly in the source frame (``FrameSet.body_boxes``).
    Finite rays lie in the bundle's box: over the bundle's time span a body box's centre runs
    along a segment, which must meet the bundle's box widened by the body's half-extents.
    Unbounded parallel rays: relative to a body a ray starting at p at time t runs from
    p - X(t) along w = d + v, so it can meet the body only if the ray from the body's centre
    along -w meets the box of relative starts widened by the body's half-extents.
    All frames at once: a slab test per frame, vectorised (a row per axis, :class:`_Boxes`).
    """
    boxes = _boxes(frames, src, ks, cache)
    lo, hi = reach.lo[:, None], reach.hi[:, None]
    scale = 1.0 + max(map(abs, reach.hi.tolist())) + max(map(abs, reach.lo.tolist()))
    widen = boxes.axes_margin + 1e-9 * scale
    if reach.direction is None:
        start = boxes.axes_x + boxes.axes_velocity * (reach.earliest - boxes.axes_t)
        direction = boxes.axes_velocity * (reach.latest - reach.earliest)
        return _segments_meet_boxes(start, direction, 1.0, lo - widen, hi + widen, direction == 0.0)
    middle = 0.5 * (reach.earliest + reach.latest)
    centre = boxes.axes_x + boxes.axes_velocity * (middle - boxes.axes_t)
    drift = boxes.axes_half_speed * (reach.latest - reach.earliest)  # how far each body moves about X(middle)
    w, parallel, any_parallel = boxes.along(reach.direction)
    return _segments_meet_boxes(None, w, np.inf, lo - centre - drift - widen, hi - centre + drift + widen,
                                parallel if any_parallel else None)


def _segments_meet_boxes(origin, direction, t_max: float, lo, hi, parallel) -> np.ndarray:
    """Whether each origin + t direction, 0 <= t <= t_max, meets its box [lo, hi]: (3, m) arrays, a
    row per axis, m boxes (few: the calls are what costs); ``origin`` None: 0.  ``parallel``:
    ``direction == 0`` (inside the slab for every t, or never), None where no component is 0."""
    if origin is not None:
        lo, hi = lo - origin, hi - origin
    if parallel is None:
        t_a, t_b = lo / direction, hi / direction
    else:
        with np.errstate(divide="ignore", invalid="ignore"):
            t_a = np.where(parallel, -np.inf, lo / direction)
            t_b = np.where(parallel, np.inf, hi / direction)
    near, far = np.minimum(t_a, t_b), np.maximum(t_a, t_b)
    enter = np.maximum(np.maximum(np.maximum(near[0], near[1]), near[2]), 0.0)
    leave = np.minimum(np.minimum(np.minimum(far[0], far[1]), far[2]), t_max)
    if parallel is not None:
        leave[(parallel & ((lo > 0.0) | (hi < 0.0))).any(axis=0)] = -np.inf
    return enter <= leave


# a render thread keeps hit_geometry's rows of every triangle of meshes up to this size (96 bytes a
# triangle, made at the first hit): three gathers of 32-byte rows per hit instead of four of 24 bytes
# (numpy copies a 32-byte row 2.5x faster), no edges or normals per hit
_HIT_TABLE_TRIANGLES = 1 << 16


def _one_or_table(values):
    """A contiguous table of ``values``, or its one number (a float) where every entry has the
    same bits: adding or multiplying by it rounds as by the gathered copies, without the gather."""
    bits = values.view(np.int64)
    if len(values) and (bits == bits[0]).all():
        return float(values[0])
    return np.ascontiguousarray(values)


def _triangle_rows(geometry, prim):
    """The first corner, the two edges out of it and the unit normal (Geometry.face_normals, from
    the edges at hand) of triangles ``prim``: four new (n, 3) arrays."""
    corners = rows.take(geometry.triangles, prim)
    p0, p1, p2 = (rows.take(geometry.vertices, corners[:, i]) for i in range(3))
    p1 -= p0
    p2 -= p0
    return p0, p1, p2, triangle_normals(p1, p2)


def hit_geometry(frame: RestFrame, prim, u, v, tau=None, cache: TraceCache | None = None):
    """Float64 position, unit geometric normal and unit shading normal at hits of one frame
    (frame coordinates; ``tau``, the hits' frame times, poses a spinning body): new arrays, the
    caller's to write into (the two normals are one array where the mesh has no corner normals),
    but for a flat mesh's normal (with ``cache``, not spinning): one read-only broadcast row.
    ``cache``: the calling thread's, which keeps the rows of small meshes' triangles."""
    geometry = frame.geometry
    # p0 + u e1 + v e2 one axis at a time in a contiguous column, its last sum written into its
    # column of the positions; float32 u, v widened once (exactly).  A body that does not spin is moved to
    # frame coordinates (RestFrame.to_frame: + offset) in the same column.
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    n, spins = len(prim), frame.spin is not None
    position, column, term = np.empty((n, 3)), np.empty(n), np.empty(n)
    if cache is not None and len(geometry.triangles) <= _HIT_TABLE_TRIANGLES:  # 1-D gathers per axis
        tables, normals, one, corner_tables = cache.hit_table(geometry)
        index = np.asarray(prim, dtype=np.intp)  # (converted once, not by each gather)
        # a flat mesh's one normal (not spun) for all its hits: a read-only broadcast row
        ng = rows.broadcast(one, n) if one is not None and not spins else np.take(normals, index, axis=0, mode="clip")
        gathered = np.empty((3, n))
        gather = lambda tables: (None if axis_tables is None else  # (in range: clip only skips the check)
                                 [table if isinstance(table, float) else np.take(table, index, out=out, mode="clip")
                                  for table, out in zip(axis_tables, gathered)]
                                 for axis_tables in tables)
        axes = gather(tables)
        corners = None if corner_tables is None else gather(corner_tables)
    else:
        p0, p1, p2, ng = _triangle_rows(geometry, prim)
        axes = [(p0[:, axis], p1[:, axis], p2[:, axis]) for axis in range(3)]
        cn = None if geometry.corner_normals is None else rows.take(geometry.corner_normals, prim)
        corners = None if cn is None else [(cn[:, 0, axis], cn[:, 1, axis], cn[:, 2, axis]) for axis in range(3)]
    for axis, corner_and_edges in enumerate(axes):
        if corner_and_edges is None:  # every corner and edge +0 on this axis (hit_table): the sum is +0
            position[:, axis] = 0.0 if spins else 0.0 + float(frame.offset[axis])
            continue
        p0, e1, e2 = corner_and_edges
        np.multiply(u, e1, out=column)
        column += p0
        if spins:
            np.add(column, np.multiply(v, e2, out=term), out=position[:, axis])  # (the last sum into its column)
        else:
            column += np.multiply(v, e2, out=term)
            np.add(column, frame.offset[axis], out=position[:, axis])
    if corners is None:
        ns = ng
    else:  # the corners' normals weighted by (1 - u - v, u, v), axis by axis as the position
        first, ns = 1.0 - u - v, np.empty((n, 3))
        for axis, (n0, n1, n2) in enumerate(corners):
            np.multiply(n0, first, out=column)
            column += np.multiply(u, n1, out=term)
            np.add(column, np.multiply(v, n2, out=term), out=ns[:, axis])
        ns = rows.normalized(ns)
    if spins:
        position, ng = frame.to_frame(position, ng, tau)
        _, ns = frame.to_frame(position, ns, tau)
    return position, ng, ns

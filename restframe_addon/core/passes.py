"""The render passes: their table, and the per-hit quantities they (and the shading) are made of.

Every pass but Combined and the denoising passes holds one exact value of the pixel-centre ray
(no sample averaging), so that it can be quoted: the Doppler factor D of the surface seen there (the frame's, times
a spinning surface's own), the world time the light left it, the surface's own clock then,
its depth, facing normal and object index.  The shading uses the same D (:func:`hit_doppler`)
and normals (:func:`facing_normals`): one formula for each.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import rows
from .frames import FrameSet, RestFrame
from .tracer import Hits, TraceCache, frames_hit, hit_geometry


@dataclass(frozen=True)
class Pass:
    """One render pass: its name, its channel ids (Blender's letters) and their kind."""

    name: str
    channels: str
    kind: str  # 'COLOR', 'VALUE' or 'VECTOR' (Blender's pass types)
    own: bool = False  # RESTframe's own pass (always filled); else one Blender has (filled where enabled)
    on_request: bool = False  # filled only when asked for by name (not among the default passes)


# The order is the order passes are listed in and registered with Blender.
TABLE = (
    Pass("Combined", "RGBA", "COLOR"),
    Pass("Doppler", "X", "VALUE", own=True),
    Pass("Emission Time", "X", "VALUE", own=True),
    Pass("Object Time", "X", "VALUE", own=True),
    Pass("Depth", "Z", "VALUE"),
    Pass("Normal", "XYZ", "VECTOR"),
    Pass("IndexOB", "X", "VALUE"),
    # Cycles' denoising data (for the compositor's Denoise node): averaged over the camera samples
    Pass("Denoising Normal", "XYZ", "VECTOR", on_request=True),
    Pass("Denoising Albedo", "RGB", "COLOR", on_request=True),
)
BY_NAME = {p.name: p for p in TABLE}
PASSES = {p.name: len(p.channels) for p in TABLE if p.own}  # RESTframe's own (Depth, Normal, IndexOB are Blender's)
EXTRA_PASSES = {p.name: len(p.channels) for p in TABLE if p.name != "Combined"}  # what RenderSettings.passes may ask for
ALL_PASSES = {p.name: len(p.channels) for p in TABLE}
DEFAULT_PASSES = {name: n for name, n in EXTRA_PASSES.items() if not BY_NAME[name].on_request}  # RenderSettings.passes None
DENOISING_PASSES = ("Denoising Normal", "Denoising Albedo")

_MISS_DEPTH = 1e10  # Blender's depth of the background


def hit_times(hits: Hits, sel) -> np.ndarray:
    """Frame times of the hit events of some rays (hit frame coordinates: start time minus path length)."""
    return hits.tau_frame[sel] - hits.s_frame[sel]


# a frame with this many hits is worked on alone: joining its rows with other frames' would cost
# more than the small steps it saves (those of ~4000 rows cost about what a step of one frame does)
_OWN_BATCH = 4096
# grouping the hits of more frames than this by one sort is cheaper than a pass over the rays per frame
_SORTED_FRAMES = 3


def frame_batches(hits: Hits, keep=None) -> list:
    """The rays that hit (and ``keep``, a mask, where given) in batches to work on at once: each
    frame with at least ``_OWN_BATCH`` hits alone, the others together, grouped by frame in
    increasing order.  A batch is its rows (a slice while that is every ray, else indices) and
    each of its frames' (k, rows of those).  What depends on the frame is worked out over each
    frame's rows and the parts joined (:func:`joined_frames`), the rest once per batch."""
    frame = hits.frame
    hit_frames = frames_hit(hits).tolist()
    if len(hit_frames) <= _SORTED_FRAMES:  # a few frames (one, the common case): a pass over the rays for each
        kept = [(k, rows.selection(frame == k if keep is None else (frame == k) & keep)) for k in hit_frames]
        hit_frames, frame_rows = [k for k, sel in kept if sel is not None], [sel for _, sel in kept if sel is not None]
    else:  # one stable (radix) sort of the hits' frames
        hit = rows.selection(frame >= 0 if keep is None else (frame >= 0) & keep)
        if hit is None:
            return []
        of_hit = rows.take(frame, hit)
        counts = np.bincount(of_hit, minlength=hit_frames[-1] + 1)
        hit_frames = np.flatnonzero(counts).tolist()
        by_frame = np.argsort(of_hit.astype(np.min_scalar_type(len(counts) - 1)), kind="stable")
        order = by_frame if isinstance(hit, slice) else np.take(hit, by_frame)
        frame_rows = np.split(order, np.cumsum(counts[hit_frames])[:-1])
    if len(frame_rows) == 1:  # (a slice while it is every ray)
        count = len(frame) if isinstance(frame_rows[0], slice) else len(frame_rows[0])
        return [(frame_rows[0], [(hit_frames[0], slice(0, count))])]
    batches = [(index, [(k, slice(0, len(index)))]) for k, index in zip(hit_frames, frame_rows)
               if len(index) >= _OWN_BATCH]
    together = [(k, index) for k, index in zip(hit_frames, frame_rows) if len(index) < _OWN_BATCH]
    if together:
        stops = np.cumsum([len(index) for _, index in together]).tolist()
        batches.append((joined_frames([index for _, index in together]),
                        [(k, slice(stop - len(index), stop)) for (k, index), stop in zip(together, stops)]))
    return batches


def joined_frames(parts):
    """The frames' parts of one quantity, in the order of a :func:`frame_batches` batch, as one
    array (one part as it is: a broadcast view stays one; a number, the same for every frame,
    stays a number)."""
    if len(parts) == 1 or np.ndim(parts[0]) == 0:
        return parts[0]
    return np.concatenate(parts)


def surface_doppler(frame: RestFrame, prim, u, v, tau_hit, d_k) -> np.ndarray:
    """Doppler factor of the surface's own motion in its frame (1 but for spinning bodies:
    their points move with omega x r), for light leaving along backward directions d_k."""
    if frame.spin is None:
        return np.ones(len(prim))
    position, _, _ = hit_geometry(frame, prim, u, v, tau_hit)
    velocity = frame.surface_velocity(position)
    return np.sqrt(1.0 - rows.dot(velocity, velocity)) / (1.0 + rows.dot(velocity, d_k))


def hit_doppler(frame: RestFrame, prim, u, v, tau_hit, d_k, w) -> np.ndarray:
    """Doppler factor D of the light of hits of one frame as seen by the rays' source: the
    surface's own factor over the path-length ratio w = s_frame / s (1/D between the frames)."""
    if frame.spin is None:  # (the surface's own factor is 1: the same bits as ones / w)
        return 1.0 / w
    return surface_doppler(frame, prim, u, v, tau_hit, d_k) / w


def facing_normals(frames: FrameSet, segments, prim, u, v, d_k, tau_hit=None, cache: TraceCache | None = None):
    """Position, geometric and shading normals turned toward the viewer, and whether the back
    was hit, at hits of one or more frames (``segments``: (frame k, its rows); frame
    coordinates): the geometry frame by frame, joined, turned at once.  A shading normal turned
    away from the viewer falls back to the geometric one.  Read-only for the caller: with flat
    shading the two normals are one array.  ``cache``: the calling thread's (see hit_geometry).
    Also the cosines ns . (-d_k) where the turn gives them exactly, else None (see _turned_to_viewer)."""
    geometry = [hit_geometry(frames.frames[k], prim[s], u[s], v[s], None if tau_hit is None else tau_hit[s], cache)
                for k, s in segments]
    position, ng = (joined_frames([part[i] for part in geometry]) for i in range(2))
    flat = all(part[2] is part[1] for part in geometry)  # (then the two normals are one array)
    return (position, *_turned_to_viewer(ng, ng if flat else joined_frames([part[2] for part in geometry]), d_k))


def _turned_to_viewer(ng, ns, d_k):
    """Geometric and shading normals (hit_geometry's own arrays: turned in place) facing the
    viewer, whether the back was hit, and the cosines ns . (-d_k) with the view where they come
    from the turn's own dot products (else None: a flat mesh's broadcast normal, hits on both
    sides).  A flat mesh's one broadcast normal stays one row while every hit is on the same side
    (a new array if they are on both); then the cosines are its dot products (all behind) or their
    negations (all in front); flat per-hit normals', |ng . d_k| (behind, dot > 0: the product of
    the two negated rows; in front, its negation).  ``rows.dot`` of the negated directions makes
    the same products and sums up to their sign (the sign of an exact 0 aside, which no user of a
    cosine with the view tells apart), row by row in either of its ways (a row's sum does not
    depend on the other rows)."""
    dot = rows.dot(ng, d_k)
    back = dot > 0.0
    if rows.is_broadcast(ng):  # (flat shading: ns is ng)
        if not back.any():
            return ng, ng, back, np.negative(dot, out=dot)
        if back.all():
            ng = rows.broadcast(-ng[:1], len(ng))
            return ng, ng, back, dot
        ng = ns = np.array(ng)
        dot = None  # (summed by the broadcast row's columns, the rows' turned normals by rows.dot's other way)
    for normals in (ng,) if ns is ng else (ng, ns):
        for axis in range(3):
            np.negative(normals[:, axis], out=normals[:, axis], where=back)
    if ns is ng:  # flat: the turned normal faces the viewer (or grazes it)
        return ng, ng, back, None if dot is None else np.abs(dot, out=dot)
    toward = rows.dot(ns, d_k)
    away = toward >= 0.0
    cos_view = np.negative(toward, out=toward)  # (the same products, negated, as ns . (-d_k))
    if away.any():
        ns[away] = rows.take(ng, away)
        cos_view[away] = np.where(back[away], dot[away], -dot[away])  # the turned ng's: +-(ng . d_k)
    return ng, ns, back, cos_view


def ray_doppler(frames: FrameSet, hits: Hits) -> np.ndarray:
    """D of every ray's hit (1 / w on a miss, where w = 1)."""
    doppler = 1.0 / hits.w
    for k in frames_hit(hits):
        frame = frames.frames[int(k)]
        if frame.spin is None:
            continue
        sel = np.flatnonzero(hits.frame == k)
        doppler[sel] = hit_doppler(frame, hits.prim[sel], hits.u[sel], hits.v[sel], hit_times(hits, sel),
                                   rows.take(hits.d_frame, sel), hits.w[sel])
    return doppler


def _emission_times(frames: FrameSet, light_speed: float, rays, hits: Hits, hit) -> np.ndarray:
    """The Emission Time pass (float32, 0 on a miss): the world time of each hit event, back
    along the ray in the camera frame, then into S."""
    tau, x, d = rays[:3]
    n = len(d)
    shared = n > 0 and x.strides[0] == 0 and tau.strides[0] == 0  # one event (broadcast views): no gathers
    to_world = frames.map(frames.camera, frames.world)
    emission = np.zeros(n, dtype=np.float32)
    if shared and to_world.is_identity:  # a camera at rest in S: no hit positions, no gathers
        world_tau = np.subtract(tau[0], hits.s)  # (every ray's; the misses' are not written)
        world_tau /= light_speed
        np.copyto(emission, world_tau, where=hit, casting="same_kind")
        return emission
    s_hit = hits.s[hit]
    world_tau = (tau[0] if shared else tau[hit]) - s_hit
    if not to_world.is_identity:
        world_tau, _ = to_world.events(world_tau, rows.add_scaled(x[0] if shared else rows.take(x, hit), s_hit,
                                                                  rows.take(d, hit)))
    emission[hit] = world_tau / light_speed
    return emission


def pixel_passes(frames: FrameSet, light_speed: float, wanted, rays, hits: Hits,
                 shading_normals=None, cache: TraceCache | None = None) -> dict[str, np.ndarray]:
    """The passes ``wanted`` (names besides Combined) of camera rays ``rays`` = (tau, x, d, ...)
    in the camera frame and their ``hits``, as (n, channels) float32 arrays (each value worked out
    in float64 and rounded once, as it is written).  ``shading_normals(k,
    prim, u, v, d_k, tau_hit)``: the Normal pass's normals at hits of frame k (normal maps applied,
    as Cycles shows them; None: :func:`facing_normals`'); ``cache``: the calling thread's)."""
    wanted = set(wanted)
    n = len(rays[2])
    hit = hits.frame >= 0
    passes = {}
    any_hit = bool(hit.any())  # (a tile that sees nothing: the misses' values alone)
    if "Depth" in wanted:
        passes["Depth"] = np.full(n, _MISS_DEPTH, dtype=np.float32)
        if any_hit:
            np.copyto(passes["Depth"], hits.s, where=hit, casting="same_kind")
    if "Emission Time" in wanted:
        passes["Emission Time"] = (_emission_times(frames, light_speed, rays, hits, hit) if any_hit
                                   else np.zeros(n, dtype=np.float32))
    per_frame = wanted & {"Doppler", "Normal", "IndexOB", "Object Time"}
    for name in per_frame:
        passes[name] = np.zeros((n, len(BY_NAME[name].channels)), dtype=np.float32)
    if not per_frame:
        return passes
    for order, segments in frame_batches(hits):  # several frames' hits at once, each pass written once
        _frame_passes(frames, light_speed, wanted, hits, order, segments, shading_normals, cache, passes)
    return passes


def _frame_passes(frames: FrameSet, light_speed: float, wanted, hits: Hits, order, segments, shading_normals, cache,
                  passes) -> None:
    """:func:`pixel_passes`' per-frame passes at the hits of one of :func:`frame_batches`' batches,
    each frame's values worked out over its rows and written at once."""
    tau_hit = hit_times(hits, order)
    prim, u, v = rows.take(hits.prim, order), rows.take(hits.u, order), rows.take(hits.v, order)
    parts = [(k, frames.frames[k], s) for k, s in segments]
    # the directions only where they matter: a spinning surface's Doppler factor, the normals
    spins = any(frame.spin is not None for _, frame, _ in parts)
    d_k = rows.take(hits.d_frame, order) if spins or "Normal" in wanted else None
    values = {}
    if "Doppler" in wanted:
        w = rows.take(hits.w, order)
        values["Doppler"] = [hit_doppler(frame, prim[s], u[s], v[s], tau_hit[s], None if d_k is None else d_k[s], w[s])
                             for _, frame, s in parts]
    if "Normal" in wanted:
        values["Normal"] = ([facing_normals(frames, segments, prim, u, v, d_k, tau_hit, cache)[2]]
                            if shading_normals is None else
                            [shading_normals(k, prim[s], u[s], v[s], d_k[s], tau_hit[s]) for k, _, s in parts])
    if "IndexOB" in wanted:
        values["IndexOB"] = [np.take(frame.geometry.tri_object_index, prim[s]) for _, frame, s in parts]
    if "Object Time" in wanted:
        values["Object Time"] = [frame.object_clock(tau_hit[s], prim[s]) / light_speed for _, frame, s in parts]
    for name, frame_values in values.items():
        joined = joined_frames(frame_values)
        rows.put_selection(passes[name], order, joined.reshape(len(joined), -1))

"""Rest frames: one per distinct velocity, each with its static geometry in one embreex scene.

Every frame shares the origin event ``(tau = 0, x = 0)`` of the world frame S and
has axes parallel to S (``docs/physics.md#frames``).  An object whose assembly pivot
is ``p`` sits in its frame at ``boost(0, p)`` plus its Blender shape relative to
``p``; the spatial part of that is ``p + (gamma - 1)(n.p) n``, so the whole body
is translated by ``(gamma - 1)(n.p) n`` (the time part only shifts the static
frame's clock).  At world time 0 its pivot is where the artist put it, and the
body is Lorentz-contracted about it as seen from S.

Bodies in accelerated motion or rotation become several frames (inertial
segments, see :mod:`.motion`) that share one :class:`Geometry` placed by an
offset, each valid only between two of the body's simultaneity slices (a
:class:`Window`); a rotating body is one frame whose pose the tracer sets per ray.
"""

from __future__ import annotations

import math
import os
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import TYPE_CHECKING, Callable

import numpy as np
from embreex import rtcore, rtcore_scene
from embreex.mesh_construction import TriangleMesh

from . import embree_direct, motion, observer, rows, validation
from .lorentz import Boost, events_of_boosts
from .scene import RAY_ALL, REST, Scene, Velocity

if TYPE_CHECKING:
    from .persistent import GeometryCache


class FrameMap:
    """Maps events and backward light rays from one frame's coordinates to another's.

    Stored as the chain of boosts to apply (through S), never as one boost of a
    composed velocity, so the Wigner rotation is kept.
    """

    __slots__ = ("steps",)

    def __init__(self, steps: list[Boost]):
        self.steps = [b for b in steps if not b.is_identity]

    @property
    def is_identity(self) -> bool:
        return not self.steps

    def events(self, tau, x):
        for boost in self.steps:
            tau, x = boost.events(tau, x)
        return tau, x

    def rays(self, d):
        """(d', w): mapped backward directions and the path-length ratio s'/s (= 1/D)."""
        if not self.steps:
            return d, np.ones(np.shape(d)[:-1])
        d, w = self.steps[0].rays(d)
        for boost in self.steps[1:]:
            d, step_w = boost.rays(d)
            w = w * step_w
        return d, w


def shift_into_frame(boost: Boost, pivot) -> np.ndarray:
    """Spatial offset that places a body with this pivot into its shared rest frame."""
    if boost.is_identity:
        return np.zeros(3)
    pivot = np.asarray(pivot, dtype=np.float64)
    return boost.gamma_minus_one * float(boost.n @ pivot) * boost.n


def clock_shift(boost: Boost, pivot) -> float:
    """Frame time of the body's origin event (tau = 0, pivot): its clock reads 0 there."""
    if boost.is_identity:
        return 0.0
    return -boost.gamma * boost.b * float(boost.n @ np.asarray(pivot, dtype=np.float64))


@dataclass
class Geometry:
    """Static triangles in local coordinates and their embreex scene (coordinates relative to ``anchor``)."""

    vertices: np.ndarray
    triangles: np.ndarray
    tri_material: np.ndarray
    tri_object_index: np.ndarray
    tri_clock: np.ndarray  # object clock = frame time + RestFrame.clock_offset + this
    corner_normals: np.ndarray | None
    corner_uvs: np.ndarray | None
    lo: np.ndarray
    hi: np.ndarray
    anchor: np.ndarray
    embree: object
    piece_start: np.ndarray  # first triangle of each embree geometry: triangle = piece_start[geomID] + primID
    clusters: np.ndarray = None  # (k, 4): centre and radius of spheres holding every triangle (None: a lone frame)
    tri_visibility: np.ndarray | None = None  # (M,) uint8 RAY_* bits of the rays that see each triangle; None: all
    tri_holdout: np.ndarray | None = None  # (M,) bool: holdout triangles; None: none
    radius: float = 0.0  # distance from the local origin (a moving body's pivot) to its farthest used vertex
    clock: float | None = None  # every triangle's tri_clock when they share one (a lone mesh's), else None
    extent: float = field(init=False)  # the longest side of the bounds

    def __post_init__(self):
        self.extent = float(np.max(self.hi - self.lo))
        for array in (self.vertices, self.triangles, self.tri_material, self.tri_object_index, self.tri_clock,
                      self.corner_normals, self.corner_uvs, self.lo, self.hi, self.anchor, self.piece_start,
                      self.clusters, self.tri_visibility, self.tri_holdout):
            if array is not None:
                array.flags.writeable = False  # shared by every render thread

    def face_normals(self, prim) -> np.ndarray:
        """Unit geometric normals of the triangles ``prim`` (0 for degenerate ones), worked out
        for the hits that need them: a pass over every triangle at build time cost a third of
        the BVH build, for a mesh whose hits are a fraction of its triangles."""
        corners = self.triangles[prim]
        p0 = self.vertices[corners[:, 0]]
        return triangle_normals(self.vertices[corners[:, 1]] - p0, self.vertices[corners[:, 2]] - p0)


def triangle_normals(edge1, edge2) -> np.ndarray:
    """Unit normals (n, 3) of triangles from their two edges out of the first corner (0 for degenerate ones)."""
    return rows.normalized(rows.cross(edge1, edge2))


@dataclass(frozen=True)
class Slice:
    """A Born-rigid body's simultaneity slice through one pivot event, in a frame's coordinates:
    the events (t, x) with ``(t - time) - beta.(x - position) = 0``, beta the pivot's velocity there.

    ``slack`` (time) is how far the segments on both sides of this cut reach past it: their
    surfaces disagree there by up to the sum of their error bounds, and without the overlap a
    ray crossing the surface at the cut could pass between them into the body.  With it a ray
    meets one of the two surfaces (both within the tolerance of the true one) unless it crosses
    within 30 degrees of grazing.
    """

    time: float
    position: np.ndarray
    beta: np.ndarray
    slack: float = 0.0

    def crossing(self, tau, origin, d, later: float):
        """Path length at which backward rays ``(tau - s, origin + s d)`` cross the slice moved
        ``later`` in time; their events lie after it for smaller s (the denominator
        ``1 + beta.d`` is positive, |beta| < 1)."""
        after = tau - self.time - (origin - self.position) @ self.beta
        return (after - later) / (1.0 + d @ self.beta)


@dataclass(frozen=True)
class Window:
    """Where an inertial segment of an accelerated body holds: after its ``start`` slice and
    before its ``end`` slice, each widened by its slack (None: the motion continues inertially).

    The slices are the body's true ones at the segment's ends, shared with its neighbours, so the
    segments tile the body's world tube.  Bounding each segment by its own simultaneity instead
    leaves wedges between neighbours whose slices differ in tilt: at a distance r from the pivot
    along the acceleration a, the body would be missing (or doubled) for a share ~ r a / 2 of the
    time, whatever the tolerance, and rays slip into the body through the gaps.
    """

    start: Slice | None
    end: Slice | None

    def clip(self, tau, origin, d, s_lo, s_hi):
        """Narrow the path-length ranges of backward rays (frame coordinates) to the window."""
        if self.end is not None:
            s_lo = np.maximum(s_lo, self.end.crossing(tau, origin, d, self.end.slack))
        if self.start is not None:
            s_hi = np.minimum(s_hi, self.start.crossing(tau, origin, d, -self.start.slack))
        return s_lo, s_hi


@dataclass
class RestFrame:
    """One inertial frame, and the triangles at rest in it (possibly none).

    Local geometry coordinates map to frame coordinates by ``local + offset``, or for a
    spinning body by ``pose(t) @ local + offset`` at frame time t.  ``window`` limits the
    placement to a stretch of spacetime (the inertial segments of an accelerated body).
    """

    index: int
    velocity: Velocity
    boost: Boost
    names: list[str] = field(default_factory=list)
    geometry: Geometry | None = None
    offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    window: Window | None = None
    clock_offset: float = 0.0  # the body's clock = frame time + clock_offset (+ Geometry.tri_clock)
    spin: np.ndarray | None = None  # angular velocity (rad per unit c*t) about ``offset``
    tolerance: float = 1e-3  # accelerated and spinning bodies: how far they may stray from their true motion

    @property
    def has_geometry(self) -> bool:
        return self.geometry is not None

    @property
    def surface_offset(self) -> float:
        """How far secondary and shadow rays start off a surface of this frame: above the float32
        geometry's rounding (relative to its extent), the float64 rounding of far positions (a
        hundred ulps), and, for the inertial segments of an accelerated body, twice the motion
        tolerance by which neighbouring segments of the same body may disagree."""
        reach = float(np.max(np.abs(self.geometry.anchor))) + float(np.max(np.abs(self.offset)))
        segment = 2.0 * self.tolerance if self.window is not None else 0.0
        return 1e-5 * self.geometry.extent + 1e-14 * reach + segment

    def object_clock(self, tau, prim):
        """The body's own clock (c*t units, 0 at its origin event) at frame times tau (an array)
        of hits on triangles prim (as long): without a gather when the triangles share one clock
        (the same sums: 0.23 ms a call for the floor's 45k hits)."""
        clock = self.geometry.clock
        return tau + self.clock_offset + (self.geometry.tri_clock[prim] if clock is None else clock)

    def pose(self, tau):
        """Rotations (n, 3, 3) of a spinning body at frame times tau: its Blender pose at clock 0."""
        return motion.rotation_matrix(np.outer(np.asarray(tau) + self.clock_offset, self.spin))

    def to_local(self, x, d, tau=None):
        """Frame coordinates (points, directions; at frame times tau if spinning) -> local geometry."""
        if self.spin is None:
            return (x - self.offset if self.offset.any() else x), d
        pose = self.pose(tau)
        return np.einsum("nji,nj->ni", pose, x - self.offset), np.einsum("nji,nj->ni", pose, d)

    def to_frame(self, x, d, tau=None):
        """Local geometry coordinates (points, directions) -> frame coordinates."""
        if self.spin is None:
            return rows.add(x, self.offset), d
        pose = self.pose(tau)
        return np.einsum("nij,nj->ni", pose, x) + self.offset, np.einsum("nij,nj->ni", pose, d)

    def surface_velocity(self, x):
        """Velocity (units of c) of body points at frame positions x: omega x r for a spinning body."""
        if self.spin is None:
            return np.zeros_like(x)
        return np.cross(self.spin, x - self.offset)


@dataclass
class SegmentGroup:
    """The inertial segments (frames) of one animated body, for culling them all at once."""

    trajectory: "motion.Trajectory"
    frames: np.ndarray  # frame indices, in world-time order
    start: np.ndarray  # pivot world-time window of each segment (-inf / inf at the ends)
    end: np.ndarray
    reach: float  # how far (in c*t) a body event can be from the pivot's light-cone crossing

    def __post_init__(self):
        finite = lambda t: np.clip(t, self.trajectory.tau[0], self.trajectory.tau[-1])
        self.start_pos = self.trajectory.state(finite(self.start))[0]
        self.end_pos = self.trajectory.state(finite(self.end))[0]

    def visible_from(self, tau, x, spread: float) -> np.ndarray:
        """Segments whose body can lie on the past light cone of events within ``spread`` of (tau, x).

        ``f(s) = s + |x - X(s)| - tau`` rises with the pivot's world time s; body events sit
        within ``reach`` of the pivot's, so a segment matters only if [f(start), f(end)]
        meets [-(reach + spread), reach + spread].
        """
        margin = self.reach + spread
        f_start = np.where(np.isfinite(self.start), self.start + np.linalg.norm(x - self.start_pos, axis=1) - tau, -np.inf)
        f_end = np.where(np.isfinite(self.end), self.end + np.linalg.norm(x - self.end_pos, axis=1) - tau, np.inf)
        return self.frames[(f_start <= margin) & (f_end >= -margin)]


class FrameSet:
    """All frames of a scene: geometry frames, light frames, the camera's and S.

    Read-only once built (tuples, no caches), so threads and processes share it freely;
    memoising what the tracer derives from it is the job of a per-thread
    :class:`~.tracer.TraceCache`.
    """

    def __init__(self, frames: list[RestFrame], world: int, camera: int, light_frames: list[int], warnings: list[str],
                 groups: list[SegmentGroup] = ()):
        self.frames = tuple(frames)
        self.world = world
        self.camera = camera
        self.light_frames = tuple(light_frames)
        self.warnings = tuple(warnings)
        self.groups = tuple(groups)
        self.geometry = tuple(f.index for f in frames if f.has_geometry)
        self.geometry_slot = MappingProxyType({k: i for i, k in enumerate(self.geometry)})  # frame -> place in geometry
        grouped = {int(i) for g in self.groups for i in g.frames}
        self.ungrouped = tuple(k for k in self.geometry if k not in grouped)
        # the ray types (RAY_* bits) some triangle is hidden from, and whether any is a holdout
        self.hidden_rays = 0
        for k in self.geometry:
            visibility = frames[k].geometry.tri_visibility
            if visibility is not None:
                self.hidden_rays |= RAY_ALL & ~int(np.bitwise_and.reduce(visibility))
        self.has_holdout = any(frames[k].geometry.tri_holdout is not None for k in self.geometry)
        self.surface_offsets = np.zeros(len(frames))  # RestFrame.surface_offset per frame (0 without geometry)
        self.surface_offsets[list(self.geometry)] = [frames[k].surface_offset for k in self.geometry]
        self.surface_offsets.flags.writeable = False
        self._inverse = tuple(f.boost.inverse() for f in frames)  # into S from each frame
        self._rigid = np.array([frames[k].spin is None for k in self.geometry], dtype=bool)  # (not spinning)
        self._rigid.flags.writeable = False
        self._world_lines, self._rest_half = self._body_world_lines()

    def candidates(self, src: int, tau0, x0) -> list[int]:
        """Geometry frames that rays from these events (frame src) may hit: all but the segments
        of animated bodies whose light cannot reach the events."""
        if not self.groups:
            return self.geometry
        tau_w, x_w = self.map(src, self.world).events(tau0, x0)
        tau_c, x_c = float(np.mean(tau_w)), np.mean(x_w, axis=0)
        spread = float(np.max(np.abs(tau_w - tau_c))) + float(np.max(np.linalg.norm(x_w - x_c, axis=1)))
        chosen = list(self.ungrouped)
        for group in self.groups:
            chosen.extend(int(k) for k in group.visible_from(tau_c, x_c, spread))
        return chosen

    def _body_world_lines(self):
        """Two events (t, x) of each geometry frame's body centre in S, (len(self.geometry), 2, 4),
        and the half-extents of its box in its rest frame (a spinning body: the cube around its sphere)."""
        lines, half = np.empty((len(self.geometry), 2, 4)), np.empty((len(self.geometry), 3))
        for line, rest_half, k in zip(lines, half, self.geometry):
            frame = self.frames[k]
            spinning = frame.spin is not None
            centre = frame.offset if spinning else frame.geometry.anchor + frame.offset
            line[:, 0], line[:, 1:] = self.map(k, self.world).events(np.array([0.0, 1.0]), np.array([centre, centre]))
            rest_half[:] = frame.geometry.radius if spinning else 0.5 * (frame.geometry.hi - frame.geometry.lo)
        lines.flags.writeable = half.flags.writeable = False
        return lines, half

    def body_boxes(self, src: int):
        """(t, x, velocity, half), each (len(self.geometry), ...): for every geometry frame, an
        axis-aligned box with half-extents ``half`` that holds its body at every time of frame
        src, its centre moving uniformly (at x at time t).  Worked out on each call (the
        tracer keeps them per thread, see :class:`~.tracer.TraceCache`).

        The body's box in its rest frame, Lorentz-contracted along the relative velocity (a
        linear map I - c n n^T with 0 <= c < 1: each of its entries lies between its values at
        c = 0 and c = 1, which bounds the image box); a spinning body: the cube around its sphere.
        """
        return tuple(a[0] for a in self.body_boxes_of([src]))

    def body_boxes_of(self, sources) -> tuple:
        """:meth:`body_boxes` of each frame of ``sources``, worked out at once (every source frame's
        map of the world lines in one pass: a scene's many velocities cost about as much as one):
        (t, x, velocity, half), each (len(sources), len(self.geometry), ...)."""
        lines = self._world_lines  # in S (the world frame)
        t, x = events_of_boosts([self.frames[src].boost for src in sources], lines[..., 0].ravel(),
                                lines[..., 1:].reshape(-1, 3))
        t, x = t.reshape(len(sources), -1, 2), x.reshape(len(sources), -1, 2, 3)  # (sources, geometry, 2 events)
        velocity = (x[:, :, 1] - x[:, :, 0]) / (t[:, :, 1] - t[:, :, 0])[..., None]
        half = np.repeat(self._rest_half[None], len(sources), axis=0)
        speed = np.sqrt(np.einsum("sij,sij->si", velocity, velocity))
        moving = (speed > 0.0) & self._rigid
        if moving.any():
            # max(I, |I - n n^T|) has 1 on its diagonal (0 <= n_i^2 <= 1) and |n_i n_j| off it
            along = np.abs(velocity[moving] / speed[moving, None])
            weighted = along * half[moving]
            half[moving] += along * (weighted.sum(axis=1, keepdims=True) - weighted)
        return t[:, :, 0], x[:, :, 0], velocity, half

    def map(self, a: int, b: int) -> FrameMap:
        """The map from frame a's coordinates to frame b's (through S)."""
        fa, fb = self.frames[a].boost, self.frames[b].boost
        # (one frame's boost is one object: is tells it without same_as' comparison of directions)
        return FrameMap([]) if fa is fb or fa.same_as(fb) else FrameMap([self._inverse[a], fb])


@dataclass
class MotionSettings:
    """How closely accelerated and rotating bodies follow their true motion."""

    tolerance: float = 1e-3  # scene units: largest displacement of any body point from its true motion


def build_frames(scene: Scene, should_stop=lambda: False, motion_settings: MotionSettings | None = None,
                 geometry_cache: GeometryCache | None = None) -> FrameSet:
    """Group the scene by velocity and build one embreex scene per moving or static frame.

    With a ``geometry_cache`` (persistent data across frames), geometry whose parts are
    unchanged since the cache's last frame is taken from it instead of built again.
    Raises ValueError (naming the object) for invalid velocities or motions.
    """
    motion_settings = motion_settings or MotionSettings()

    def build(parts: list[dict]) -> Geometry | None:
        if geometry_cache is None:
            return _geometry(parts, should_stop)
        return geometry_cache.geometry(parts, lambda: _geometry(parts, should_stop))

    frames: list[RestFrame] = []
    by_key: dict[tuple, RestFrame] = {}
    warnings: list[str] = []

    boosts: dict[tuple, Boost] = {}  # by velocity key: checked and worked out (in exact arithmetic) once, not per object

    def shared_frame(velocity: Velocity, name: str) -> RestFrame:
        boost = boosts.get(velocity.key)
        if boost is None:
            boost = boosts[velocity.key] = Boost.from_velocity(velocity.beta, velocity.lorentz_factor, name=name)
        key = REST.key if boost.is_identity else velocity.key
        frame = by_key.get(key)
        if frame is None:
            frame = RestFrame(index=len(frames), velocity=velocity, boost=boost)
            frames.append(frame)
            by_key[key] = frame
        frame.names.append(name)
        return frame

    world = shared_frame(REST, "world").index
    camera = shared_frame(observer.camera_velocity(scene.camera, scene.tau_obs), scene.camera.name).index
    # an animated lamp is in no one frame: it is lit from its momentary rest frame at each retarded event
    light_frames = [shared_frame(REST if light.trajectory is not None else light.velocity, light.name).index
                    for light in scene.lights]

    inertial: dict[int, list] = {}
    part_names: dict[int, list[str]] = {}  # the meshes of each frame's parts, for their warnings
    groups: list[SegmentGroup] = []
    special: dict[int, tuple] = {}  # id(trajectory) or mesh id -> (kind, meshes)
    for mesh in scene.meshes:
        if should_stop():
            break
        if mesh.trajectory is not None:
            special.setdefault(id(mesh.trajectory), ("animated", []))[1].append(mesh)
        elif mesh.angular_velocity is not None and np.any(mesh.angular_velocity):
            special[id(mesh)] = ("rotating", [mesh])
        else:
            frame = shared_frame(mesh.velocity, mesh.name)
            part = _mesh_part(mesh, frame.boost, warnings)
            if part is not None:
                inertial.setdefault(frame.index, []).append(part)
                part_names.setdefault(frame.index, []).append(mesh.name)

    for index, parts in inertial.items():
        if should_stop():
            break
        frames[index].geometry = build(parts)
        if frames[index].geometry is not None:
            warnings.extend(_precision_warnings(part_names[index], parts, frames[index].geometry))
    for kind, meshes in special.values():
        if should_stop():
            break
        if kind == "animated":
            _add_segments(frames, meshes, scene, motion_settings, warnings, groups, build)
        else:
            _add_rotation(frames, meshes[0], scene, motion_settings, warnings, build)
    _add_clusters([f.geometry for f in frames if f.has_geometry], should_stop)
    if geometry_cache is not None and not should_stop():
        geometry_cache.finish_frame()
    return FrameSet(frames, world, camera, light_frames, warnings, groups)


# how much of an object's size its float32 vertices may be rounded by, relative to its frame's
# anchor, before the render warns (1e-3: a pixel of an object 1000 pixels across)
_ROUNDING_WARNING = 1e-3


_EMBREE_REACH = 2.0**41  # local coordinates embree still hits (raw embreex misses triangles at 2**42)


def _precision_warnings(names: list[str], parts: list[dict], geometry: Geometry) -> list[str]:
    """A warning naming the meshes of one frame that embree cannot trace as they are: beyond its
    reach, or rounded badly by float32 coordinates about the frame's one anchor (small objects far
    from the others with the same velocity: a 2-unit ball 1e5 units from another object has its
    depth off by 1 %; 1e7 away it falls apart)."""
    if geometry.extent / 2 >= _EMBREE_REACH:
        return [f"{', '.join(names)}: {geometry.extent:.3g} scene units across, more than Embree can trace "
                f"({2 * _EMBREE_REACH:.2g}): triangles will be missing; scale the scene down"]
    if len(parts) < 2:
        return []
    # each part's bounds at once from the frame's vertices, the parts' one after another (a pass a
    # column, not six reductions a part: 4.2 of the 11x11 bars' 12.7 ms prepare), by column: numpy
    # is slow along a length-3 axis
    starts = np.cumsum([0] + [len(part["vertices"]) for part in parts[:-1]])
    columns = [geometry.vertices[:, axis] for axis in range(3)]
    lo = np.stack([np.minimum.reduceat(column, starts) for column in columns], axis=1)
    hi = np.stack([np.maximum.reduceat(column, starts) for column in columns], axis=1)
    rounding = np.max(np.maximum(np.abs(lo - geometry.anchor), np.abs(hi - geometry.anchor)), axis=1) * 2.0**-24
    far = rounding > _ROUNDING_WARNING * np.max(hi - lo, axis=1)  # rounded by more than half an ulp allows
    if not far.any():
        return []
    rounded = [name for name, is_far in zip(names, far.tolist()) if is_far]
    return [f"{', '.join(rounded)}: too far from the other objects with the same velocity for float32 geometry "
            f"(rounded by up to {float(rounding[far].max()):.2g} scene units): move far objects nearer and scale "
            "them down (they look the same from a camera at rest), or scale the scene down"]


def _add_clusters(geometries: list[Geometry], should_stop) -> None:
    """Culling clusters for every geometry, where there are several: the tracer culls a ray
    bundle by them only between frames (a lone mesh pays nothing).  Small meshes go together,
    up to ``_CHUNK`` triangles at a time (one pass for all: many small frames, as many rows of
    bars each moving at its own speed, paid a pass each).  Stops once ``should_stop()`` is true."""
    if len(geometries) < 2:
        return
    batches: list[list[Geometry]] = [[]]
    for geometry in {id(g): g for g in geometries}.values():  # segments share one geometry
        if geometry.clusters is not None:  # reused from an earlier frame (persistent data): the same clusters
            continue
        if len(geometry.triangles) > _CHUNK:
            batches.append([geometry])
        elif sum(len(g.triangles) for g in batches[0]) + len(geometry.triangles) <= _CHUNK:
            batches[0].append(geometry)
        else:
            batches.insert(0, [geometry])
    for batch in batches:
        if not batch:
            continue
        clusters = _clusters_of([(g.vertices, g.triangles) for g in batch], should_stop)
        if clusters is None:
            return
        for geometry, spheres in zip(batch, clusters):
            spheres.flags.writeable = False  # as Geometry's own arrays
            geometry.clusters = spheres


def _mesh_part(mesh, boost: Boost, warnings: list[str], relative_to=None):
    """Valid triangles of a mesh, placed in its shared frame (or relative to a pivot): the
    vertices in a new array, the other arrays possibly views of the mesh's; ``"new"``: which of the
    triangles and material numbers are not (a lone part's are then used as they are, not copied again)."""
    vertices = np.asarray(mesh.vertices, dtype=np.float64).reshape(-1, 3)
    triangles = np.asarray(mesh.triangles, dtype=np.int64).reshape(-1, 3)
    if len(triangles) == 0:
        return None
    # (read as unsigned, a negative index is larger than any vertex count: one reduction for both ends)
    if int(triangles.view(np.uint64).max()) < len(vertices) and np.isfinite(vertices).all():
        keep, count = slice(None), len(triangles)  # the common case, checked without a pass per triangle
    else:
        valid = np.all((triangles >= 0) & (triangles < len(vertices)), axis=1)
        finite_vertex = np.all(np.isfinite(vertices), axis=1)
        valid[valid] &= np.all(finite_vertex[triangles[valid]], axis=1)
        if not valid.all():
            warnings.append(f"{mesh.name}: skipped {np.count_nonzero(~valid)} triangles with invalid or non-finite vertices")
        keep = np.flatnonzero(valid)
        count = len(keep)
        if count == 0:
            return None
    materials = (
        np.zeros(len(triangles), dtype=np.int32)
        if mesh.material_indices is None
        else np.asarray(mesh.material_indices, dtype=np.int32)
    )
    triangles, materials = triangles[keep], materials[keep]
    new = tuple(name for name, array, given in (("material", materials, mesh.material_indices),
                                                ("triangles", triangles, mesh.triangles))
                if not (isinstance(given, np.ndarray) and np.may_share_memory(array, given)))  # (a tuple: parts_key digests it)
    if relative_to is None:
        placed = vertices + shift_into_frame(boost, mesh.pivot)
        clock = -clock_shift(boost, mesh.pivot)
    else:
        placed = vertices - np.asarray(relative_to, dtype=np.float64)
        clock = 0.0
    return {
        "vertices": placed,
        "triangles": triangles,
        "material": materials,
        "object_index": np.full(count, mesh.object_index, dtype=np.int32),
        "clock": np.full(count, clock),
        "normals": None if mesh.corner_normals is None else np.asarray(mesh.corner_normals, np.float64)[keep],
        "uvs": None if mesh.corner_uvs is None else np.asarray(mesh.corner_uvs, np.float64)[keep],
        "visibility": int(mesh.visibility) & RAY_ALL,
        "holdout": bool(mesh.holdout),
        "new": new,
    }


_DEVICE = None  # one embree device for every scene: a device per scene crashes embree past ~1000


def _embree_device():
    global _DEVICE
    if _DEVICE is None:
        _DEVICE = rtcore.EmbreeDevice()
    return _DEVICE


# Triangles per embree geometry, so that Esc is polled between pieces: with embreex's own
# TriangleMesh, which copies a mesh into embree element by element while holding the GIL (1.6 s
# for a million triangles in one piece), a piece of 2**14 triangles takes about 35 ms.  Handed
# over directly (embree_direct) a piece of 2**22 takes about as long (two memory copies), so
# most meshes go in one piece: each query's hits of a mesh in pieces are renumbered (a gather
# of every ray's geometry id, 0.17 ms per 65k rays).  Embree builds one BVH over all pieces of
# a scene from the same triangles in the same order either way: the same hits.
_PIECE_TRIANGLES = 2**14
_DIRECT_PIECE_TRIANGLES = 2**22


def _geometry(parts: list[dict], should_stop=lambda: False) -> Geometry | None:
    """The parts' triangles in one embreex scene; None once ``should_stop()`` is true
    (checked between pieces of ``_DIRECT_PIECE_TRIANGLES``, through embreex ``_PIECE_TRIANGLES``;
    embree's BVH build, last, cannot be interrupted)."""
    offsets = np.cumsum([0] + [len(p["vertices"]) for p in parts[:-1]])
    # (a lone part's vertices are its own: _mesh_part places them in a new array)
    vertices = parts[0]["vertices"] if len(parts) == 1 else np.concatenate([p["vertices"] for p in parts])
    direct = embree_direct.ready(_embree_device())

    def index_side():
        triangles = _joined([p["triangles"] + o if o else p["triangles"] for p, o in zip(parts, offsets)],
                            new="triangles" in parts[0]["new"])
        is_used = np.zeros(len(vertices), dtype=bool)
        is_used[triangles] = True  # a mask, not np.unique: no sort (0.14 s -> 0.02 s for 1M triangles)
        # embree's index buffer as embree_direct makes it (uint32), here beside the vertices' side
        return triangles, is_used, np.ascontiguousarray(triangles, dtype=np.uint32) if direct else triangles

    if sum(len(p["triangles"]) for p in parts) > _CHUNK:  # the vertices' side as if all are used (the common case)
        (triangles, is_used, indices), placed, (normals, uvs) = _side_by_side(lambda side: side(), [
            (index_side,), (lambda: _placed(vertices, vertices),), (lambda: _corner_attributes(parts),)])
    else:  # one after the other (a small mesh's steps take less than handing them to a thread)
        (triangles, is_used, indices), placed, (normals, uvs) = index_side(), None, _corner_attributes(parts)
    visibility = holdout = None
    if any(p["visibility"] != RAY_ALL for p in parts):
        visibility = np.concatenate([np.full(len(p["triangles"]), p["visibility"], dtype=np.uint8) for p in parts])
    if any(p["holdout"] for p in parts):
        holdout = np.concatenate([np.full(len(p["triangles"]), p["holdout"]) for p in parts])
    if placed is None or not is_used.all():
        placed = _placed(vertices if is_used.all() else vertices[is_used], vertices)
    lo, hi, radius, anchor, padded = placed
    scene = rtcore_scene.EmbreeScene(_embree_device())
    local_vertices = padded[:, :3]
    shared = embree_direct.shared_vertices(_embree_device(), padded)
    piece = _PIECE_TRIANGLES if shared is None else _DIRECT_PIECE_TRIANGLES
    piece_start = np.arange(0, len(triangles), piece, dtype=np.int32)
    claimed_by = np.empty(len(vertices), dtype=np.intp)  # scratch for _attach_piece
    try:
        for start in piece_start:
            if should_stop():
                return None
            _attach_piece(scene, local_vertices, indices[start:start + piece], claimed_by, shared)
    finally:
        if shared is not None:
            shared.release()
    _commit(scene)
    return Geometry(
        radius=radius,
        vertices=vertices, triangles=triangles,
        tri_material=_joined([p["material"] for p in parts], new="material" in parts[0]["new"]),
        tri_object_index=_joined([p["object_index"] for p in parts], new=True),  # (_mesh_part's np.full)
        tri_clock=_joined([p["clock"] for p in parts], new=True),
        clock=float(parts[0]["clock"][0]) if len(parts) == 1 else None,  # (_mesh_part's np.full of one clock)
        corner_normals=normals, corner_uvs=uvs, lo=lo, hi=hi, anchor=anchor, embree=scene,
        piece_start=piece_start, tri_visibility=visibility, tri_holdout=holdout,
    )


def _corner_attributes(parts: list[dict]) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The parts' corner normals and UVs (M, 3, 3) and (M, 3, 2), in arrays of the geometry's own
    (None: no part has them; a part without them gets flat normals, zero UVs)."""
    normals = uvs = None
    if any(p["normals"] is not None for p in parts):
        normals = np.concatenate([p["normals"] if p["normals"] is not None else _flat_normals(p) for p in parts])
    if any(p["uvs"] is not None for p in parts):
        uvs = np.concatenate([p["uvs"] if p["uvs"] is not None else np.zeros((len(p["triangles"]), 3, 2)) for p in parts])
    return normals, uvs


def _placed(used: np.ndarray, vertices: np.ndarray):
    """(lo, hi, radius, anchor, float32 vertices in embree's layout about the anchor) of a
    geometry's ``vertices`` from those of them its triangles ``used``."""
    x, y, z = (used[:, axis] for axis in range(3))  # by column: numpy is slow along a length-3 axis
    lo, hi = np.array([x.min(), y.min(), z.min()]), np.array([x.max(), y.max(), z.max()])
    radius = float(np.sqrt(np.max(x * x + y * y + z * z)))
    anchor = 0.5 * (lo + hi)
    return lo, hi, radius, anchor, embree_direct.padded_vertices(vertices, anchor)  # float32, rounded once


def _joined(arrays: list[np.ndarray], new: bool = False) -> np.ndarray:
    """The arrays one after the other: the one array of a lone part as it is if ``new`` (made
    for this build), else a copy (it may be a view of the scene's), not two."""
    if len(arrays) == 1:
        return arrays[0] if new else np.array(arrays[0])
    return np.concatenate(arrays)


def _commit(scene) -> None:
    """Build the scene's BVH now (embreex commits lazily on the first query, which is not
    thread-safe): directly (embree_direct) without holding the GIL, so that the engine's main
    thread goes on polling Esc; through embreex holding it (about 0.4 s per million triangles)."""
    if embree_direct.ready(_embree_device()):
        embree_direct.commit(scene)
    else:
        scene.run(np.zeros((1, 3), np.float32), np.array([[1, 0, 0]], np.float32))


def _attach_piece(scene, vertices, triangles, claimed_by, shared=None) -> None:
    """Add triangles to an embreex scene as one geometry: directly, on the mesh's
    :class:`embree_direct.SharedVertices` when given, else through embreex, holding only the
    vertices they use (embreex copies every vertex it is given).

    For embreex the used vertices are renumbered without sorting (np.unique costs 3x as much):
    each is claimed by one of its corners in ``claimed_by`` (scratch, one entry per vertex),
    and the claiming corners, in order, number them.
    """
    if shared is not None and embree_direct.attach(scene, _embree_device(), shared, triangles):
        return
    corners = triangles.ravel()
    corner_index = np.arange(len(corners))
    claimed_by[corners] = corner_index  # of a vertex's corners, one is stored
    claimant = claimed_by[corners]
    claims = claimant == corner_index
    new_number = np.cumsum(claims, dtype=np.int32) - 1
    TriangleMesh(scene, vertices[corners[claims]], new_number[claimant].reshape(-1, 3))


def _clusters(vertices, triangles, should_stop=lambda: False, depth: int = 4) -> np.ndarray | None:
    """Bounding spheres of up to 2**depth groups of triangles (median splits of their centroids
    along the longest axis): a tighter outline than one sphere, for culling whole ray bundles.
    None once ``should_stop()`` is true (checked between steps)."""
    clusters = _clusters_of([(vertices, triangles)], should_stop, depth)
    return None if clusters is None else clusters[0]


def _clusters_of(meshes: list[tuple], should_stop=lambda: False, depth: int = 4) -> list[np.ndarray] | None:
    """:func:`_clusters` of each mesh (vertices, triangles), all in one pass.

    Worked on (3, n) arrays, coordinate by triangle (numpy is slow along a length-3 last axis,
    and on a small mesh the calls cost more than their arithmetic): a group's box is the box of
    its triangles' own boxes.  The groups of a split that have the same size are split at once
    (one row each).  The triangles go in chunks, and (for a large mesh) the groups of each split
    and the groups' lower and upper bounds side by side, to the build's threads (numpy lets go
    of the GIL on long arrays); each gathers into its own stretch of one scratch array (fresh
    arrays this size cost more in page faults than the arithmetic).  The triangles' indices are
    valid, so ``take`` has nothing to clip.
    """
    counts = [len(triangles) for _, triangles in meshes]
    first = np.cumsum([0] + counts)  # each mesh's first triangle
    n = int(first[-1])
    scratch = np.empty((3, n))
    if len(meshes) == 1:
        corner_index = np.ascontiguousarray(meshes[0][1].T)
        columns = np.ascontiguousarray(meshes[0][0].T)
    else:  # every mesh's triangles and vertices in a row
        offsets = np.cumsum([0] + [len(vertices) for vertices, _ in meshes[:-1]])
        corner_index = np.concatenate([triangles.T + offset for (_, triangles), offset in zip(meshes, offsets)], axis=1)
        columns = np.concatenate([vertices.T for vertices, _ in meshes], axis=1)
    centroids, tri_lo, tri_hi = np.empty((3, n)), np.empty((3, n)), np.empty((3, n))  # [axis, triangle]

    def stretch(start: int, stop: int) -> np.ndarray:
        """The scratch's (3, stop - start) stretch for triangles start..stop, contiguous, so that
        ``take`` fills it in place (a strided ``out`` is filled through a temporary copy)."""
        return scratch.reshape(-1)[3 * start:3 * stop].reshape(3, -1)

    def triangle_bounds(start: int, stop: int) -> None:
        centroid, lo, hi = (a[:, start:stop] for a in (centroids, tri_lo, tri_hi))
        corner = stretch(start, stop)
        for i, index in enumerate(corner_index):
            np.take(columns, index[start:stop], axis=1, out=corner, mode="clip")
            if i == 0:
                centroid[...], lo[...], hi[...] = corner, corner, corner
            else:
                np.minimum(lo, corner, out=lo)
                np.maximum(hi, corner, out=hi)
                centroid += corner
        centroid /= 3.0

    def halves(rows: np.ndarray, at: int) -> list[np.ndarray]:
        """Groups of one size, one a row, each split at its centroids' median along their longest
        axis (``at``: where their stretch of the scratch array starts): the halves in order."""
        count, size = rows.shape
        c = np.take(centroids, rows, axis=1, out=stretch(at, at + rows.size).reshape(3, count, size), mode="clip")
        axis = np.argmax(c.max(axis=2) - c.min(axis=2), axis=0)
        along = c[axis, np.arange(count)] if count > 1 else c[int(axis[0])]
        order = np.argpartition(along, size // 2, axis=1)  # row by row, as for each alone
        return [half for group, row in zip(rows, order) for half in (group[row[:size // 2]], group[row[size // 2:]])]

    def split(groups: list[np.ndarray]) -> list[np.ndarray]:
        """Every group of ``_SMALLEST_SPLIT`` triangles or more split in two, in place."""
        together: dict[int, list[int]] = {}  # the groups to split by size (each alone on threads)
        for i, group in enumerate(groups):
            if len(group) >= _SMALLEST_SPLIT:
                together.setdefault(i if threaded else len(group), []).append(i)
        tasks = list(together.values())
        rows = [groups[task[0]][None, :] if len(task) == 1 else np.array([groups[i] for i in task]) for task in tasks]
        at = np.cumsum([0] + [part.size for part in rows[:-1]]).tolist()
        halved = {}
        for task, pieces in zip(tasks, _side_by_side(halves, list(zip(rows, at)), threaded)):
            halved.update((i, pieces[2 * j:2 * j + 2]) for j, i in enumerate(task))
        return [piece for i, group in enumerate(groups) for piece in halved.get(i, [group])]

    def boxes(reduce, bounds, out) -> np.ndarray:
        """Every group's ``reduce`` (min or max) of its triangles' ``bounds`` (3, n): their
        triangles in a row (gathered into ``out``), reduced group by group."""
        return reduce.reduceat(np.take(bounds, in_groups, axis=1, out=out, mode="clip"), starts, axis=1)

    if should_stop():
        return None
    threaded = n > _CHUNK  # a small mesh's steps take less than handing them to a thread
    _side_by_side(triangle_bounds, [(start, min(start + _CHUNK, n)) for start in range(0, n, _CHUNK)])
    groups = [np.arange(a, b) for a, b in zip(first[:-1], first[1:])]
    for _ in range(depth):
        if should_stop():
            return None
        if all(len(group) < _SMALLEST_SPLIT for group in groups):  # none splits any more
            break
        groups = split(groups)
    if should_stop():
        return None
    in_groups = np.concatenate(groups)
    starts = np.cumsum([0] + [len(group) for group in groups[:-1]])
    # (the centroids, split by now, are the second gather's scratch)
    lo, hi = (b.T for b in _side_by_side(boxes, [(np.minimum, tri_lo, scratch), (np.maximum, tri_hi, centroids)],
                                            threaded))
    spheres = np.empty((len(groups), 4))
    spheres[:, :3] = 0.5 * (lo + hi)
    # the radii term by term: BLAS's dot of a 3-vector rounds differently with its address's
    # alignment on some CPUs (AVX-512 OpenBLAS kernels), these do not
    span = hi - lo
    spheres[:, 3] = 0.5 * np.sqrt(span[:, 0] * span[:, 0] + span[:, 1] * span[:, 1] + span[:, 2] * span[:, 2])
    owner = np.searchsorted(first[1:], [int(group[0]) for group in groups], side="right")  # each group's mesh
    return np.split(spheres, np.cumsum(np.bincount(owner, minlength=len(meshes)))[:-1])


_CHUNK = 2**16  # triangles per task of the culling clusters' first pass
_SMALLEST_SPLIT = 64  # triangles: a culling cluster of fewer is not split


_POOL: ThreadPoolExecutor | None = None  # the build's threads, one per core
_POOL_LOCK = threading.Lock()


def _side_by_side(work: Callable, arguments: list[tuple], threaded: bool = True) -> list:
    """``[work(*a) for a in arguments]``, computed on the build's threads (in the calling
    thread where there is one task or one core, or not ``threaded``)."""
    global _POOL
    if not threaded or len(arguments) < 2 or (os.cpu_count() or 1) < 2:
        return [work(*a) for a in arguments]
    with _POOL_LOCK:
        if _POOL is None:
            _POOL = ThreadPoolExecutor(max_workers=os.cpu_count(), thread_name_prefix="restframe-build")
    return [future.result() for future in [_POOL.submit(work, *a) for a in arguments]]


def _flat_normals(part: dict) -> np.ndarray:
    tri = part["vertices"][part["triangles"]]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    return np.repeat(n[:, None, :], 3, axis=1)


def _add_segments(frames, meshes, scene: Scene, settings: MotionSettings, warnings, groups, build) -> None:
    """An animated assembly: one frame per inertial segment of its pivot's world line (none once
    ``build``, parts -> Geometry, returns None: cancelled)."""
    trajectory = meshes[0].trajectory
    pivot = np.asarray(meshes[0].pivot, dtype=np.float64)
    parts = [p for p in (_mesh_part(m, Boost.identity(), warnings, relative_to=pivot) for m in meshes) if p is not None]
    if not parts:
        return
    geometry = build(parts)
    if geometry is None:  # cancelled
        return
    if geometry.radius > trajectory.body_radius:  # built for a smaller body: round the corners for this one
        trajectory = replace(trajectory, body_radius=geometry.radius, warnings=[])
    warnings.extend(trajectory.warnings)
    name = meshes[0].name
    segments = motion.segment_world_line(trajectory, trajectory.tau[0], trajectory.tau[-1], settings.tolerance, name)
    mids = np.array([seg.mid for seg in segments])
    proper = trajectory.proper_time(mids)
    first = len(frames)
    starts, ends = [], []
    # the cuts between neighbouring segments; before the first and after the last segment the
    # motion continues inertially
    cuts = np.array([seg.end for seg in segments[:-1]])
    cut_position, cut_beta = trajectory.state(cuts)
    slack = [a.error + b.error for a, b in zip(segments[:-1], segments[1:])]
    for i, seg in enumerate(segments):
        boost = Boost.from_velocity(tuple(seg.beta), name=name)
        t_mid, x_mid = boost.events(np.array(seg.mid), seg.position)
        t_mid = float(t_mid)
        start = -np.inf if i == 0 else seg.start
        end = np.inf if i == len(segments) - 1 else seg.end
        window = Window(*(_slice(boost, cuts[j], cut_position[j], cut_beta[j], slack[j])
                          if 0 <= j < len(cuts) else None for j in (i - 1, i)))
        frames.append(RestFrame(index=len(frames), velocity=Velocity(tuple(seg.beta)), boost=boost, names=[name],
                                geometry=geometry, offset=x_mid, window=window, clock_offset=float(proper[i]) - t_mid,
                                tolerance=settings.tolerance))
        starts.append(start)
        ends.append(end)
    speed = np.linalg.norm(trajectory.beta, axis=1).max()
    gamma_max = 1.0 / math.sqrt((1.0 - speed) * (1.0 + speed))
    # the overlaps at the cuts reach past the segments' pivot times by up to gamma * slack
    groups.append(SegmentGroup(trajectory, np.arange(first, len(frames)), np.array(starts), np.array(ends),
                               reach=(gamma_max + 1.0) * trajectory.body_radius + settings.tolerance
                               + 2.0 * gamma_max * max(slack, default=0.0)))


def _slice(boost: Boost, tau, position, beta, slack: float) -> Slice:
    """The body's slice through its pivot event (tau, position) of velocity beta (in S), in the
    coordinates of the frame of ``boost``."""
    t, x = boost.events(np.array(tau), position)
    gamma = 1.0 / math.sqrt(1.0 - float(beta @ beta))
    u0, u = boost.events(np.array(gamma), gamma * beta)  # the pivot's 4-velocity
    return Slice(float(t), x, u / u0, slack)


def _add_rotation(frames, mesh, scene: Scene, settings: MotionSettings, warnings, build) -> None:
    """A body spinning at constant angular velocity about its pivot, in its (inertial) axis frame
    (none once ``build``, parts -> Geometry, returns None: cancelled).

    It shows its Blender pose at its own clock's zero; the tracer poses it per ray.
    """
    boost = Boost.from_velocity(mesh.velocity.beta, mesh.velocity.lorentz_factor, name=mesh.name)
    pivot = np.asarray(mesh.pivot, dtype=np.float64)
    part = _mesh_part(mesh, boost, warnings, relative_to=pivot)
    if part is None:
        return
    geometry = build([part])
    if geometry is None:  # cancelled
        return
    omega = np.asarray(mesh.angular_velocity, dtype=np.float64) / scene.light_speed  # rad per unit c*t
    validation.check_angular_velocity(mesh.angular_velocity, mesh.name)
    # a body point moves at |omega x r|: its distance from the axis counts, not from the pivot
    used = geometry.vertices[np.unique(geometry.triangles)]
    validation.check_rim_speed(float(np.max(np.linalg.norm(np.cross(omega, used), axis=1))), mesh.name)
    t0 = clock_shift(boost, pivot)
    frames.append(RestFrame(index=len(frames), velocity=mesh.velocity, boost=boost, names=[mesh.name],
                            geometry=geometry, offset=pivot + shift_into_frame(boost, pivot),
                            clock_offset=-t0, spin=omega, tolerance=settings.tolerance))

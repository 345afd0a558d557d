"""Rest frames: one per distinct velocity, each with its static geometry in one embreex scene.

Every frame shares the origin event ``(tau = 0, x = 0)`` of the world frame S and
has axes parallel to S (``shared/physics.md``).  An object whose assembly pivot
is ``p`` sits in its frame at ``boost(0, p)`` plus its Blender shape relative to
``p``; the spatial part of that is ``p + (gamma - 1)(n.p) n``, so the whole body
is translated by ``(gamma - 1)(n.p) n`` (the time part only shifts the static
frame's clock).  At world time 0 its pivot is where the artist put it, and the
body is Lorentz-contracted about it as seen from S.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh

from .lorentz import Boost
from .scene import REST, Scene, Velocity


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
        w = np.ones(np.shape(d)[:-1])
        for boost in self.steps:
            d, step_w = boost.rays(d)
            w = w * step_w
        return d, w


def shift_into_frame(boost: Boost, pivot) -> np.ndarray:
    """Spatial offset that places a body with this pivot into its shared rest frame."""
    if boost.is_identity:
        return np.zeros(3)
    pivot = np.asarray(pivot, dtype=np.float64)
    return boost.gamma_minus_one * float(boost.n @ pivot) * boost.n


@dataclass
class RestFrame:
    """One inertial frame and the triangles at rest in it (possibly none)."""

    index: int
    velocity: Velocity
    boost: Boost
    names: list[str] = field(default_factory=list)
    vertices: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    triangles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), dtype=np.int64))
    tri_material: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int32))
    tri_object_index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int32))
    corner_normals: np.ndarray | None = None
    corner_uvs: np.ndarray | None = None
    lo: np.ndarray | None = None  # float64 bounds of the geometry
    hi: np.ndarray | None = None
    anchor: np.ndarray | None = None  # embree coordinates are relative to this point
    embree: object = None

    @property
    def has_geometry(self) -> bool:
        return self.embree is not None


class FrameSet:
    """All frames of a scene: geometry frames, light frames, the camera's and S."""

    def __init__(self, frames: list[RestFrame], world: int, camera: int, light_frames: list[int], warnings: list[str]):
        self.frames = frames
        self.world = world
        self.camera = camera
        self.light_frames = light_frames
        self.warnings = warnings
        self.geometry = [f.index for f in frames if f.has_geometry]
        self._maps: dict[tuple[int, int], FrameMap] = {}

    def map(self, a: int, b: int) -> FrameMap:
        """The map from frame a's coordinates to frame b's (cached)."""
        key = (a, b)
        cached = self._maps.get(key)
        if cached is None:
            fa, fb = self.frames[a].boost, self.frames[b].boost
            cached = FrameMap([]) if fa.same_as(fb) else FrameMap([fa.inverse(), fb])
            self._maps[key] = cached
        return cached


def build_frames(scene: Scene, should_stop=lambda: False) -> FrameSet:
    """Group the scene by velocity and build one embreex scene per moving or static frame.

    Raises ValueError (naming the object) for invalid velocities.
    """
    frames: list[RestFrame] = []
    by_key: dict[tuple, RestFrame] = {}
    warnings: list[str] = []

    def frame_for(velocity: Velocity, name: str) -> RestFrame:
        boost = Boost.from_velocity(velocity.beta, velocity.lorentz_factor, name=name)
        key = REST.key if boost.is_identity else velocity.key
        frame = by_key.get(key)
        if frame is None:
            frame = RestFrame(index=len(frames), velocity=velocity, boost=boost)
            frames.append(frame)
            by_key[key] = frame
        frame.names.append(name)
        return frame

    world = frame_for(REST, "world").index
    camera = frame_for(scene.camera.velocity, scene.camera.name).index
    light_frames = [frame_for(light.velocity, light.name).index for light in scene.lights]

    parts: dict[int, list] = {}
    for mesh in scene.meshes:
        if should_stop():
            break
        frame = frame_for(mesh.velocity, mesh.name)
        part = _mesh_part(mesh, frame.boost, warnings)
        if part is not None:
            parts.setdefault(frame.index, []).append(part)

    for index, frame_parts in parts.items():
        if should_stop():
            break
        _fill_geometry(frames[index], frame_parts)
    return FrameSet(frames, world, camera, light_frames, warnings)


def _mesh_part(mesh, boost: Boost, warnings: list[str]):
    vertices = np.asarray(mesh.vertices, dtype=np.float64).reshape(-1, 3)
    triangles = np.asarray(mesh.triangles, dtype=np.int64).reshape(-1, 3)
    if len(triangles) == 0:
        return None
    valid = np.all((triangles >= 0) & (triangles < len(vertices)), axis=1)
    finite_vertex = np.all(np.isfinite(vertices), axis=1)
    valid[valid] &= np.all(finite_vertex[triangles[valid]], axis=1)
    if not valid.all():
        warnings.append(f"{mesh.name}: skipped {np.count_nonzero(~valid)} triangles with invalid or non-finite vertices")
    keep = np.flatnonzero(valid)
    if len(keep) == 0:
        return None
    materials = (
        np.zeros(len(triangles), dtype=np.int32)
        if mesh.material_indices is None
        else np.asarray(mesh.material_indices, dtype=np.int32)
    )
    return {
        "vertices": vertices + shift_into_frame(boost, mesh.pivot),
        "triangles": triangles[keep],
        "material": materials[keep],
        "object_index": np.full(len(keep), mesh.object_index, dtype=np.int32),
        "normals": None if mesh.corner_normals is None else np.asarray(mesh.corner_normals, np.float64)[keep],
        "uvs": None if mesh.corner_uvs is None else np.asarray(mesh.corner_uvs, np.float64)[keep],
    }


def _fill_geometry(frame: RestFrame, parts: list[dict]) -> None:
    offsets = np.cumsum([0] + [len(p["vertices"]) for p in parts[:-1]])
    frame.vertices = np.concatenate([p["vertices"] for p in parts])
    frame.triangles = np.concatenate([p["triangles"] + o for p, o in zip(parts, offsets)])
    frame.tri_material = np.concatenate([p["material"] for p in parts])
    frame.tri_object_index = np.concatenate([p["object_index"] for p in parts])
    if any(p["normals"] is not None for p in parts):
        frame.corner_normals = np.concatenate([_flat_or(p, "normals", _flat_normals) for p in parts])
    if any(p["uvs"] is not None for p in parts):
        frame.corner_uvs = np.concatenate([_flat_or(p, "uvs", lambda q: np.zeros((len(q["triangles"]), 3, 2))) for p in parts])
    used = frame.vertices[np.unique(frame.triangles)]
    frame.lo, frame.hi = used.min(axis=0), used.max(axis=0)
    frame.anchor = 0.5 * (frame.lo + frame.hi)
    scene = rtcore_scene.EmbreeScene()
    TriangleMesh(scene, (frame.vertices - frame.anchor).astype(np.float32), frame.triangles.astype(np.int32))
    # commit now (embreex commits lazily on the first query, which is not thread-safe)
    scene.run(np.zeros((1, 3), np.float32), np.array([[1, 0, 0]], np.float32))
    frame.embree = scene


def _flat_or(part: dict, key: str, fallback):
    return part[key] if part[key] is not None else fallback(part)


def _flat_normals(part: dict) -> np.ndarray:
    tri = part["vertices"][part["triangles"]]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    return np.repeat(n[:, None, :], 3, axis=1)

"""Motion: velocities, and the world line of a body animated by location keys (Motion = Animation)."""

from __future__ import annotations

import math

import numpy as np

from ..core import validation
from ..core.motion import Trajectory
from ..core.scene import Velocity
from ..motion_query import (SUBFRAMES, has_animated_location, keyed_positions, location_curves,  # noqa: F401 (SUBFRAMES: public here too)
                            parent_matrix)
from .errors import ExportCancelled, ExportError
from .keyed_speed import KeyedCurve, fastest, is_finite, non_finite_key


_SHUTTER_OPENS = {'START': 0.0, 'CENTER': -0.5, 'END': -1.0}  # the frame's place in the shutter, in shutters


def shutter_frames(scene) -> tuple[float, float] | None:
    """The shutter interval in frames from the rendered frame (Blender's Motion Blur panel:
    shutter length and position), or None without motion blur."""
    render = scene.render
    if not render.use_motion_blur or render.motion_blur_shutter <= 0.0:
        return None
    opens = _SHUTTER_OPENS[render.motion_blur_position] * render.motion_blur_shutter
    return opens, opens + render.motion_blur_shutter


def object_velocity(obj) -> Velocity:
    """The object's ``restframe`` velocity, checked: raises ExportError naming the object."""
    rf = obj.restframe
    try:
        return Velocity(*validation.check_velocity(rf.velocity, rf.lorentz_factor, obj.name))
    except ValueError as error:
        raise ExportError(str(error)) from None


MAX_SAMPLES = 20000  # per object: beyond this the samples thin out (long light-travel times)


def body_radius(vertices: np.ndarray, triangles: np.ndarray, pivot) -> float:
    """The largest distance from the pivot of a (finite) vertex of the triangles: the rigid body's
    radius, which sets how widely its world line's corners are rounded."""
    used = np.zeros(len(vertices), dtype=bool)
    used[triangles] = True
    distance = np.linalg.norm(vertices[used] - np.asarray(pivot, dtype=np.float64), axis=1)
    return float(np.max(distance[is_finite(distance)], initial=0.0))


def object_trajectory(root, scene, camera_position, radius: float, *, should_stop=lambda: False,
                      warn=print, smooth: bool = False) -> Trajectory:
    """The assembly pivot's world line from its location keys (Motion = Animation).

    ``radius`` is the assembly's ``body_radius`` about the pivot (every mesh moving with it),
    so the world line is built with its corners rounded for that body; ``smooth`` (a camera or
    a lamp: a point) rounds them as widely as the samples allow (``Trajectory.smooth``).

    Samples ``SUBFRAMES`` per frame, and every key, from before the scene's start frame
    (early enough for light from any sampled position to reach the camera) up to just past
    the rendered frame; the F-curves are evaluated directly, so the scene's current frame
    never changes.  Supported: the object's own location/delta location keys; a parent
    is taken as static at its pose of the rendered frame.  Raises ExportError (naming
    the object and frames) when the keyed curves, differentiated per segment, reach c
    anywhere (``_refuse_light_speed``), ExportCancelled on Esc.
    """
    rf = scene.restframe
    c = rf.light_speed
    fps = scene.render.fps / scene.render.fps_base
    curves, ignored = location_curves(root)
    if not curves:
        warn(f"{root.name}: Motion is Animation but its location has no keyframes: it stays at rest")
    if ignored:
        warn(f"{root.name}: Motion = Animation uses the location keys only ({' and '.join(ignored)} ignored)")
    if root.parent is not None and has_animated_location(root.parent):
        warn(f"{root.name}: its parent '{root.parent.name}' is animated; Motion = Animation takes "
             "the parent as static (pose of the rendered frame)")

    keyed = {key: KeyedCurve.from_fcurve(fc) for key, fc in curves.items()}
    for (path, index), curve in keyed.items():
        frame = non_finite_key(curve)
        if frame is not None:
            raise ExportError(f"{root.name}: the {path}[{index}] key at frame {frame:g} is not a finite number "
                              "(NaN or inf): Motion = Animation cannot follow it")

    def world(frames):
        return keyed_positions(root, curves, frames)

    current = scene.frame_current + scene.frame_subframe
    first = min(float(scene.frame_start), current)
    end = current + 1.0 + max((shutter_frames(scene) or (0.0, 0.0))[1], 0.0)  # past the shutter's closing
    # how far back light can come from: the farthest sampled position, plus the body's radius
    coarse = np.linspace(first, end, int(min(end - first, 2000)) + 2)
    seen = world(coarse)
    if not np.all(is_finite(seen)):
        raise ExportError(validation.non_finite_motion(root.name))
    reach = float(np.linalg.norm(seen - np.asarray(camera_position), axis=1).max()) + radius
    start = first - math.ceil(2.0 * reach / c * fps) - 1.0
    if not math.isfinite(start):
        raise ExportError(validation.non_finite_motion(root.name))
    count = int(min((end - start) * SUBFRAMES, MAX_SAMPLES)) + 1
    keys = np.concatenate([curve.key_frame for curve in keyed.values()] + [np.empty(0)])
    # the keys themselves are samples too: a short burst between two keys is not averaged away
    frames = _samples_with_keys(start, end, count, keys)
    _refuse_light_speed(root.name, keyed, parent_matrix(root), frames, fps / c)
    if should_stop():
        raise ExportCancelled()
    position = world(frames)
    if should_stop():
        raise ExportCancelled()
    tau = c * (frames - rf.reference_frame) / fps
    evaluated = np.asarray(root.matrix_world.translation)
    here = world(np.array([current]))[0]
    if np.linalg.norm(here - evaluated) > max(1e-6 * (1.0 + np.linalg.norm(evaluated)), rf.motion_tolerance):
        warn(f"{root.name}: its location at this frame differs from the keyframed one by "
             f"{np.linalg.norm(here - evaluated):.3g} (constraints, drivers or parents?); "
             "Motion = Animation follows the keys")
    try:
        return Trajectory(tau=tau, position=position, name=root.name, frames=frames, body_radius=radius,
                          smooth=smooth)
    except ValueError as error:
        raise ExportError(str(error)) from error


def _samples_with_keys(start: float, end: float, count: int, keys: np.ndarray) -> np.ndarray:
    """``count`` even samples of [start, end] and every key inside, without the even samples that
    come within a quarter step of a key (a sliver interval would leave a key's corner no room)."""
    grid = np.linspace(start, end, count)
    keys = np.unique(keys[(keys > start) & (keys < end)])
    if len(keys) == 0:
        return grid
    step = (end - start) / max(count - 1, 1)
    nearest = np.clip(np.searchsorted(keys, grid), 1, len(keys)) - 1
    gap = np.minimum(np.abs(grid - keys[nearest]), np.abs(grid - keys[np.minimum(nearest + 1, len(keys) - 1)]))
    keep = gap >= 0.25 * step
    keep[[0, -1]] = True
    return np.union1d(grid[keep], keys)


def _refuse_light_speed(name: str, keyed: dict, parent_matrix: np.ndarray, frames: np.ndarray,
                        to_c: float) -> None:
    """Raise ExportError (naming the object and the frames) where the keyed location, differentiated
    per key segment, reaches the speed of light within ``frames``; a jump is infinitely fast.
    ``to_c`` turns scene units per frame into units of c (fps / c)."""
    lo, hi = frames[0], frames[-1]
    jumps = sorted({f for curve in keyed.values() for f in curve.jumps() if lo <= f <= hi})
    if jumps:
        listed = ", ".join(f"{f:g}" for f in jumps[:5]) + (f" and {len(jumps) - 5} more" if len(jumps) > 5 else "")
        raise ExportError(f"{name}: the keyed location jumps (CONSTANT interpolation or two keys on one frame) "
                          f"at frame {listed}: infinitely fast, not below the speed of light; "
                          "use Linear or Bezier interpolation")
    if not keyed:
        return
    vertical = sorted({f for curve in keyed.values() for f in curve.vertical() if lo <= f <= hi})
    if vertical:
        raise ExportError(f"{name}: the keyed location's Bezier handles make it stand still in time while it moves "
                          f"at frame {', '.join(f'{f:.6g}' for f in vertical[:5])}: infinitely fast, not below the "
                          "speed of light; shorten the handles")
    linear = parent_matrix[:3, :3]

    def velocity(at):  # in units of c
        local = np.zeros((len(at), 3))
        for (_, index), curve in keyed.items():
            local[:, index] += curve.derivative(at)
        return local @ linear.T * to_c

    probes = np.concatenate([frames] + [curve.probe_frames() for curve in keyed.values()])
    probes = np.unique(probes[(probes >= lo) & (probes <= hi)])
    speed, frame = fastest(velocity, probes)
    if speed < 1.0:
        return
    fast = np.linalg.norm(velocity(probes), axis=1) >= 1.0
    edges = np.flatnonzero(np.diff(np.concatenate([[0], fast.astype(np.int8), [0]])))
    spans = [(probes[a], probes[b - 1]) for a, b in zip(edges[::2], edges[1::2])] or [(frame, frame)]
    listed = ", ".join(f"{a:.6g}-{b:.6g}" for a, b in spans[:5]) + (
        f" and {len(spans) - 5} more" if len(spans) > 5 else "")
    raise ExportError(f"{name}: the animation moves at {speed:.6g} c (at frame {frame:.6g}), not below the speed "
                      f"of light, between frames {listed}: slow it down or raise the scene's speed of light")


def point_trajectory(root, scene, camera_position, position, name: str, *, should_stop=lambda: False,
                     warn=print) -> Trajectory:
    """The world line of a point (a camera or a lamp) of an animated assembly (Motion = Animation):
    its root's keyed world line, the point carried along at its offset from the root at the rendered
    frame, laid off in the root's momentary rest frames as for every point of the Born-rigid body
    (``Trajectory.carried``)."""
    trajectory = object_trajectory(root, scene, camera_position, 0.0, should_stop=should_stop, warn=warn,
                                   smooth=True)
    offset = np.asarray(position, dtype=np.float64) - np.asarray(root.matrix_world.translation)
    if not np.any(offset):
        return trajectory
    try:
        return trajectory.carried(offset, name)
    except ValueError:
        raise ExportError(f"{name}: it lies {np.linalg.norm(offset):.6g} from '{root.name}', the pivot of its "
                          "assembly, beyond the horizon of the assembly's acceleration (a rigid body cannot "
                          "reach that far): keep it closer or accelerate more gently") from None

"""What an object's RESTframe motion settings and animation say, read from Blender data.

The UI's panels ask these questions while drawing, and the exporter asks them too;
this module reads the Blender data only (it builds nothing for the core), so the
UI does not import the exporter to answer them.
"""

from __future__ import annotations

import math

import numpy as np

from .core.motion import Trajectory
from .core.observer import proper_time as _proper_time
from .core.scene import Velocity

SUBFRAMES = 8  # world-line samples per frame of animation


def observation_time(scene) -> float:
    """Seconds from the reference time to the rendered frame (``docs/physics.md#units-and-clocks``)."""
    rf = scene.restframe
    return (scene.frame_current + scene.frame_subframe - rf.reference_frame) * scene.render.fps_base / scene.render.fps


def _same_velocity(a, b) -> bool:
    """Same motion settings: such a parent and child move (and spin) as one rigid assembly."""
    ra, rb = a.restframe, b.restframe
    if ra.motion != rb.motion or tuple(ra.angular_velocity) != tuple(rb.angular_velocity):
        return False
    return ra.motion == 'ANIMATION' or (
        tuple(ra.velocity) == tuple(rb.velocity) and ra.lorentz_factor == rb.lorentz_factor)


def assembly_root(obj):
    """The topmost parent reached through parents with the same velocity (``docs/physics.md#rest-shapes``)."""
    root = obj
    while root.parent is not None and _same_velocity(root.parent, root):
        root = root.parent
    return root


def rides_with_parent(obj) -> bool:
    """A camera with no motion of its own (Constant, zero velocity) under a parent rides with the
    parent's assembly, as a cockpit camera rides with its ship (``docs/physics.md#observer``)."""
    rf = obj.restframe
    return obj.type == 'CAMERA' and obj.parent is not None and not rf.is_animated and not rf.is_moving


def motion_source(obj):
    """The object whose motion settings ``obj`` follows: its own, or a riding camera's parent's."""
    return obj.parent if rides_with_parent(obj) else obj


def fcurves(action, slot):
    """The F-curves of an action (for its slot, with layered actions in 4.4+)."""
    if action is None:
        return ()
    if hasattr(action, "layers") and not getattr(action, "is_action_legacy", False):
        from bpy_extras.anim_utils import action_get_channelbag_for_slot
        bag = action_get_channelbag_for_slot(action, slot) if slot is not None else None
        return bag.fcurves if bag is not None else ()
    return action.fcurves


def _action_paths(animation_data) -> set[str]:
    """Data paths animated by the active action, NLA strips and drivers."""
    if animation_data is None:
        return set()
    paths = {driver.data_path for driver in animation_data.drivers}
    actions = [(animation_data.action, getattr(animation_data, "action_slot", None))]
    for track in animation_data.nla_tracks:
        if not track.mute:
            actions += [(strip.action, getattr(strip, "action_slot", None)) for strip in track.strips]
    for action, slot in actions:
        paths.update(fc.data_path for fc in fcurves(action, slot))
    return paths


def has_animated_location(obj) -> bool:
    """True if the object or a parent in its assembly has keyframed/driven location.

    Such an object also has a velocity, so it would jump from frame to frame
    instead of moving smoothly: the UI and the render warn about it.
    """
    node = obj
    while node is not None:
        if {"location", "delta_location"} & _action_paths(node.original.animation_data):
            return True
        node = node.parent if node.parent is not None and _same_velocity(node.parent, node) else None
    return False



def location_curves(obj) -> tuple[dict, list[str]]:
    """{(data_path, index): F-curve} of the object's own location keys, and what is ignored.

    Motion = Animation reads the active action's ``location`` and ``delta_location``
    curves; NLA strips, drivers and constraints on the location are not evaluated.
    """
    anim = obj.original.animation_data
    curves: dict = {}
    ignored: list[str] = []
    if anim is None:
        return curves, ignored
    for fc in fcurves(anim.action, getattr(anim, "action_slot", None)):
        if fc.data_path in {"location", "delta_location"} and not fc.mute:
            curves[(fc.data_path, fc.array_index)] = fc
    if any(d.data_path in {"location", "delta_location"} for d in anim.drivers):
        ignored.append("drivers")
    if any(not track.mute and track.strips for track in anim.nla_tracks):
        ignored.append("NLA strips")
    return curves, ignored


def _local_locations(obj, curves: dict, frames: np.ndarray) -> np.ndarray:
    """location + delta_location (the local matrix's translation) at each frame, (N, 3)."""
    out = np.empty((len(frames), 3))
    base = obj.original
    for i in range(3):
        total = np.zeros(len(frames))
        for path in ("location", "delta_location"):
            fc = curves.get((path, i))
            if fc is None:
                total += float(getattr(base, path)[i])
            else:
                evaluate = fc.evaluate
                total += np.fromiter((evaluate(f) for f in frames), dtype=np.float64, count=len(frames))
        out[:, i] = total
    return out


def parent_matrix(obj) -> np.ndarray:
    """The world matrix of the object's parent space (the parent taken static, at its pose of the
    rendered frame), identity without a parent."""
    if obj.parent is None:
        return np.eye(4)
    return np.array(obj.parent.matrix_world, dtype=np.float64) @ np.array(obj.matrix_parent_inverse, dtype=np.float64)


def keyed_positions(obj, curves: dict, frames: np.ndarray) -> np.ndarray:
    """World positions (N, 3) of the object's keyed location at Blender frames (parent static)."""
    matrix = parent_matrix(obj)
    return _local_locations(obj, curves, frames) @ matrix[:3, :3].T + matrix[:3, 3]


def world_time(scene, frames) -> np.ndarray:
    """World time c*t of Blender frames (0 at the reference frame)."""
    render = scene.render
    return scene.restframe.light_speed * (np.asarray(frames, dtype=np.float64)
                                          - scene.restframe.reference_frame) * render.fps_base / render.fps


def clock(obj, scene) -> tuple[float, tuple[float, float, float]]:
    """The object's own clock at the rendered frame (seconds, 0 at the reference time: its
    proper time since then) and its velocity (units of c) there; NaNs where its motion is not
    below c.  Motion = Animation: along the world line of its keyed location sampled
    ``SUBFRAMES`` per frame, as the renderer samples it (a camera or lamp away from its assembly's
    pivot: its own, carried with the pivot).  A riding camera (``rides_with_parent``) takes its
    parent's motion."""
    source = motion_source(obj)
    rf = source.restframe
    c = scene.restframe.light_speed
    tau = c * observation_time(scene)
    nan = (math.nan, (math.nan,) * 3)
    trajectory = None
    if rf.is_animated:
        root = assembly_root(source)
        curves, _ = location_curves(root)
        if curves:
            current = scene.frame_current + scene.frame_subframe
            lo = math.floor(min(current, scene.restframe.reference_frame)) - 1.0
            hi = math.ceil(max(current, scene.restframe.reference_frame)) + 1.0
            frames = np.linspace(lo, hi, int(round((hi - lo) * SUBFRAMES)) + 1)
            try:
                trajectory = Trajectory(world_time(scene, frames), keyed_positions(root, curves, frames),
                                        name=obj.name, smooth=True)
                offset = np.asarray(obj.matrix_world.translation) - np.asarray(root.matrix_world.translation)
                if obj.type in {'CAMERA', 'LIGHT'} and np.any(offset):  # a point's own clock, as rendered
                    trajectory = trajectory.carried(offset, obj.name)
            except ValueError:
                return nan
        velocity = Velocity()
    else:
        velocity = Velocity(tuple(rf.velocity), rf.lorentz_factor)
    try:
        seconds = _proper_time(tau, velocity, trajectory) / c
    except ValueError:
        return nan
    beta = velocity.beta if trajectory is None else trajectory.state(np.array([tau]))[1][0]
    return seconds, tuple(float(b) for b in beta)

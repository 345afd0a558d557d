"""What an object's RESTframe motion settings and animation say, read from Blender data.

The UI's panels ask these questions while drawing, and the exporter asks them too;
this module reads the Blender data only (it builds nothing for the core), so the
UI does not import the exporter to answer them.
"""

from __future__ import annotations


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


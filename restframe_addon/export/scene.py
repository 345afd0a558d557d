"""Evaluated Blender data -> :mod:`restframe_addon.core.scene` (pure data, nothing modified).

Everything is read from the evaluated depsgraph, so modifiers, geometry nodes,
curves, text, metaballs and (collection) instances arrive as the triangles
Blender itself would render.  Mesh data moves through ``foreach_get`` into numpy;
a mesh instanced many times is read once and only transformed per instance.
The user's data is never written: no ``to_mesh`` copies, no edits, no saves.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from ..core.motion import Trajectory
from ..core.scene import Light, Mesh, RenderSettings, Scene, Velocity
from ..motion_query import assembly_root, has_animated_location, observation_time
from .camera import export_camera
from .errors import ExportCancelled, ExportError
from .features import FeatureReport, object_features, uses_stereo
from .lights import export_light, world_color
from .materials import MaterialExporter
from .meshes import MeshData, place, read_mesh
from .motion import object_trajectory, object_velocity
from .settings import render_settings


def _instance_source(inst):
    """The object whose velocity an instance takes, and where its assembly pivot is.

    An instance moves with its instancer (collection instance empty, particle
    emitter, the curve/text object of its own evaluated geometry) when that has
    a velocity; otherwise with the instanced object's own velocity, pivoting at
    the instance's origin.
    """
    parent = inst.parent
    if inst.is_instance and parent is not None and (parent.restframe.is_moving or parent.restframe.is_animated
                                                    or any(parent.restframe.angular_velocity)):
        return parent, tuple(assembly_root(parent).matrix_world.translation)
    obj = inst.object
    if inst.is_instance:
        return obj, tuple(inst.matrix_world.translation)
    return obj, tuple(assembly_root(obj).matrix_world.translation)


def export_scene(depsgraph, camera_object=None, *, resolution=None,
                 should_stop: Callable[[], bool] = lambda: False,
                 warn: Callable[[str], None] = print) -> tuple[Scene, RenderSettings]:
    """Build the core Scene and RenderSettings for the depsgraph's frame.

    Raises ExportError for scenes that cannot be rendered and ExportCancelled as
    soon as ``should_stop()`` is true (checked between objects).
    """
    scene = depsgraph.scene_eval
    rf = scene.restframe
    if not (math.isfinite(rf.light_speed) and rf.light_speed > 0.0):
        raise ExportError(f"the speed of light must be positive (got {rf.light_speed:g})")
    warned: set[str] = set()

    def warn_once(message: str) -> None:
        if message not in warned:
            warned.add(message)
            warn(message)

    if camera_object is None:
        camera_object = scene.camera
    if camera_object is not None:
        camera_object = camera_object.evaluated_get(depsgraph)
    camera = export_camera(camera_object, scene)
    materials = MaterialExporter(warn_once, scene)
    meshes: list[Mesh] = []
    lights: list[Light] = []
    cache: dict[tuple, MeshData | None] = {}
    trajectories: dict[int, Trajectory] = {}  # assembly root -> its world line, shared by its meshes
    jumping: set[str] = set()
    camera_position = tuple(camera_object.matrix_world.translation)
    unsupported = FeatureReport()
    features_seen: set[int] = set()  # original objects already asked (instances share theirs)
    view_layer = depsgraph.view_layer
    if uses_stereo(scene):
        unsupported.add(f"View layer '{view_layer.name}'", ["stereo"])

    for inst in depsgraph.object_instances:
        if should_stop():
            raise ExportCancelled()
        obj = inst.object
        if obj.type in {'MESH', 'CURVES', 'VOLUME'} and obj.original.as_pointer() not in features_seen:
            features_seen.add(obj.original.as_pointer())
            unsupported.add(obj.name, object_features(obj, view_layer))
        if obj.type not in {'MESH', 'LIGHT'} or not inst.show_self:
            continue
        source, pivot = _instance_source(inst)
        animated = source.restframe.is_animated
        # an animated body's velocity comes from its world line (lights keep theirs)
        velocity = Velocity() if animated and obj.type == 'MESH' else object_velocity(source)
        spin = tuple(float(w) for w in source.restframe.angular_velocity)
        if not animated and not velocity.is_zero and has_animated_location(source):
            jumping.add(source.name)
        matrix = np.array(inst.matrix_world, dtype=np.float64)
        name = f"{inst.parent.name}/{obj.name}" if inst.is_instance and inst.parent is not None else obj.name
        if obj.type == 'LIGHT':
            if animated or any(spin):
                warn_once(f"{source.name}: lights move only at a constant velocity "
                          "(Motion = Animation and Angular Velocity are ignored)")
            lights.append(export_light(obj, matrix, velocity, pivot, warn_once))
            continue
        trajectory = None
        if animated:
            if any(spin):
                warn_once(f"{source.name}: Angular Velocity is ignored with Motion = Animation")
            root = assembly_root(source)
            key = root.original.as_pointer()
            if key not in trajectories:
                trajectories[key] = object_trajectory(root, scene, camera_position,
                                                      should_stop=should_stop, warn=warn_once)
            trajectory = trajectories[key]
        elif any(spin) and not all(math.isfinite(w) for w in spin):
            raise ExportError(f"{source.name}: the angular velocity {spin} is not a finite number")
        mesh = obj.data
        key = (mesh.as_pointer(), tuple(slot.material.as_pointer() if slot.material else 0
                                        for slot in obj.material_slots))
        if key not in cache:
            cache[key] = read_mesh(obj, mesh, materials, should_stop)
        data = cache[key]
        if data is None:
            continue
        if should_stop():
            raise ExportCancelled()
        vertices, normals = place(data, matrix)
        meshes.append(Mesh(
            name=name,
            vertices=vertices,
            triangles=data.triangles,
            velocity=velocity,
            pivot=pivot,
            material_indices=data.materials,
            corner_normals=normals,
            corner_uvs=data.uvs,
            object_index=int(obj.pass_index),
            trajectory=trajectory,
            angular_velocity=spin if any(spin) and trajectory is None else None,
        ))

    for message in unsupported.warnings():
        warn_once(message)
    for name in sorted(jumping):
        warn_once(f"{name}: has a velocity and a keyframed location, so it jumps between frames "
                  "(set its Motion to Animation to follow the keyframed path)")
    out = Scene(
        camera=camera,
        meshes=meshes,
        materials=materials.materials,
        lights=lights,
        world_color=world_color(scene, warn_once),
        tau_obs=rf.light_speed * observation_time(scene),
        light_speed=rf.light_speed,
    )
    return out, render_settings(scene, resolution, depsgraph.view_layer)

"""Evaluated Blender data -> :mod:`restframe_addon.core.scene` (pure data, nothing modified).

Everything is read from the evaluated depsgraph, so modifiers, geometry nodes,
curves, text, metaballs and (collection) instances arrive as the triangles
Blender itself would render.  Mesh data moves through ``foreach_get`` into numpy;
a mesh instanced many times is read once and only transformed per instance.
The user's data is never written: no ``to_mesh`` copies, no edits, no saves.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from ..core import validation
from ..core.scene import (RAY_ALL, RAY_CAMERA, RAY_DIFFUSE, RAY_GLOSSY, RAY_SHADOW, RAY_TRANSMISSION, Light, Mesh,
                          RenderSettings, Scene, Velocity)
from ..motion_query import assembly_root, has_animated_location, observation_time
from .camera import export_camera, render_views
from .errors import ExportCancelled, ExportError
from .features import FeatureReport, lamp_features, object_features
from .lights import export_light, world_color, world_texture
from .materials import MaterialExporter
from .meshes import MeshData, place, read_mesh
from .motion import body_radius, object_trajectory, object_velocity, point_trajectory
from .settings import render_settings


_NO_LEVEL = 2**31 - 1  # how Blender pads an instance's persistent id beyond its nesting depth


def _moves(obj) -> bool:
    rf = obj.restframe
    return rf.is_moving or rf.is_animated or any(rf.angular_velocity)


def _instancer_key(inst, levels_up: int = 0):
    """Identifies an instance among the instances of its top-level instancer: its persistent id
    (innermost level first), or that of the instancer ``levels_up`` levels above it."""
    pid = tuple(inst.persistent_id)[levels_up:]
    return (inst.parent.original.as_pointer() if inst.parent is not None else 0,
            pid + (_NO_LEVEL,) * levels_up)


def _instance_source(inst, moving_instancers: dict):
    """The object whose velocity an instance takes, and where its assembly pivot is.

    The innermost motion counts, as for parents (docs/physics.md#rest-shapes: a child with its own velocity is
    its own assembly, moving with that velocity in S): an instanced object's own velocity, else
    that of the nearest instancer with one (a collection instance inside an instanced collection,
    from ``moving_instancers``), else the top-level instancer's (collection instance empty,
    particle emitter).  An object's own evaluated geometry listed as its instances (geometry-nodes
    instances of geometry, a curve's or text's mesh) is the object itself, in its assembly.
    Velocities do not add up through the levels: each is measured in S.
    """
    obj = inst.object
    if not inst.is_instance:
        return obj, tuple(assembly_root(obj).matrix_world.translation)
    parent = inst.parent
    if parent is not None and obj.original == parent.original:
        # the instancer's own evaluated geometry (geometry-nodes instances of geometry, a curve's or
        # text's mesh): Blender lists it as a copy of the instancer, which moves as the instancer's assembly
        return parent, tuple(assembly_root(parent).matrix_world.translation)
    if _moves(obj):
        return obj, tuple(inst.matrix_world.translation)
    pid = tuple(inst.persistent_id)
    for level in range(1, len(pid)):
        if pid[level] == _NO_LEVEL:
            break
        found = moving_instancers.get(_instancer_key(inst, level))
        if found is not None:
            return found
    if parent is not None and _moves(parent):
        return parent, tuple(assembly_root(parent).matrix_world.translation)
    return obj, tuple(inst.matrix_world.translation)


_RAY_VISIBILITY = (("visible_camera", RAY_CAMERA), ("visible_diffuse", RAY_DIFFUSE), ("visible_glossy", RAY_GLOSSY),
                   ("visible_transmission", RAY_TRANSMISSION), ("visible_shadow", RAY_SHADOW))


def ray_visibility(inst, view_layer) -> int:
    """The ray types (RAY_* bits) that see an instance, as Cycles decides: the object's Ray
    Visibility, and its instancer's; Indirect Only collections hide it from the camera."""
    visibility = RAY_ALL
    for obj in (inst.object, inst.parent if inst.is_instance else None):
        if obj is not None:
            for name, bit in _RAY_VISIBILITY:
                if not getattr(obj, name):
                    visibility &= ~bit
    source = inst.parent if inst.is_instance and inst.parent is not None else inst.object
    if view_layer is not None and source.original.indirect_only_get(view_layer=view_layer):
        visibility &= ~RAY_CAMERA
    return visibility


def is_holdout(inst, view_layer) -> bool:
    """Object Holdout (of the object or its instancer) or a Holdout collection (Cycles: the instancer's)."""
    source = inst.parent if inst.is_instance and inst.parent is not None else inst.object
    if inst.object.original.is_holdout or source.original.is_holdout:
        return True
    return view_layer is not None and source.original.holdout_get(view_layer=view_layer)


def export_scene(depsgraph, camera_object=None, *, resolution=None,
                 should_stop: Callable[[], bool] = lambda: False,
                 warn: Callable[[str], None] = print) -> tuple[Scene, RenderSettings]:
    """Build the core Scene and RenderSettings for the depsgraph's frame.

    Raises ExportError for scenes that cannot be rendered and ExportCancelled as
    soon as ``should_stop()`` is true (checked between objects).
    """
    scene = depsgraph.scene_eval
    rf = scene.restframe
    try:
        validation.check_light_speed(rf.light_speed)
    except ValueError as error:
        raise ExportError(str(error)) from None
    warned: set[str] = set()

    def warn_once(message: str) -> None:
        if message not in warned:
            warned.add(message)
            warn(message)

    if camera_object is None:
        camera_object = scene.camera
    if camera_object is not None:
        camera_object = camera_object.evaluated_get(depsgraph)
    camera = export_camera(camera_object, scene, warn_once)
    if render_views(scene) and camera.kind == 'PANO':
        warn_once(f"{camera_object.name}: a panoramic camera's stereo views are rendered as two panoramas from the "
                  "eyes' positions (spherical stereo, the eyes turning with the view direction, is not supported)")
    bodies: list[tuple[int | None, dict]] = []  # (assembly key of an animated body, Mesh fields) per mesh
    lights: list[Light] = []
    cache: dict[tuple, MeshData | None] = {}
    roots: dict[int, object] = {}  # animated assembly key -> its root, whose keys give the world line
    radii: dict[int, float] = {}  # animated assembly key -> body_radius over all its meshes
    jumping: set[str] = set()
    camera_position = tuple(camera_object.matrix_world.translation)
    unsupported = FeatureReport()
    materials = MaterialExporter(warn_once, scene, unsupported=unsupported)
    features_seen: set[int] = set()  # original objects already asked (instances share theirs)
    # instanced instancers with a velocity -> (object, pivot); Blender lists them before their instances
    moving_instancers: dict = {}
    view_layer = depsgraph.view_layer

    for inst in depsgraph.object_instances:
        if should_stop():
            raise ExportCancelled()
        obj = inst.object
        if obj.type in {'MESH', 'CURVES', 'VOLUME'} and obj.original.as_pointer() not in features_seen:
            features_seen.add(obj.original.as_pointer())
            unsupported.add(obj.name, object_features(obj))
        if inst.is_instance and (obj.instance_type != 'NONE' or len(obj.particle_systems)) and _moves(obj):
            if obj.restframe.is_animated:
                warn_once(f"{obj.name}: Motion = Animation of an instancer inside an instanced collection is "
                          "not supported: its instances move with the instancers around it")
            else:
                # the original: Blender reuses one temporary object for every instance it lists
                moving_instancers[_instancer_key(inst)] = (obj.original, tuple(inst.matrix_world.translation))
        if obj.type not in {'MESH', 'LIGHT'} or not inst.show_self:
            continue
        source, pivot = _instance_source(inst, moving_instancers)
        animated = source.restframe.is_animated
        # an animated body's or lamp's velocity comes from its world line
        velocity = Velocity() if animated else object_velocity(source)
        spin = tuple(float(w) for w in source.restframe.angular_velocity)
        if not animated and not velocity.is_zero and has_animated_location(source):
            jumping.add(source.name)
        matrix = np.array(inst.matrix_world, dtype=np.float64)
        name = f"{inst.parent.name}/{obj.name}" if inst.is_instance and inst.parent is not None else obj.name
        if obj.type == 'LIGHT':
            if any(spin):
                warn_once(f"{source.name}: lamps do not spin (Angular Velocity is ignored)")
            trajectory = None
            if animated and obj.data.type == 'SUN':
                warn_once(f"{source.name}: a sun lamp is infinitely far and has no world line "
                          "(Motion = Animation is ignored: it stays at rest)")
            elif animated:  # the lamp rides on its assembly's keyed world line
                trajectory = point_trajectory(assembly_root(source), scene, camera_position, matrix[:3, 3], name,
                                              should_stop=should_stop, warn=warn_once)
            light = export_light(obj, matrix, velocity, pivot, warn_once, scene=scene, trajectory=trajectory)
            light.visibility = ray_visibility(inst, view_layer)  # which rays see a lamp with an extent
            unsupported.add(name, lamp_features(obj, light))
            lights.append(light)
            continue
        body = None
        if animated:
            if any(spin):
                warn_once(f"{source.name}: Angular Velocity is ignored with Motion = Animation")
            root = assembly_root(source)
            body = root.original.as_pointer()
            roots.setdefault(body, root)
        elif any(spin):
            try:
                validation.check_angular_velocity(spin, source.name)
            except ValueError as error:
                raise ExportError(str(error)) from None
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
        if body is not None:
            radii[body] = max(radii.get(body, 0.0), body_radius(vertices, data.triangles, pivot))
        bodies.append((body, dict(
            name=name,
            vertices=vertices,
            triangles=data.triangles,
            velocity=velocity,
            pivot=pivot,
            material_indices=data.materials,
            corner_normals=normals,
            corner_uvs=data.uvs,
            object_index=int(obj.pass_index),
            angular_velocity=spin if any(spin) and body is None else None,
            visibility=ray_visibility(inst, view_layer),
            holdout=is_holdout(inst, view_layer),
        )))

    # each world line is built once its whole body is known, so its corners are rounded for that body
    trajectories = {body: object_trajectory(root, scene, camera_position, radii.get(body, 0.0),
                                            should_stop=should_stop, warn=warn_once)
                    for body, root in roots.items()}
    meshes = [Mesh(**fields, trajectory=trajectories.get(body)) for body, fields in bodies]
    for message in unsupported.warnings():
        warn_once(message)
    for name in sorted(jumping):
        warn_once(f"{name}: has a velocity and a keyframed location, so it jumps between frames "
                  "(set its Motion to Animation to follow the keyframed path)")
    environment = world_texture(scene, warn_once)
    if environment is not None and rf.integrator == 'DIRECT':
        warn_once(f"World '{environment.name}': Direct Light shows the plain Background colour behind the scene; "
                  "the Environment Texture lights it with Path Tracing")
    out = Scene(
        camera=camera,
        meshes=meshes,
        materials=materials.materials,
        lights=lights,
        world_color=world_color(scene, warn_once),
        world_texture=environment,
        tau_obs=rf.light_speed * observation_time(scene),
        light_speed=rf.light_speed,
    )
    return out, render_settings(scene, resolution, depsgraph.view_layer)

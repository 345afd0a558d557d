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

import bpy
import numpy as np

from .core.motion import Trajectory
from .core.render import PASSES
from .core.scene import Camera, Light, Material, Mesh, RenderSettings, Scene, Velocity
from .properties import speed_of


class ExportError(ValueError):
    """The Blender scene cannot be rendered as it is; the message names what to fix."""


class ExportCancelled(Exception):
    """The user pressed Esc (``should_stop`` became true) during export."""


# --------------------------------------------------------------------------- clock and motion
def observation_time(scene) -> float:
    """Seconds from the reference time to the rendered frame (``docs/physics.md#units-and-clocks``)."""
    rf = scene.restframe
    return (scene.frame_current + scene.frame_subframe - rf.reference_frame) * scene.render.fps_base / scene.render.fps


def object_velocity(obj) -> Velocity:
    """The object's ``restframe`` velocity, checked: raises ExportError naming the object."""
    rf = obj.restframe
    beta = tuple(float(c) for c in rf.velocity)
    gamma = float(rf.lorentz_factor)
    if not all(math.isfinite(c) for c in beta):
        raise ExportError(f"{obj.name}: the velocity {beta} is not a finite number")
    if not math.isfinite(gamma):
        raise ExportError(f"{obj.name}: the Lorentz factor {gamma} is not a finite number")
    if gamma > 0.0:
        if gamma < 1.0:
            raise ExportError(f"{obj.name}: a Lorentz factor must be at least 1 (got {gamma:g}); 0 means unused")
        if gamma > 1.0 and not any(beta):
            raise ExportError(f"{obj.name}: a Lorentz factor above 1 needs a velocity to give the direction")
    elif not speed_of(beta, 0.0)[0] < 1.0:
        speed = math.sqrt(sum(c * c for c in beta))
        raise ExportError(
            f"{obj.name}: speed {speed:.7g} c is not below the speed of light; "
            "use the Lorentz factor for speeds very close to c")
    return Velocity(beta, gamma)


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


def _fcurves(action, slot):
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
        paths.update(fc.data_path for fc in _fcurves(action, slot))
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


# --------------------------------------------------------------------------- animated motion
SUBFRAMES = 8  # world-line samples per frame of animation
MAX_SAMPLES = 20000  # per object: beyond this the samples thin out (long light-travel times)


def _location_curves(obj) -> tuple[dict, list[str]]:
    """{(data_path, index): F-curve} of the object's own location keys, and what is ignored.

    Motion = Animation reads the active action's ``location`` and ``delta_location``
    curves; NLA strips, drivers and constraints on the location are not evaluated.
    """
    anim = obj.original.animation_data
    curves: dict = {}
    ignored: list[str] = []
    if anim is None:
        return curves, ignored
    for fc in _fcurves(anim.action, getattr(anim, "action_slot", None)):
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


def object_trajectory(root, scene, camera_position, *, should_stop=lambda: False, warn=print) -> Trajectory:
    """The assembly pivot's world line from its location keys (Motion = Animation).

    Samples ``SUBFRAMES`` per frame from before the scene's start frame (early enough
    for light from any sampled position to reach the camera) up to just past the
    rendered frame; the F-curves are evaluated directly, so the scene's current frame
    never changes.  Supported: the object's own location/delta location keys; a parent
    is taken as static at its pose of the rendered frame.  Raises ExportError (naming
    the object and frames) when the motion reaches c, ExportCancelled on Esc.
    """
    rf = scene.restframe
    c = rf.light_speed
    fps = scene.render.fps / scene.render.fps_base
    curves, ignored = _location_curves(root)
    if not curves:
        warn(f"{root.name}: Motion is Animation but its location has no keyframes: it stays at rest")
    if ignored:
        warn(f"{root.name}: Motion = Animation uses the location keys only ({' and '.join(ignored)} ignored)")
    parent_matrix = np.eye(4)
    if root.parent is not None:
        parent_matrix = _matrix(root.parent.matrix_world) @ _matrix(root.matrix_parent_inverse)
        if has_animated_location(root.parent):
            warn(f"{root.name}: its parent '{root.parent.name}' is animated; Motion = Animation takes "
                 "the parent as static (pose of the rendered frame)")

    def world(frames):
        local = _local_locations(root, curves, frames)
        return local @ parent_matrix[:3, :3].T + parent_matrix[:3, 3]

    current = scene.frame_current + scene.frame_subframe
    first = min(float(scene.frame_start), current)
    end = current + 1.0
    # how far back light can come from: the farthest sampled position, plus the body's size
    coarse = np.linspace(first, end, int(min(end - first, 2000)) + 2)
    size = float(max(root.dimensions)) if hasattr(root, "dimensions") else 0.0
    reach = float(np.linalg.norm(world(coarse) - np.asarray(camera_position), axis=1).max()) + size
    start = first - math.ceil(2.0 * reach / c * fps) - 1.0
    if not math.isfinite(start):
        raise ExportError(f"{root.name}: the animated location is not a finite number")
    count = int(min((end - start) * SUBFRAMES, MAX_SAMPLES)) + 1
    frames = np.linspace(start, end, count)
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
        return Trajectory(tau=tau, position=position, name=root.name, frames=frames)
    except ValueError as error:
        raise ExportError(str(error)) from error


# --------------------------------------------------------------------------- materials
def _linear_from_srgb(c: np.ndarray) -> np.ndarray:
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _upstream(socket):
    """The node feeding a socket, through reroutes; None if unlinked."""
    while socket is not None and socket.is_linked:
        link = socket.links[0]
        if not link.is_valid or link.is_muted:
            return None
        node = link.from_node
        if node.type != 'REROUTE':
            return node
        socket = node.inputs[0]
    return None


def _output_node(id_data):
    """The active output node a path tracer uses, or None when nodes are off or missing."""
    tree = id_data.node_tree
    # use_nodes is always on from 5.0 (and deprecated there)
    if tree is None or (bpy.app.version < (5, 0, 0) and not id_data.use_nodes):
        return None
    return tree.get_output_node('CYCLES')


class MaterialExporter:
    """Principled BSDF (and a few simple shaders) -> core Materials, each read once."""

    def __init__(self, warn: Callable[[str], None], scene=None):
        self.warn = warn
        self.scene = scene
        self.materials: list[Material] = [Material(name="Default")]
        self._index: dict[int, int] = {}

    def index_of(self, material) -> int:
        if material is None:
            return 0
        key = material.original.as_pointer()
        index = self._index.get(key)
        if index is None:
            index = len(self.materials)
            self.materials.append(self._convert(material))
            self._index[key] = index
        return index

    def _convert(self, mat) -> Material:
        out = Material(name=mat.name)
        output = _output_node(mat)
        node = _upstream(output.inputs["Surface"]) if output is not None else None
        if node is None:
            out.base_color = tuple(mat.diffuse_color[:3])
            out.metallic, out.roughness = float(mat.metallic), float(mat.roughness)
            if output is not None:  # a node tree with nothing on Surface renders black in Blender
                out.base_color = (0.0, 0.0, 0.0)
            return out
        if node.type == 'BSDF_PRINCIPLED':
            self._principled(mat, node, out)
        elif node.type == 'EMISSION':
            out.base_color = (0.0, 0.0, 0.0)
            out.emission = self._emission(mat, node.inputs["Color"], node.inputs["Strength"], out)
        elif node.type == 'BSDF_DIFFUSE':
            out.base_color = self._color(mat, node.inputs["Color"])
            out.roughness = 1.0
        else:
            self.warn(f"Material '{mat.name}': shader '{node.bl_label}' is not supported, "
                      "using its viewport display colour (use a Principled BSDF)")
            out.base_color = tuple(mat.diffuse_color[:3])
            out.metallic, out.roughness = float(mat.metallic), float(mat.roughness)
        return out

    def _principled(self, mat, node, out: Material) -> None:
        inputs = node.inputs
        base = inputs["Base Color"]
        texture_node = _upstream(base)
        if texture_node is not None and texture_node.type == 'TEX_IMAGE':
            out.base_color_texture = self._image(mat, texture_node)
            out.base_color = tuple(base.default_value[:3])
        else:
            out.base_color = self._color(mat, base)
        out.metallic = self._value(mat, inputs["Metallic"])
        out.roughness = self._value(mat, inputs["Roughness"])
        out.ior = self._value(mat, inputs["IOR"])
        out.specular_ior_level = self._value(mat, inputs["Specular IOR Level"])
        out.transmission = self._value(mat, inputs["Transmission Weight"])
        out.emission = self._emission(mat, inputs["Emission Color"], inputs["Emission Strength"], out)

    def _emission(self, mat, color, strength, out: Material):
        """Emission colour * strength; a keyframed strength becomes an optical-clock curve."""
        curve = self._emission_curve(mat, strength)
        scale = 1.0 if curve is not None else self._value(mat, strength)
        out.emission_curve = curve
        return tuple(float(v) for v in np.asarray(self._color(mat, color)) * scale)

    def _emission_curve(self, mat, strength):
        """(seconds of the emitter's own clock, strengths) from the strength's F-curve, or None.

        The camera sees an emitter's animation at the emitter's clock reading of each seen
        event (docs/physics.md#optical-clocks): Blender frame f is clock time
        (f - reference_frame) * fps_base / fps.  Sampled over the keys and the scene's frame
        range, twice widened; beyond that the first and last values hold.
        """
        tree = getattr(mat.original, "node_tree", None)
        animation = getattr(tree, "animation_data", None) if tree is not None else None
        if self.scene is None or animation is None:
            return None
        path = strength.path_from_id("default_value")
        curve = next((fc for fc in _fcurves(animation.action, getattr(animation, "action_slot", None))
                      if fc.data_path == path), None)
        if curve is None or len(curve.keyframe_points) == 0:
            return None
        scene = self.scene
        keys = [k.co[0] for k in curve.keyframe_points]
        lo, hi = min(min(keys), scene.frame_start), max(max(keys), scene.frame_end)
        span = hi - lo + 1.0
        frames = np.linspace(lo - 2 * span, hi + 2 * span, int(min(5 * span * SUBFRAMES, MAX_SAMPLES)) + 1)
        values = np.array([curve.evaluate(float(f)) for f in frames])
        seconds = (frames - scene.restframe.reference_frame) * scene.render.fps_base / scene.render.fps
        return seconds, values

    def _unsupported_link(self, mat, socket) -> None:
        self.warn(f"Material '{mat.name}': the link into '{socket.name}' is not supported, using its value")

    def _color(self, mat, socket):
        if _upstream(socket) is not None:
            self._unsupported_link(mat, socket)
        return tuple(float(v) for v in socket.default_value[:3])

    def _value(self, mat, socket) -> float:
        if _upstream(socket) is not None:
            self._unsupported_link(mat, socket)
        return float(socket.default_value)

    def _image(self, mat, node) -> np.ndarray | None:
        """The image's pixels as scene-linear RGB (H, W, 3), row 0 = bottom; None if missing."""
        image = node.image
        if image is None:
            self.warn(f"Material '{mat.name}': the image texture node has no image")
            return None
        width, height = image.size
        channels = image.channels
        if width == 0 or height == 0 or not image.has_data:
            self.warn(f"Image '{image.name}' (material '{mat.name}') could not be loaded: "
                      f"'{image.filepath}' is missing; using the base colour")
            return None
        pixels = np.empty(width * height * channels, dtype=np.float32)
        image.pixels.foreach_get(pixels)
        pixels = pixels.reshape(height, width, channels)
        rgb = pixels[..., :3] if channels >= 3 else np.repeat(pixels[..., :1], 3, axis=2)
        space = image.colorspace_settings.name
        if not image.is_float and space not in {"Non-Color", "Linear Rec.709", "Linear", "Raw"}:
            if "sRGB" not in space:
                self.warn(f"Image '{image.name}': colour space '{space}' is read as sRGB")
            rgb = _linear_from_srgb(rgb)
        return np.ascontiguousarray(rgb, dtype=np.float32)


# --------------------------------------------------------------------------- meshes
class _MeshData:
    """One evaluated mesh in its object space, ready to be placed per instance."""

    __slots__ = ("vertices", "triangles", "materials", "normals", "uvs")

    def __init__(self, vertices, triangles, materials, normals, uvs):
        self.vertices, self.triangles, self.materials = vertices, triangles, materials
        self.normals, self.uvs = normals, uvs


def _read_mesh(obj, mesh, materials: MaterialExporter, should_stop=lambda: False) -> _MeshData | None:
    """Vertices, loop triangles, global material indices, corner normals and UVs.

    ``should_stop`` is checked between the bulk reads (a million triangles take seconds).
    """

    def check():
        if should_stop():
            raise ExportCancelled()

    tris = mesh.loop_triangles
    n_tri, n_vert = len(tris), len(mesh.vertices)
    if n_tri == 0 or n_vert == 0:
        return None
    check()
    vertices = np.empty(n_vert * 3, dtype=np.float32)
    mesh.vertices.foreach_get("co", vertices)
    check()
    triangles = np.empty(n_tri * 3, dtype=np.int32)
    tris.foreach_get("vertices", triangles)
    check()
    slot_of_tri = np.empty(n_tri, dtype=np.int32)
    tris.foreach_get("material_index", slot_of_tri)

    slots = [slot.material for slot in obj.material_slots] or [None]
    lookup = np.array([materials.index_of(m) for m in slots], dtype=np.int32)
    global_materials = lookup[np.clip(slot_of_tri, 0, len(lookup) - 1)]

    corners = None
    normals = None
    check()
    if mesh.normals_domain != 'FACE':  # flat meshes: the tracer's geometric normals are exact
        corners = np.empty(n_tri * 3, dtype=np.int32)
        tris.foreach_get("loops", corners)
        corner_normals = np.empty(len(mesh.loops) * 3, dtype=np.float32)
        check()
        mesh.corner_normals.foreach_get("vector", corner_normals)
        check()
        normals = corner_normals.reshape(-1, 3)[corners].reshape(n_tri, 3, 3).astype(np.float64)

    uvs = None
    layer = next((uv for uv in mesh.uv_layers if uv.active_render), None)
    if layer is not None and any(materials.materials[i].base_color_texture is not None for i in np.unique(lookup)):
        if corners is None:
            corners = np.empty(n_tri * 3, dtype=np.int32)
            tris.foreach_get("loops", corners)
        corner_uvs = np.empty(len(mesh.loops) * 2, dtype=np.float32)
        layer.uv.foreach_get("vector", corner_uvs)
        uvs = corner_uvs.reshape(-1, 2)[corners].reshape(n_tri, 3, 2).astype(np.float64)

    check()
    return _MeshData(vertices.reshape(-1, 3).astype(np.float64), triangles.reshape(-1, 3),
                     global_materials, normals, uvs)


def _place(data: _MeshData, matrix: np.ndarray):
    """World-space vertices and normals for one instance transform."""
    linear, offset = matrix[:3, :3], matrix[:3, 3]
    vertices = data.vertices @ linear.T + offset
    normals = None
    if data.normals is not None:
        # normals transform with the inverse transpose; row vectors: n @ inv(linear)
        normals = data.normals @ np.linalg.inv(linear)
        normals /= np.maximum(np.linalg.norm(normals, axis=2, keepdims=True), 1e-300)
    return vertices, normals


def _matrix(m) -> np.ndarray:
    return np.array(m, dtype=np.float64)


# --------------------------------------------------------------------------- lights, camera, world
def _light(obj, matrix: np.ndarray, velocity: Velocity, pivot) -> Light:
    data = obj.data
    rotation = matrix[:3, :3] / np.linalg.norm(matrix[:3, :3], axis=0)
    light = Light(
        name=obj.name,
        kind=data.type,
        position=tuple(matrix[:3, 3]),
        matrix=rotation,
        color=tuple(float(c) for c in data.color[:3]),
        # a black body (a spectrum the core Doppler-shifts), tinted by the colour
        temperature=float(data.temperature) if getattr(data, "use_temperature", False) else 0.0,
        power=float(data.energy) * 2.0 ** float(getattr(data, "exposure", 0.0)),
        velocity=velocity,
        pivot=pivot,
    )
    if data.type in {'POINT', 'SPOT'}:
        light.radius = float(data.shadow_soft_size)
    if data.type == 'SPOT':
        light.spot_size, light.spot_blend = float(data.spot_size), float(data.spot_blend)
    elif data.type == 'SUN':
        light.sun_angle = float(data.angle)
    elif data.type == 'AREA':
        scale = np.linalg.norm(matrix[:3, :3], axis=0)
        light.area_shape = data.shape
        size_y = data.size_y if data.shape in {'RECTANGLE', 'ELLIPSE'} else data.size
        light.area_size = (float(data.size * scale[0]), float(size_y * scale[1]))
    return light


_PANORAMAS = {"EQUIRECTANGULAR", "FISHEYE_EQUIDISTANT", "FISHEYE_EQUISOLID"}


def _fitted_sensor(cam, aspect: float) -> tuple[float, float]:
    """Sensor (width, height) in mm after Blender's sensor fit for this image aspect."""
    fit = cam.sensor_fit
    if fit == 'AUTO':
        fit = 'HORIZONTAL' if aspect >= 1.0 else 'VERTICAL'
        size = cam.sensor_width
    else:
        size = cam.sensor_width if fit == 'HORIZONTAL' else cam.sensor_height
    return (size, size / aspect) if fit == 'HORIZONTAL' else (size * aspect, size)


def export_camera(camera_object, scene) -> Camera:
    """Blender's camera as the core sees it; ``view_frame`` gives the exact image plane."""
    if camera_object is None:
        raise ExportError("the scene has no camera: add one and set it as the scene camera")
    if camera_object.type != 'CAMERA':
        raise ExportError(f"{camera_object.name}: the scene camera is a {camera_object.type.lower()} object, not a camera")
    cam = camera_object.data
    matrix = _matrix(camera_object.matrix_world)
    matrix[:3, :3] /= np.linalg.norm(matrix[:3, :3], axis=0)
    render = scene.render
    aspect = (render.resolution_x * render.pixel_aspect_x) / (render.resolution_y * render.pixel_aspect_y)
    out = Camera(
        matrix=matrix,
        kind=cam.type,
        frame=np.array([tuple(v) for v in cam.view_frame(scene=scene)], dtype=np.float64),
        clip_start=float(cam.clip_start),
        clip_end=float(cam.clip_end),
        sensor_size=_fitted_sensor(cam, aspect),
        velocity=object_velocity(camera_object),
        name=camera_object.name,
    )
    if cam.type == 'PANO':
        ptype = getattr(cam, "panorama_type", None) or getattr(getattr(cam, "cycles", None), "panorama_type", None)
        if ptype not in _PANORAMAS:
            raise ExportError(f"{camera_object.name}: panorama type {ptype} is not supported "
                              f"(use one of {', '.join(sorted(_PANORAMAS))})")
        out.panorama_type = ptype
        out.latitude_range = (float(cam.latitude_min), float(cam.latitude_max))
        out.longitude_range = (float(cam.longitude_min), float(cam.longitude_max))
        out.fisheye_fov = float(cam.fisheye_fov)
        out.fisheye_lens = float(cam.fisheye_lens)
    return out


def world_color(scene, warn: Callable[[str], None]) -> tuple[float, float, float]:
    """Uniform background radiance: the Background node's colour x strength, or World.color."""
    world = scene.world
    if world is None:
        return (0.0, 0.0, 0.0)
    output = _output_node(world)
    if output is None:
        return tuple(float(c) for c in world.color[:3])
    node = _upstream(output.inputs["Surface"])
    if node is None:
        return (0.0, 0.0, 0.0)
    if node.type != 'BACKGROUND':
        warn(f"World '{world.name}': shader '{node.bl_label}' is not supported, using the world colour")
        return tuple(float(c) for c in world.color[:3])
    color, strength = node.inputs["Color"], node.inputs["Strength"]
    if _upstream(color) is not None or _upstream(strength) is not None:
        warn(f"World '{world.name}': textures on the background are not supported, using its plain colour")
    return tuple(float(c) * float(strength.default_value) for c in color.default_value[:3])


# --------------------------------------------------------------------------- settings
def full_resolution(scene) -> tuple[int, int]:
    render = scene.render
    return (render.resolution_x * render.resolution_percentage // 100,
            render.resolution_y * render.resolution_percentage // 100)


def border_region(scene, resolution) -> tuple[int, int, int, int] | None:
    """Blender's render border in pixels (x1/y1 exclusive), rounded as Blender does."""
    render = scene.render
    if not render.use_border:
        return None
    width, height = resolution
    x0, x1 = int(render.border_min_x * width), int(render.border_max_x * width)
    y0, y1 = int(render.border_min_y * height), int(render.border_max_y * height)
    if x1 <= x0 or y1 <= y0:
        raise ExportError("the render region (border) is empty: draw a larger one or turn it off")
    return (x0, y0, x1, y1)


def core_passes(view_layer) -> tuple[str, ...]:
    """The core passes a render of this view layer fills besides Combined: Blender's where the
    view layer enables them, RESTframe's own always."""
    blender = (("Depth", view_layer.use_pass_z), ("Normal", view_layer.use_pass_normal),
               ("IndexOB", view_layer.use_pass_object_index))
    return tuple(name for name, used in blender if used) + tuple(PASSES)


def render_settings(scene, resolution=None, view_layer=None) -> RenderSettings:
    """The render settings of the scene's RESTframe and Render panels (all passes without a view layer)."""
    rf = scene.restframe
    render = scene.render
    resolution = tuple(resolution) if resolution is not None else full_resolution(scene)
    return RenderSettings(
        resolution=resolution,
        region=border_region(scene, resolution),
        samples=rf.samples,
        max_bounces=rf.max_bounces,
        doppler_mode=rf.doppler_mode,
        searchlight=rf.searchlight,
        spectral_samples=rf.spectral_samples,
        normalize_exposure=rf.normalize_exposure,
        film_transparent=render.film_transparent,
        tile_size=rf.tile_size,
        threads=render.threads if render.threads_mode == 'FIXED' else 0,
        doppler_range=None if rf.doppler_range_auto else tuple(rf.doppler_range),
        doppler_levels=rf.doppler_levels,
        motion_tolerance=rf.motion_tolerance,
        passes=None if view_layer is None else core_passes(view_layer),
    )


# --------------------------------------------------------------------------- the scene
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
    cache: dict[tuple, _MeshData | None] = {}
    trajectories: dict[int, Trajectory] = {}  # assembly root -> its world line, shared by its meshes
    jumping: set[str] = set()
    camera_position = tuple(camera_object.matrix_world.translation)

    for inst in depsgraph.object_instances:
        if should_stop():
            raise ExportCancelled()
        obj = inst.object
        if obj.type not in {'MESH', 'LIGHT'} or not inst.show_self:
            continue
        source, pivot = _instance_source(inst)
        animated = source.restframe.is_animated
        # an animated body's velocity comes from its world line (lights keep theirs)
        velocity = Velocity() if animated and obj.type == 'MESH' else object_velocity(source)
        spin = tuple(float(w) for w in source.restframe.angular_velocity)
        if not animated and not velocity.is_zero and has_animated_location(source):
            jumping.add(source.name)
        matrix = _matrix(inst.matrix_world)
        name = f"{inst.parent.name}/{obj.name}" if inst.is_instance and inst.parent is not None else obj.name
        if obj.type == 'LIGHT':
            if animated or any(spin):
                warn_once(f"{source.name}: lights move only at a constant velocity "
                          "(Motion = Animation and Angular Velocity are ignored)")
            lights.append(_light(obj, matrix, velocity, pivot))
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
            cache[key] = _read_mesh(obj, mesh, materials, should_stop)
        data = cache[key]
        if data is None:
            continue
        if should_stop():
            raise ExportCancelled()
        vertices, normals = _place(data, matrix)
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

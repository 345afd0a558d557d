"""Lights and the world: Blender lamps -> core Lights, the world's background radiance and environment image."""

from __future__ import annotations

from typing import Callable

import numpy as np

from ..core.scene import Light, Velocity, WorldTexture
from ..motion_query import fcurves
from .camera import without_scale
from .images import ImageMissing, image_texture
from .motion import MAX_SAMPLES, SUBFRAMES
from .nodes import output_node, upstream


def node_emission(data, name: str, warn: Callable[[str], None]) -> tuple[np.ndarray, float]:
    """(colour, strength) of the Emission node in a light's node tree, which Cycles multiplies
    into the light's own colour and power; (white, 1) without nodes, black when nothing feeds
    the Light Output."""
    tree = data.node_tree
    if tree is None or not data.use_nodes:
        return np.ones(3), 1.0
    output = tree.get_output_node('CYCLES')
    if output is None:
        return np.ones(3), 1.0
    node = upstream(output.inputs["Surface"])
    if node is None:
        return np.zeros(3), 0.0
    if node.type != 'EMISSION':
        warn(f"Light '{name}': shader '{node.bl_label}' in its node tree is not supported, ignored")
        return np.ones(3), 1.0
    color, strength = node.inputs["Color"], node.inputs["Strength"]
    if upstream(color) is not None or upstream(strength) is not None:
        warn(f"Light '{name}': links into its Emission node are not supported, using their values")
    return np.asarray(color.default_value[:3], dtype=np.float64), float(strength.default_value)


def _area_size_y(data) -> float:
    """An area lamp's second side: Size Y of a rectangle or ellipse, else its one Size."""
    return data.size_y if data.shape in {'RECTANGLE', 'ELLIPSE'} else data.size


def export_light(obj, matrix: np.ndarray, velocity: Velocity, pivot, warn: Callable[[str], None] = print,
                 scene=None, trajectory=None) -> Light:
    """The lamp as the core sees it; with ``scene``, its keyed strength and colour as curves on
    its own clock, and ``trajectory`` its world line (Motion = Animation)."""
    data = obj.data
    unit, scale = without_scale(matrix)
    rotation = unit[:3, :3]
    tint, strength = node_emission(data, obj.name, warn)
    flattened = bool(np.all(np.isfinite(scale)) and np.any(scale == 0.0))
    if flattened:  # as Cycles: a point lamp shines on (its axes do not matter), any other goes dark
        rotation = np.eye(3)
    light = Light(
        name=obj.name,
        kind=data.type,
        position=tuple(matrix[:3, 3]),
        matrix=rotation,
        color=tuple(float(c) for c in np.asarray(data.color[:3], dtype=np.float64) * tint),
        # a black body (a spectrum the core Doppler-shifts), tinted by the colour
        temperature=float(data.temperature) if getattr(data, "use_temperature", False) else 0.0,
        power=float(data.energy) * 2.0 ** float(getattr(data, "exposure", 0.0)) * strength,
        velocity=velocity,
        pivot=pivot,
        trajectory=trajectory,
        # Cycles' Multiple Importance: bounce rays find the lamp, weighed against its samples
        use_mis=bool(getattr(getattr(data, "cycles", None), "use_multiple_importance_sampling", True)),
    )
    if scene is not None:
        light.power_curve, light.color_curve = keyed_output(data, scene, tint, strength)
    if flattened and data.type != 'POINT':
        warn(f"Light '{obj.name}': scaled to zero along an axis, it gives no light")
        light.power, light.power_curve = 0.0, None
    elif data.type == 'AREA' and not (data.size > 0.0 and _area_size_y(data) > 0.0):
        warn(f"Light '{obj.name}': an area lamp of size 0 gives no light (as in Cycles)")
        light.power, light.power_curve = 0.0, None
    if data.type in {'POINT', 'SPOT'}:
        light.radius = float(data.shadow_soft_size)
    if data.type == 'SPOT':
        light.spot_size, light.spot_blend = float(data.spot_size), float(data.spot_blend)
    elif data.type == 'SUN':
        light.sun_angle = float(data.angle)
    elif data.type == 'AREA':
        light.area_shape = data.shape
        light.area_size = (float(data.size * scale[0]), float(_area_size_y(data) * scale[1]))
    return light

def _emission_strength(data):
    """The Strength socket of the Emission node that feeds a light's node tree output (which
    Cycles multiplies into the lamp's power), or None."""
    tree = getattr(data, "node_tree", None)
    if tree is None or not getattr(data, "use_nodes", False):
        return None
    output = tree.get_output_node('CYCLES')
    node = upstream(output.inputs["Surface"]) if output is not None else None
    return node.inputs["Strength"] if node is not None and node.type == 'EMISSION' else None


def _curve(animation, path: str, index: int = 0):
    if animation is None:
        return None
    return next((fc for fc in fcurves(animation.action, getattr(animation, "action_slot", None))
                 if fc.data_path == path and fc.array_index == index and not fc.mute), None)


_BEFORE_KEY = 1e-6  # frames: where a step at a key (after a Constant key) is sampled from below


def _sample_frames(curves, scene) -> np.ndarray:
    """Blender frames at which to sample keyed curves: ``SUBFRAMES`` per frame over the keys and the
    scene's frame range, twice widened, plus every key and the instant before it (a Constant key
    steps there)."""
    keys = np.array([k.co[0] for fc in curves for k in fc.keyframe_points], dtype=np.float64)
    lo, hi = min(keys.min(), scene.frame_start), max(keys.max(), scene.frame_end)
    span = hi - lo + 1.0
    grid = np.linspace(lo - 2 * span, hi + 2 * span, int(min(5 * span * SUBFRAMES, MAX_SAMPLES)) + 1)
    return np.unique(np.concatenate([grid, keys, keys - _BEFORE_KEY]))


def _evaluate(fc, frames: np.ndarray) -> np.ndarray:
    """An F-curve at frames; just before a key that ends a Constant segment, the held value
    (Blender's evaluation snaps to a key within 0.01 frames of it)."""
    values = np.fromiter((fc.evaluate(float(f)) for f in frames), dtype=np.float64, count=len(frames))
    points = fc.keyframe_points
    for before, key in zip(points[:-1], points[1:]):
        if before.interpolation == 'CONSTANT':
            values[np.abs(frames - (key.co[0] - _BEFORE_KEY)) < 0.5 * _BEFORE_KEY] = before.co[1]
    return values


def keyed_output(data, scene, tint=(1.0, 1.0, 1.0), strength: float = 1.0):
    """(power curve, colour curve) of a lamp whose energy, colour or node Emission strength is
    keyed: (seconds of the lamp's own clock, watts) and (seconds, (N, 3) colours), each None when
    not keyed.  Blender frame f is clock time (f - reference_frame) * fps_base / fps
    (docs/physics.md#lamps-and-shadow-rays); the power includes the exposure of the rendered frame
    and the node Emission ``strength`` (where not keyed), the colours its ``tint``
    (:func:`node_emission`)."""
    animation = data.animation_data
    energy = _curve(animation, "energy")
    colors = [_curve(animation, "color", i) for i in range(3)]
    socket = _emission_strength(data)
    keyed_strength = None
    if socket is not None:
        keyed_strength = _curve(data.node_tree.animation_data, socket.path_from_id("default_value"))
        if keyed_strength is not None and not len(keyed_strength.keyframe_points):
            keyed_strength = None
    keyed = [fc for fc in (energy, keyed_strength, *colors) if fc is not None and len(fc.keyframe_points)]
    if not keyed:
        return None, None
    frames = _sample_frames(keyed, scene)
    seconds = (frames - scene.restframe.reference_frame) * scene.render.fps_base / scene.render.fps

    def values(fc, constant):
        if fc is None or not len(fc.keyframe_points):
            return np.full(len(frames), float(constant))
        return _evaluate(fc, frames)

    power_curve = color_curve = None
    if any(fc in keyed for fc in (energy, keyed_strength)):
        watts = values(energy, data.energy) * 2.0 ** float(getattr(data, "exposure", 0.0))
        power_curve = (seconds, watts * (strength if keyed_strength is None else values(keyed_strength, 0.0)))
    if any(fc in keyed for fc in colors):
        color_curve = (seconds, np.column_stack([values(fc, data.color[i]) for i, fc in enumerate(colors)])
                       * np.asarray(tint, dtype=np.float64))
    return power_curve, color_curve


def world_color(scene, warn: Callable[[str], None]) -> tuple[float, float, float]:
    """Uniform background radiance: the Background node's colour x strength, or World.color."""
    world = scene.world
    if world is None:
        return (0.0, 0.0, 0.0)
    output = output_node(world)
    if output is None:
        return tuple(float(c) for c in world.color[:3])
    node = upstream(output.inputs["Surface"])
    if node is None:
        return (0.0, 0.0, 0.0)
    if node.type != 'BACKGROUND':
        warn(f"World '{world.name}': shader '{node.bl_label}' is not supported, using the world colour")
        return tuple(float(c) for c in world.color[:3])
    color, strength = node.inputs["Color"], node.inputs["Strength"]
    texture = upstream(color)
    if (texture is not None and texture.type != 'TEX_ENVIRONMENT') or upstream(strength) is not None:
        warn(f"World '{world.name}': textures on the background other than an Environment Texture on its "
             "Color are not supported, using its plain colour")
    return tuple(float(c) * float(strength.default_value) for c in color.default_value[:3])


_ENVIRONMENT_INTERPOLATIONS = {'Linear': "Linear", 'Closest': "Closest", 'Cubic': "Linear", 'Smart': "Linear"}


def world_texture(scene, warn: Callable[[str], None]) -> WorldTexture | None:
    """The Environment Texture (equirectangular image, optionally rotated by a Mapping node) on the
    world's Background Color, or None (a plain colour, or something RESTframe cannot read: warned)."""
    world = scene.world
    output = output_node(world) if world is not None else None
    node = upstream(output.inputs["Surface"]) if output is not None else None
    if node is None or node.type != 'BACKGROUND':
        return None
    texture = upstream(node.inputs["Color"])
    if texture is None or texture.type != 'TEX_ENVIRONMENT':
        return None
    label = f"World '{world.name}'"
    if texture.projection != 'EQUIRECTANGULAR':
        warn(f"{label}: the Environment Texture's {texture.projection.title().replace('_', ' ')} projection is not "
             "supported (use Equirectangular); using the plain Background colour")
        return None
    if texture.image is None:
        warn(f"{label}: the Environment Texture has no image; using the plain Background colour")
        return None
    try:
        image = image_texture(texture.image, texture.image_user, scene.frame_current, warn)
    except ImageMissing as missing:
        warn(f"Image '{texture.image.name}' (world '{world.name}') could not be loaded: '{missing}' is missing; "
             "using the plain Background colour")
        return None
    if image.tiles != (1, 1):
        warn(f"{label}: a tiled (UDIM) image cannot be an environment; using the plain Background colour")
        return None
    image = image.pixels
    if texture.interpolation not in ('Linear', 'Closest'):
        warn(f"{label}: {texture.interpolation} interpolation of the Environment Texture is read as Linear")
    rotation, vector_type = (0.0, 0.0, 0.0), "POINT"
    mapping = upstream(texture.inputs["Vector"])
    if mapping is not None and mapping.type != 'MAPPING':
        warn(f"{label}: only a Mapping node may feed the Environment Texture's Vector; '{mapping.bl_label}' is ignored")
    elif mapping is not None:
        vector_type = mapping.vector_type
        inputs = mapping.inputs
        if any(upstream(inputs[name]) is not None for name in ("Location", "Rotation", "Scale")):
            warn(f"{label}: the Mapping node's inputs must not be linked; using their values")
        moved = vector_type in ('POINT', 'TEXTURE') and any(inputs["Location"].default_value)
        if moved or tuple(inputs["Scale"].default_value) != (1.0, 1.0, 1.0):
            warn(f"{label}: the Mapping node's location and scale are ignored (a world direction is only rotated)")
        rotation = tuple(float(a) for a in inputs["Rotation"].default_value)
    return WorldTexture(image=image, strength=float(node.inputs["Strength"].default_value), rotation=rotation,
                        vector_type=vector_type, interpolation=_ENVIRONMENT_INTERPOLATIONS[texture.interpolation],
                        name=world.name)


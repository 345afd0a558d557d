"""Lights and the world: Blender lamps -> core Lights, the world's uniform background radiance."""

from __future__ import annotations

from typing import Callable

import numpy as np

from ..core.scene import Light, Velocity
from .materials import output_node, upstream


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


def export_light(obj, matrix: np.ndarray, velocity: Velocity, pivot, warn: Callable[[str], None] = print) -> Light:
    data = obj.data
    rotation = matrix[:3, :3] / np.linalg.norm(matrix[:3, :3], axis=0)
    tint, strength = node_emission(data, obj.name, warn)
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
    if upstream(color) is not None or upstream(strength) is not None:
        warn(f"World '{world.name}': textures on the background are not supported, using its plain colour")
    return tuple(float(c) * float(strength.default_value) for c in color.default_value[:3])


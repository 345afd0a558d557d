"""Materials: Principled BSDF (and a few simple shaders) -> core Materials; shader-node helpers."""

from __future__ import annotations

from typing import Callable

import bpy
import numpy as np

from ..core.scene import Material
from ..motion_query import fcurves
from .motion import MAX_SAMPLES, SUBFRAMES


def _linear_from_srgb(c: np.ndarray) -> np.ndarray:
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def upstream(socket):
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


def output_node(id_data):
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
        output = output_node(mat)
        node = upstream(output.inputs["Surface"]) if output is not None else None
        if node is None and output is not None:  # a node tree with nothing on Surface renders black
            out.base_color, out.specular_ior_level = (0.0, 0.0, 0.0), 0.0
            return out
        if node is None:
            out.base_color = tuple(mat.diffuse_color[:3])
            out.metallic, out.roughness = float(mat.metallic), float(mat.roughness)
            return out
        if node.type == 'BSDF_PRINCIPLED':
            self._principled(mat, node, out)
        elif node.type == 'EMISSION':  # emits, reflects nothing
            out.base_color, out.specular_ior_level = (0.0, 0.0, 0.0), 0.0
            out.emission = self._emission(mat, node.inputs["Color"], node.inputs["Strength"], out)
        elif node.type == 'BSDF_DIFFUSE':  # Lambert, without the Principled BSDF's specular layer
            out.base_color, out.specular_ior_level = self._color(mat, node.inputs["Color"]), 0.0
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
        texture_node = upstream(base)
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
        curve = next((fc for fc in fcurves(animation.action, getattr(animation, "action_slot", None))
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
        if upstream(socket) is not None:
            self._unsupported_link(mat, socket)
        return tuple(float(v) for v in socket.default_value[:3])

    def _value(self, mat, socket) -> float:
        if upstream(socket) is not None:
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


"""Materials: Principled BSDF (and a few simple shaders) -> core Materials; shader-node helpers."""

from __future__ import annotations

from typing import Callable

import numpy as np

from ..core.scene import Material
from ..motion_query import fcurves
from .images import ImageMissing, image_texture
from .motion import MAX_SAMPLES, SUBFRAMES
from .features import FeatureReport, principled_features
from .nodes import output_node, upstream, upstream_link
from .surface_maps import principled_alpha, principled_normal_map

IDENTITY_UV = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # (2, 3) affine map of (u, v, 1)


def _euler_matrix(angles) -> np.ndarray:
    """Blender's XYZ Euler rotation: Rz @ Ry @ Rx."""
    (cx, cy, cz), (sx, sy, sz) = np.cos(angles), np.sin(angles)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


def mapping_affine(kind: str, location, rotation, scale) -> np.ndarray:
    """The Mapping node on a UV (u, v, 0) as the (2, 3) affine map of (u, v, 1) it amounts to
    (an image texture reads x and y only, so the map is exact)."""
    rotate = _euler_matrix(np.asarray(rotation, dtype=np.float64))
    location, scale = np.asarray(location, dtype=np.float64), np.asarray(scale, dtype=np.float64)
    if kind == 'TEXTURE':  # the inverse of Point: (R^T (v - location)) / scale
        with np.errstate(divide="ignore", invalid="ignore"):
            inverse_scale = np.where(scale != 0.0, 1.0 / scale, 0.0)
        linear = inverse_scale[:, None] * rotate.T
        offset = -linear @ location
    else:  # Point: R (v * scale) + location; Vector: without the location
        linear = rotate * scale[None, :]
        offset = location if kind == 'POINT' else np.zeros(3)
    return np.column_stack([linear[:2, :2], offset[:2]])


class MaterialExporter:
    """Principled BSDF (and a few simple shaders) -> core Materials, each read once."""

    def __init__(self, warn: Callable[[str], None], scene=None, *, unsupported: FeatureReport):
        """``unsupported`` collects the Principled inputs a material uses that are not modelled
        (its owner warns about them with the scene's other unsupported features)."""
        self.warn = warn
        self.scene = scene
        self.unsupported = unsupported
        self.materials: list[Material] = [Material(name="Default")]
        self._index: dict[int, int] = {}
        # material index -> (2, 3) affine map of its texture's UVs (Mapping node, UDIM layout)
        self.uv_transforms: dict[int, np.ndarray] = {}

    def index_of(self, material) -> int:
        if material is None:
            return 0
        key = material.original.as_pointer()
        index = self._index.get(key)
        if index is None:
            index = len(self.materials)
            converted, uv_transform = self._convert(material)
            self.materials.append(converted)
            if uv_transform is not None:
                self.uv_transforms[index] = uv_transform
            self._index[key] = index
        return index

    def _convert(self, mat) -> tuple[Material, np.ndarray | None]:
        """The material, and the affine map of its texture's UVs (None: as they are)."""
        out = Material(name=mat.name)
        output = output_node(mat)
        node = upstream(output.inputs["Surface"]) if output is not None else None
        if node is None and output is not None:  # a node tree with nothing on Surface renders black
            out.base_color, out.specular_ior_level = (0.0, 0.0, 0.0), 0.0
            return out, None
        if node is None:
            out.base_color = tuple(mat.diffuse_color[:3])
            out.metallic, out.roughness = float(mat.metallic), float(mat.roughness)
            return out, None
        uv_transform = None
        if node.type == 'BSDF_PRINCIPLED':
            uv_transform = self._principled(mat, node, out)
        elif node.type == 'EMISSION':  # emits, reflects nothing
            out.base_color, out.specular_ior_level = (0.0, 0.0, 0.0), 0.0
            out.emission = self._emission(mat, node.inputs["Color"], node.inputs["Strength"], out)
        elif node.type == 'HOLDOUT':  # a hole in the image (reflects and emits nothing)
            out.base_color, out.specular_ior_level, out.holdout = (0.0, 0.0, 0.0), 0.0, True
        elif node.type == 'BSDF_DIFFUSE':  # Lambert, without the Principled BSDF's specular layer
            out.base_color, out.specular_ior_level = self._color(mat, node.inputs["Color"]), 0.0
            out.roughness = 1.0
        else:
            self.warn(f"Material '{mat.name}': shader '{node.bl_label}' is not supported, "
                      "using its viewport display colour (use a Principled BSDF)")
            out.base_color = tuple(mat.diffuse_color[:3])
            out.metallic, out.roughness = float(mat.metallic), float(mat.roughness)
        return out, uv_transform

    def _principled(self, mat, node, out: Material) -> np.ndarray | None:
        """Fills ``out``; returns the affine map of the base colour texture's UVs (None: as they are)."""
        inputs = node.inputs
        base = inputs["Base Color"]
        texture_node = upstream(base)
        uv_transform = None
        if texture_node is not None and texture_node.type == 'TEX_IMAGE':
            out.base_color_texture, uv_transform = self._image(mat, texture_node)
            out.base_color = tuple(base.default_value[:3])
            out.base_color_interpolation = 'Closest' if texture_node.interpolation == 'Closest' else 'Linear'
            if texture_node.interpolation not in {'Linear', 'Closest'}:
                self.warn(f"Material '{mat.name}': {texture_node.interpolation} image interpolation is read as Linear")
            if texture_node.extension != 'REPEAT' or texture_node.projection != 'FLAT':
                self.warn(f"Material '{mat.name}': image extension '{texture_node.extension}' / projection "
                          f"'{texture_node.projection}' are read as Repeat / Flat")
        else:
            out.base_color = self._color(mat, base)
        out.metallic = self._value(mat, inputs["Metallic"])
        out.roughness = self._value(mat, inputs["Roughness"])
        out.ior = self._value(mat, inputs["IOR"])
        out.specular_ior_level = self._value(mat, inputs["Specular IOR Level"])
        out.transmission = self._value(mat, inputs["Transmission Weight"])
        out.coat_weight = self._value(mat, inputs["Coat Weight"])
        out.coat_roughness = self._value(mat, inputs["Coat Roughness"])
        out.coat_ior = self._value(mat, inputs["Coat IOR"])
        self.unsupported.add(f"Material '{mat.name}'", principled_features(node))
        out.emission = self._emission(mat, inputs["Emission Color"], inputs["Emission Strength"], out)
        out.alpha, out.alpha_texture = principled_alpha(mat, node, self.warn)
        out.normal_texture, out.normal_strength = principled_normal_map(
            mat, node, self.scene.frame_current if self.scene is not None else 1, self.warn)
        return uv_transform

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

    def _uv_source(self, mat, link) -> bool:
        """Whether a link carries the mesh's UVs (Texture Coordinate UV or a UV Map node)."""
        if link is None:
            return True
        node = link.from_node
        if node.type == 'UVMAP' or (node.type == 'TEX_COORD' and link.from_socket.name == 'UV'):
            return True
        self.warn(f"Material '{mat.name}': texture coordinates from '{node.bl_label}' are not supported, using the UVs")
        return False

    def _uv_transform(self, mat, node) -> np.ndarray:
        """The (2, 3) affine map the image texture's Vector input applies to the UVs."""
        link = upstream_link(node.inputs["Vector"])
        if link is None or link.from_node.type != 'MAPPING':
            self._uv_source(mat, link)
            return IDENTITY_UV
        mapping = link.from_node
        self._uv_source(mat, upstream_link(mapping.inputs["Vector"]))
        if mapping.vector_type == 'NORMAL':
            self.warn(f"Material '{mat.name}': a Normal-type Mapping on the UVs is not supported, ignored")
            return IDENTITY_UV
        values = []
        for name, unused in (("Location", (0.0, 0.0, 0.0)), ("Rotation", (0.0, 0.0, 0.0)), ("Scale", (1.0, 1.0, 1.0))):
            socket = mapping.inputs.get(name)  # (a Vector mapping has no Location)
            if socket is not None and upstream(socket) is not None:
                self._unsupported_link(mat, socket)
            values.append(tuple(socket.default_value) if socket is not None else unused)
        return mapping_affine(mapping.vector_type, *values)

    def _image(self, mat, node) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The image's pixels as scene-linear RGB (H, W, 3) float32, row 0 = bottom (None if missing),
        and the affine map of its UVs (Mapping node, UDIM tile layout; None: as they are)."""
        image = node.image
        if image is None:
            self.warn(f"Material '{mat.name}': the image texture node has no image")
            return None, None
        if image.source == 'MOVIE':
            self.warn(f"Image '{image.name}' (material '{mat.name}'): movie textures are not supported; "
                      "using the base colour")
            return None, None
        frame = self.scene.frame_current if self.scene is not None else 1
        try:
            texture = image_texture(image, node.image_user, frame, self.warn)
        except ImageMissing as missing:
            self.warn(f"Image '{image.name}' (material '{mat.name}') could not be loaded: "
                      f"'{missing}' is missing; using the base colour")
            return None, None
        transform = self._uv_transform(mat, node)
        columns, rows = texture.tiles
        if (columns, rows) != (1, 1):  # tile (i, j) covers UVs [i, i+1) x [j, j+1) of the side-by-side layout
            transform = np.array([[1.0 / columns], [1.0 / rows]]) * transform
        return texture.pixels, None if np.array_equal(transform, IDENTITY_UV) else transform

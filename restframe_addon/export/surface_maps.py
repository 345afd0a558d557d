"""Principled Alpha (cut-outs) and tangent-space normal maps: what the material's node tree feeds them.

Supported as Cycles reads them: a value, or an Image Texture's Alpha output into Alpha (times
nothing else); a Normal Map node in tangent space with a constant Strength and an Image
Texture's Color into Normal.  Anything else linked there is warned about and ignored.
The images are read through the UV map the mesh exports (the render's active one).
"""

from __future__ import annotations

import numpy as np

from .images import ImageMissing, image_texture
from .nodes import upstream, upstream_link


def _pixels(image):
    """An image's pixels (H, W, C) float32, row 0 = bottom; None without data."""
    width, height = image.size
    if width == 0 or height == 0 or not image.has_data:
        return None
    pixels = np.empty(width * height * image.channels, dtype=np.float32)
    image.pixels.foreach_get(pixels)
    return pixels.reshape(height, width, image.channels)


def _texture_node(mat, socket, output: str, warn):
    """The Image Texture node whose ``output`` feeds ``socket`` (None: unlinked or warned)."""
    link = upstream_link(socket)
    if link is None:
        return None
    if link.from_node.type != 'TEX_IMAGE' or link.from_socket.name != output:
        warn(f"Material '{mat.name}': the link into '{socket.name}' is not supported "
             f"(use an Image Texture's {output}), ignored")
        return None
    if link.from_node.image is None:
        warn(f"Material '{mat.name}': the image texture node on '{socket.name}' has no image, ignored")
        return None
    return link.from_node


def principled_alpha(mat, node, warn):
    """(alpha value, alpha image (H, W, 1) or None) of a Principled BSDF."""
    socket = node.inputs["Alpha"]
    texture = _texture_node(mat, socket, "Alpha", warn)
    if texture is None:
        return float(socket.default_value), None
    pixels = _pixels(texture.image)
    if pixels is None:
        warn(f"Image '{texture.image.name}' (material '{mat.name}') could not be loaded: opaque")
        return 1.0, None
    if pixels.shape[2] < 4:  # no alpha channel: Blender reads it as 1
        return 1.0, None
    # straight alpha, as Cycles' Image Texture hands out (its Alpha output is not colour-managed)
    return 1.0, np.ascontiguousarray(pixels[..., 3:4])


def principled_normal_map(mat, node, frame: int, warn):
    """(normal map image (H, W, 3) or None, strength) of a Principled BSDF's Normal input, the
    image as an Image Texture shows it at scene frame ``frame`` (converted once, cached)."""
    socket = node.inputs["Normal"]
    link = upstream_link(socket)
    if link is None:
        return None, 1.0
    normal_map = link.from_node
    if normal_map.type == 'BUMP':  # warned about with the objects that use it (features.uses_bump_map)
        return None, 1.0
    if normal_map.type != 'NORMAL_MAP' or normal_map.space != 'TANGENT':
        warn(f"Material '{mat.name}': only a tangent-space Normal Map node is supported on 'Normal', ignored")
        return None, 1.0
    strength = normal_map.inputs["Strength"]
    if upstream(strength) is not None:
        warn(f"Material '{mat.name}': the link into the Normal Map's 'Strength' is not supported, using its value")
    texture = _texture_node(mat, normal_map.inputs["Color"], "Color", warn)
    if texture is None:
        return None, 1.0
    try:
        image = image_texture(texture.image, texture.image_user, frame, warn)
    except ImageMissing as missing:
        warn(f"Image '{texture.image.name}' (material '{mat.name}') could not be loaded: '{missing}' is missing; "
             "no normal map")
        return None, 1.0
    if image.tiles != (1, 1):
        warn(f"Image '{texture.image.name}' (material '{mat.name}'): UDIM normal maps are not supported; no normal map")
        return None, 1.0
    return image.pixels, max(float(strength.default_value), 0.0)

"""Image textures -> scene-linear float32 RGB arrays, converted once and cached across frames.

Converting an 8K image costs seconds and gigabytes (Blender hands its pixels out as floats),
so each conversion is kept, read-only, under a key that changes whenever the image would
convert differently (its file and the file's size and time, its source, size, colour space,
generated settings, packed data, the sequence frame or the UDIM tiles); an image edited in
memory (``is_dirty``) is converted afresh.  The cache keeps the most recent conversions up
to ``CACHE_BYTES`` (always the latest one).

Image sequences use the file of the image user's frame (Blender's rule: the scene frame
counted from the user's start frame, cyclic or held at the ends, plus the offset), UDIM
images every tile, laid out side by side in one array (``Texture.tiles`` says how many
columns and rows; the exporter scales the UVs to match).  Approximations of that layout:
Linear filtering blends a tile's outermost half pixel with its neighbour's, and UVs beyond the
tiles wrap around instead of finding no tile.  Both read their files through a temporary
image datablock that is removed again.
"""

from __future__ import annotations

import os
import re
from collections import OrderedDict
from dataclasses import dataclass

import bpy
import numpy as np

from ..core.world import texel_image

CACHE_BYTES = 2 << 30
_BAND_ROWS = 512
_cache: OrderedDict = OrderedDict()

_LINEAR_SPACES = {"Non-Color", "Linear Rec.709", "Linear", "Raw", "Linear CIE-XYZ E", "Linear FilmLight E-Gamut"}
# 8-bit sRGB code value -> linear, for byte images (Blender hands out code / 255 exactly)
_CODE = np.arange(256, dtype=np.float64) / 255.0
_SRGB_TO_LINEAR = np.where(_CODE <= 0.04045, _CODE / 12.92, ((_CODE + 0.055) / 1.055) ** 2.4).astype(np.float32)


@dataclass(frozen=True)
class Texture:
    """Scene-linear RGB pixels (H, W, 3) float32, row 0 = bottom; ``tiles`` = (columns, rows) of UDIM tiles."""

    pixels: np.ndarray
    tiles: tuple[int, int] = (1, 1)


class ImageMissing(Exception):
    """The image has no pixels to read (the message says which file)."""


def sequence_frame(user, scene_frame: int) -> int:
    """The file frame an image user shows at a scene frame (Blender's image-user rule)."""
    length = user.frame_duration
    if length <= 0:
        return 0
    frame = scene_frame - user.frame_start + 1
    if user.use_cyclic:
        frame %= length
        if frame == 0:
            frame = length
    frame = min(max(frame, 0), length)
    return frame + user.frame_offset


def _numbered(path: str, number: int) -> str:
    """The path with the last run of digits in its file name replaced by ``number``, same padding."""
    head, name = os.path.split(path)
    match = None
    for match in re.finditer(r"\d+", name):
        pass
    if match is None:
        return path
    digits = f"{number:0{len(match.group())}d}"
    return os.path.join(head, name[:match.start()] + digits + name[match.end():])


def _tile_path(path: str, number: int) -> str:
    u, v = (number - 1001) % 10, (number - 1001) // 10
    return path.replace("<UDIM>", str(number)).replace("<UVTILE>", f"u{u + 1}_v{v + 1}")


def _file_stamp(path: str):
    try:
        stat = os.stat(path)
    except OSError:
        return None
    return (stat.st_size, stat.st_mtime_ns)


def _files(image, scene_frame: int, user) -> list[tuple[int, str]]:
    """(tile number, absolute file path) of what a sequence frame or UDIM image reads."""
    path = bpy.path.abspath(image.filepath, library=image.library)
    if image.source == 'SEQUENCE':
        return [(1001, _numbered(path, sequence_frame(user, scene_frame)))]
    return [(tile.number, _tile_path(path, tile.number)) for tile in image.tiles]


def _key(image, files):
    if image.is_dirty:
        return None
    generated = (image.generated_type, tuple(image.generated_color), image.generated_width,
                 image.generated_height, image.use_generated_float) if image.source == 'GENERATED' else None
    packed = image.packed_file.size if image.packed_file is not None else None
    path = bpy.path.abspath(image.filepath, library=image.library)
    return (image.as_pointer(), image.name_full, image.source, path, _file_stamp(path),
            image.colorspace_settings.name, image.alpha_mode, generated, packed,
            tuple((number, file, _file_stamp(file)) for number, file in files))


def _rgb(image, colorspace: str, warn) -> np.ndarray:
    """An image's own pixels (it must have data) as linear RGB float32 (H, W, 3)."""
    width, height = image.size
    channels = image.channels
    pixels = np.empty(width * height * channels, dtype=np.float32)
    image.pixels.foreach_get(pixels)
    pixels = pixels.reshape(height, width, channels)
    rgb = pixels[..., :3] if channels >= 3 else np.repeat(pixels[..., :1], 3, axis=2)
    if image.is_float or colorspace in _LINEAR_SPACES:
        return np.ascontiguousarray(rgb, dtype=np.float32)
    if "sRGB" not in colorspace:
        warn(f"Image '{image.name}': colour space '{colorspace}' is read as sRGB")
    # 8 bits per channel (Blender keeps anything deeper as floats): the pixels are code values / 255;
    # converted in bands of rows, so the temporaries stay small next to the image
    out = np.empty(rgb.shape, dtype=np.float32)
    for start in range(0, height, _BAND_ROWS):
        band = slice(start, start + _BAND_ROWS)
        out[band] = _SRGB_TO_LINEAR[np.rint(rgb[band] * 255.0).astype(np.uint8)]
    return out


def _read_file(image, path: str, warn) -> np.ndarray:
    """One file's pixels through a temporary image datablock (removed again), read like ``image``."""
    if not os.path.isfile(path):
        raise ImageMissing(path)
    temporary = bpy.data.images.load(path, check_existing=False)
    try:
        temporary.colorspace_settings.name = image.colorspace_settings.name
        if 0 in tuple(temporary.size):  # (asking the size loads the file)
            raise ImageMissing(path)
        return _rgb(temporary, image.colorspace_settings.name, warn)
    finally:
        bpy.data.images.remove(temporary)


def _tiled(image, files, warn) -> Texture:
    """UDIM tiles side by side (10 columns at most, as UDIM numbers them); absent tiles black."""
    read = {number: _read_file(image, path, warn) for number, path in files}
    height, width = next(iter(read.values())).shape[:2]
    columns = max((number - 1001) % 10 for number in read) + 1
    rows = max((number - 1001) // 10 for number in read) + 1
    atlas = np.zeros((rows * height, columns * width, 3), dtype=np.float32)
    for number, pixels in read.items():
        if pixels.shape[:2] != (height, width):
            warn(f"Image '{image.name}': UDIM tile {number} is {pixels.shape[1]}x{pixels.shape[0]}, not "
                 f"{width}x{height} like the first tile: resampled (nearest pixel)")
            ys = (np.arange(height) * pixels.shape[0]) // height
            xs = (np.arange(width) * pixels.shape[1]) // width
            pixels = pixels[ys][:, xs]
        u, v = (number - 1001) % 10, (number - 1001) // 10
        atlas[v * height:(v + 1) * height, u * width:(u + 1) * width] = pixels
    return Texture(atlas, (columns, rows))


def image_texture(image, user, scene_frame: int, warn) -> Texture:
    """The image (as an Image Texture node with image user ``user`` shows it at ``scene_frame``)
    as a Texture; raises ImageMissing naming the file when there is nothing to read."""
    files = _files(image, scene_frame, user) if image.source in {'SEQUENCE', 'TILED'} else []
    key = _key(image, files)
    if key is not None and key in _cache:
        _cache.move_to_end(key)
        return _cache[key]
    if image.source == 'TILED':
        texture = _tiled(image, files, warn)
    elif image.source == 'SEQUENCE':
        texture = Texture(_read_file(image, files[0][1], warn))
    else:
        width, height = image.size
        if width == 0 or height == 0 or not image.has_data:
            raise ImageMissing(bpy.path.abspath(image.filepath, library=image.library))
        texture = Texture(_rgb(image, image.colorspace_settings.name, warn))
    # laid out once for the lookups (read-only, shared by every frame that uses it): the scene and
    # its prepared lookups hold one copy
    texture = Texture(texel_image(texture.pixels), texture.tiles)
    if key is not None:
        _cache[key] = texture
        while len(_cache) > 1 and sum(t.pixels.nbytes for t in _cache.values()) > CACHE_BYTES:
            _cache.popitem(last=False)
    return texture

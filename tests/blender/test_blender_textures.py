"""Image textures as Cycles reads them: Mapping node, Closest interpolation, UDIM tiles, image sequences.

Each test renders the same small scene at rest with Cycles (CPU, 64 samples, box-like pixel filter,
direct light only) and with RESTframe, and compares the albedo per pixel: each engine's image of
the textured plane divided by its own image of the same plane in plain white, so that only the
texture lookup is compared, not the lighting.
"""


import bpy
import numpy as np
import OpenEXR
import pytest

from blender_helpers import add_camera, render_direct_light
from restframe_addon.export import images

SAMPLES = 64


def textured_plane(scene, image, size=(2.0, 2.0), uv_scale=(1.0, 1.0)):
    """A plane in z = 0 with a Principled (diffuse only) material reading ``image``, lit from straight
    above, seen by an orthographic camera that it fills exactly."""
    sx, sy = size[0] / 2, size[1] / 2
    mesh = bpy.data.meshes.new("Plane")
    mesh.from_pydata([(-sx, -sy, 0), (sx, -sy, 0), (sx, sy, 0), (-sx, sy, 0)], [], [(0, 1, 2, 3)])
    uv = mesh.uv_layers.new(name="UVMap")
    for loop, corner in zip(uv.data, [(0, 0), (1, 0), (1, 1), (0, 1)]):
        loop.uv = (corner[0] * uv_scale[0], corner[1] * uv_scale[1])
    plane = bpy.data.objects.new("Plane", mesh)
    scene.collection.objects.link(plane)
    mat = bpy.data.materials.new("Textured")
    if bpy.app.version < (5, 0, 0):
        mat.use_nodes = True
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    bsdf.inputs["Roughness"].default_value = 1.0
    bsdf.inputs["Specular IOR Level"].default_value = 0.0
    tex = mat.node_tree.nodes.new("ShaderNodeTexImage")
    tex.image = image
    mat.node_tree.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    mesh.materials.append(mat)
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", 'SUN'))
    sun.data.energy = 3.0
    scene.collection.objects.link(sun)
    scene.world = None
    add_camera(scene, location=(0.0, 0.0, 5.0), type='ORTHO', ortho_scale=max(size))
    scene.render.resolution_x = int(16 * size[0])
    scene.render.resolution_y = int(16 * size[1])
    return mat, tex


def render(scene, tmp_path, engine, name):
    return render_direct_light(scene, tmp_path / f"{name}-{engine}.exr", engine, SAMPLES)


def albedo(scene, tmp_path, engine, mat, tex, name="t"):
    """The textured image over the same plane in white (the texture's link removed, then restored)."""
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    textured = render(scene, tmp_path, engine, name)
    link = next(link for link in mat.node_tree.links if link.to_socket == bsdf.inputs["Base Color"])
    mat.node_tree.links.remove(link)
    white = render(scene, tmp_path, engine, name + "-white")
    mat.node_tree.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    assert white.min() > 0.0
    return textured / white


def pixel_image(name, pixels, path=None):
    """An image of the given linear RGB pixels (h, w, 3), row 0 at the bottom: in memory, or written
    as a float EXR file at ``path`` (by OpenEXR itself, so that no Blender colour handling is involved)."""
    h, w = pixels.shape[:2]
    if path is not None:
        rgb = np.ascontiguousarray(pixels[::-1], dtype=np.float32)  # EXR rows run top-down
        with OpenEXR.File({"type": OpenEXR.scanlineimage}, {"RGB": rgb}) as exr:
            exr.write(str(path))
        return None
    image = bpy.data.images.new(name, w, h, float_buffer=True)
    rgba = np.concatenate([pixels, np.ones((h, w, 1))], axis=2).astype(np.float32)
    image.pixels.foreach_set(rgba.ravel())  # a float image: linear, as given
    return image


def checker(seed, h=4, w=4):
    return np.random.default_rng(seed).uniform(0.1, 0.9, (h, w, 3))


def blocks(image, size=4):
    """Means over size x size pixel blocks: pixels on a texel edge differ by the engines' own sampling."""
    h, w = image.shape[:2]
    return image.reshape(h // size, size, w // size, size, -1).mean(axis=(1, 3))


def compare(ours, cycles, tolerance=0.03):
    difference = np.abs(blocks(ours) - blocks(cycles))
    assert difference.max() < tolerance, difference.max()
    assert difference.mean() < tolerance / 3, difference.mean()


@pytest.mark.parametrize("kind", ['POINT', 'TEXTURE', 'VECTOR'])
def test_mapping_node_on_the_uvs_matches_cycles(scene, tmp_path, kind):
    mat, tex = textured_plane(scene, pixel_image("Checker", checker(1)))
    tree = mat.node_tree
    mapping = tree.nodes.new("ShaderNodeMapping")
    mapping.vector_type = kind
    if kind != 'VECTOR':  # (a Vector mapping has no Location)
        mapping.inputs["Location"].default_value = (0.15, -0.3, 0.0)
    mapping.inputs["Rotation"].default_value = (0.0, 0.0, 0.4)
    mapping.inputs["Scale"].default_value = (1.7, 0.6, 1.0)
    coords = tree.nodes.new("ShaderNodeTexCoord")
    tree.links.new(coords.outputs["UV"], mapping.inputs["Vector"])
    tree.links.new(mapping.outputs["Vector"], tex.inputs["Vector"])
    ours = albedo(scene, tmp_path, 'RESTFRAME', mat, tex)
    cycles = albedo(scene, tmp_path, 'CYCLES', mat, tex)
    plain = np.repeat(np.repeat(checker(1), 8, axis=0), 8, axis=1)  # the unmapped texture on 32x32 pixels
    assert np.abs(cycles - plain).mean() > 0.05, "the mapping must change the image"
    compare(ours, cycles)


@pytest.mark.parametrize("interpolation", ['Closest', 'Linear'])
def test_closest_and_linear_interpolation_match_cycles(scene, tmp_path, interpolation):
    mat, tex = textured_plane(scene, pixel_image("Checker", checker(2)))
    tex.interpolation = interpolation
    ours = albedo(scene, tmp_path, 'RESTFRAME', mat, tex)
    cycles = albedo(scene, tmp_path, 'CYCLES', mat, tex)
    if interpolation == 'Closest':  # 8x8 pixels per texel, each a single colour
        np.testing.assert_allclose(cycles[4::8, 4::8], checker(2), rtol=0.02)
    compare(ours, cycles)


def test_udim_tiles_match_cycles(scene, tmp_path):
    """Two UDIM tiles (1001, 1002) side by side on a plane whose UVs run over u in [0, 2]."""
    tiles = {1001: checker(3), 1002: checker(4)}
    for number, pixels in tiles.items():
        pixel_image(f"tile{number}", pixels, tmp_path / f"paint.{number}.exr")
    image = bpy.data.images.load(str(tmp_path / "paint.1001.exr"))
    image.source = 'TILED'
    image.filepath = str(tmp_path / "paint.<UDIM>.exr")
    if 1002 not in [tile.number for tile in image.tiles]:
        image.tiles.new(tile_number=1002)
    mat, tex = textured_plane(scene, image, size=(4.0, 2.0), uv_scale=(2.0, 1.0))
    tex.interpolation = 'Closest'
    ours = albedo(scene, tmp_path, 'RESTFRAME', mat, tex)
    cycles = albedo(scene, tmp_path, 'CYCLES', mat, tex)
    np.testing.assert_allclose(cycles[4::8, 36::8], tiles[1002], rtol=0.02)  # the right half is tile 1002
    compare(ours, cycles)


@pytest.mark.parametrize("frame", [1, 2, 5, 9])
def test_image_sequence_frame_matches_cycles(scene, tmp_path, frame):
    """Files seq.0001-0004 of different colours; the image user starts at scene frame 2, runs 3
    images, cyclic, offset 1: which file each scene frame shows is Blender's rule."""
    colours = {n: np.full((2, 2, 3), 0.15 + 0.2 * n) * np.array([1.0, 0.7, 0.4]) for n in range(1, 5)}
    for n, pixels in colours.items():
        pixel_image(f"seq{n}", pixels, tmp_path / f"seq.{n:04d}.exr")
    image = bpy.data.images.load(str(tmp_path / "seq.0001.exr"))
    image.source = 'SEQUENCE'
    mat, tex = textured_plane(scene, image)
    user = tex.image_user
    user.frame_start, user.frame_duration, user.use_cyclic, user.frame_offset = 2, 3, True, 1
    scene.frame_set(frame)
    ours = albedo(scene, tmp_path, 'RESTFRAME', mat, tex)
    cycles = albedo(scene, tmp_path, 'CYCLES', mat, tex)
    shown = images.sequence_frame(user, frame)
    np.testing.assert_allclose(cycles, np.broadcast_to(colours[shown][0, 0], cycles.shape), rtol=0.02)
    compare(ours, cycles, tolerance=0.01)


def test_a_texture_is_converted_once_across_frames_and_again_when_it_changes(scene, tmp_path):
    """Two frames of one job share one read-only float32 conversion; a new file (size and time
    change) or another colour space gives a new one."""
    from blender_helpers import export_now

    path = tmp_path / "grid.exr"
    pixel_image("Grid", checker(5, 8, 8), path)
    image = bpy.data.images.load(str(path))
    textured_plane(scene, image)

    def texture():
        out, _, _ = export_now(scene)
        return next(m.base_color_texture for m in out.materials if m.name == "Textured")

    first = texture()
    assert first.dtype == np.float32 and not first.flags.writeable
    np.testing.assert_allclose(first, checker(5, 8, 8), rtol=1e-6)
    scene.frame_set(2)
    assert texture() is first
    pixel_image("Grid2", checker(6, 16, 16), path)  # the file is replaced
    image.reload()
    second = texture()
    assert second is not first and second.shape == (16, 16, 3)
    np.testing.assert_allclose(second, checker(6, 16, 16), rtol=1e-6)
    image.colorspace_settings.name = "Non-Color"
    assert texture() is not second

"""Holdout, Indirect Only, ray visibility, Principled Alpha, normal maps and stereo render as in Cycles.

An orthographic camera looks straight down at a white Lambert floor (Principled, no specular)
lit by a sun without size: 32 x 32 pixels of 0.25 units.  A 2 x 2 card floats 1 above the
floor's middle; the sun comes 45 degrees from the zenith, so the card's shadow lies one card
width beside it.  Every edge falls on pixel boundaries, and the sun needs no sampling, so both
renderers' images are exact up to float rounding: the test compares the image's mean RGBA (and
for cut-outs with partial alpha, within the samples' noise).  Cycles renders on the CPU with
box pixels and only the bounces the feature needs.
"""

import math

import bpy
import numpy as np
import pytest

from blender_helpers import add_camera, add_plane, principled, render_exr, render_eyes, render_rgba

SUN_TILT = math.radians(45)


def surface(name, color=(1.0, 1.0, 1.0), **inputs):
    """A Principled material, Lambertian unless ``inputs`` say otherwise (no specular layer, roughness 1)."""
    return principled(name, color, roughness=1.0, **{"Specular_IOR_Level": 0.0, **inputs})


def glow(name, strength=1.0):
    return surface(name, color=(0.0, 0.0, 0.0), Emission_Color=(1.0, 0.6, 0.3, 1.0),
                      Emission_Strength=strength)


def card_scene(scene, card_material=None, floor_material=None, sun=True):
    scene.render.resolution_x = scene.render.resolution_y = 32
    scene.world = None
    add_camera(scene, location=(0.0, 0.0, 6.0), type='ORTHO', ortho_scale=8.0)
    floor = add_plane(scene, "Floor", size=20.0)
    floor.data.materials.append(floor_material or surface("White"))
    card = add_plane(scene, "Card", size=2.0, location=(0.0, 0.0, 1.0))
    card.data.uv_layers.new()
    card.data.materials.append(card_material or surface("Card", color=(0.2, 0.4, 0.8)))
    if sun:
        light = bpy.data.lights.new("Sun", 'SUN')
        light.energy, light.angle = 3.0, 0.0
        lamp = bpy.data.objects.new("Sun", light)
        lamp.rotation_euler = (0.0, SUN_TILT, 0.0)  # toward +x: the shadow falls at -x
        scene.collection.objects.link(lamp)
    return floor, card


def render_both(scene, tmp_path, bounces=0, samples=16, ours=16):
    images = {}
    for engine in ('RESTFRAME', 'CYCLES'):
        scene.render.engine = engine
        if engine == 'CYCLES':
            cycles = scene.cycles
            cycles.device = 'CPU'
            cycles.samples = samples
            cycles.use_adaptive_sampling = False
            cycles.use_denoising = False
            cycles.max_bounces = cycles.glossy_bounces = cycles.transmission_bounces = bounces
            cycles.diffuse_bounces = 0
            cycles.filter_width = 0.01
        else:
            scene.restframe.samples = ours
        images[engine] = render_rgba(scene, tmp_path / f"{engine}.exr")
    return images['RESTFRAME'], images['CYCLES']


def assert_same(ours, cycles, atol=1e-5, rtol=1e-3):
    np.testing.assert_allclose(ours.reshape(-1, 4).mean(axis=0), cycles.reshape(-1, 4).mean(axis=0),
                               rtol=rtol, atol=atol)


def in_collection(scene, obj, name):
    collection = bpy.data.collections.new(name)
    scene.collection.children.link(collection)
    scene.collection.objects.unlink(obj)
    collection.objects.link(obj)
    return scene.view_layers[0].layer_collection.children[name]


def holdout_shader():
    mat = bpy.data.materials.new("Hole")
    if bpy.app.version < (5, 0, 0):
        mat.use_nodes = True
    nodes = mat.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    mat.node_tree.links.new(nodes.new("ShaderNodeHoldout").outputs[0], nodes["Material Output"].inputs["Surface"])
    return mat


@pytest.mark.parametrize("how", ["object", "collection", "shader"])
def test_a_holdout_is_a_hole_that_casts_its_shadow(scene, tmp_path, how):
    _, card = card_scene(scene, card_material=holdout_shader() if how == "shader" else None)
    if how == "object":
        card.is_holdout = True
    elif how == "collection":
        in_collection(scene, card, "Held").holdout = True
    ours, cycles = render_both(scene, tmp_path)
    assert np.count_nonzero(cycles[..., 3] == 0.0) == 64  # the card's 8 x 8 pixels
    assert np.all(ours[cycles[..., 3] == 0.0] == 0.0)
    assert_same(ours, cycles)


@pytest.mark.parametrize("how", ["visible_camera", "indirect_only"])
def test_hidden_from_the_camera_it_still_casts_its_shadow(scene, tmp_path, how):
    _, card = card_scene(scene)
    if how == "visible_camera":
        card.visible_camera = False
    else:
        in_collection(scene, card, "Indirect").indirect_only = True
    ours, cycles = render_both(scene, tmp_path)
    assert cycles[..., 2].min() == 0.0  # the shadow is there ...
    assert not np.any(np.all(np.isclose(cycles[..., :3], (0.2 * 3 / math.pi * math.cos(SUN_TILT),)), axis=-1))
    assert_same(ours, cycles)  # ... the card is not


def test_hidden_from_shadow_rays_it_casts_none(scene, tmp_path):
    _, card = card_scene(scene)
    card.visible_shadow = False
    ours, cycles = render_both(scene, tmp_path)
    assert cycles[..., 0].min() > 0.1
    assert_same(ours, cycles)


@pytest.mark.parametrize("hidden", [False, True])
def test_hidden_from_glossy_rays_a_mirror_does_not_show_it(scene, tmp_path, hidden):
    """A mirror floor under a glowing card: seen in the mirror unless Visible to Glossy is off."""
    mirror = surface("Mirror", Metallic=1.0, Roughness=0.0)
    card_scene(scene, card_material=glow("Glow"), floor_material=mirror, sun=False)
    card = scene.objects["Card"]
    card.location.z = 8.0  # above the camera: only the mirror shows it
    card.scale = (10.0, 10.0, 1.0)
    card.visible_glossy = not hidden
    ours, cycles = render_both(scene, tmp_path, bounces=1)
    assert (cycles[..., 0].max() == 0.0) == hidden
    assert_same(ours, cycles, rtol=3e-3)  # Cycles' white metal reflects 0.998 (its F82 Fresnel), RESTframe's 1


@pytest.mark.parametrize("hidden", [False, True])
def test_hidden_from_transmission_rays_glass_does_not_show_it(scene, tmp_path, hidden):
    """A clear pane (IOR 1) over a glowing floor: seen through it unless Visible to Transmission is off."""
    clear = surface("Clear", Transmission_Weight=1.0, IOR=1.0, Roughness=0.0, Specular_IOR_Level=0.5)
    floor, card = card_scene(scene, card_material=clear, floor_material=glow("Glow"), sun=False)
    card.scale = (10.0, 10.0, 1.0)
    floor.visible_transmission = not hidden
    ours, cycles = render_both(scene, tmp_path, bounces=2)
    assert (cycles[..., 0].max() == 0.0) == hidden
    assert_same(ours, cycles, rtol=3e-3)  # Cycles shows 0.998 of a glow seen through a bounce, as for the mirror


def alpha_image(left, right, size=16):
    """A float RGBA image, white, with alpha ``left`` on its left half and ``right`` on its right."""
    image = bpy.data.images.new("Mask", size, size, alpha=True, float_buffer=True)
    pixels = np.ones((size, size, 4), dtype=np.float32)
    pixels[:, : size // 2, 3], pixels[:, size // 2:, 3] = left, right
    image.pixels.foreach_set(pixels.ravel())
    return image


def image_node(mat, image, output, socket, **settings):
    nodes = mat.node_tree.nodes
    texture = nodes.new("ShaderNodeTexImage")
    texture.image = image
    for key, value in settings.items():
        setattr(texture, key, value)
    mat.node_tree.links.new(texture.outputs[output], socket)
    return texture


def test_cut_outs_from_an_image_alpha_show_and_shade_what_is_behind(scene, tmp_path):
    """The card's left half is cut out (alpha 0), its right half opaque: both renderers see the
    floor through the left half and the left half's shadow is gone."""
    card_material = surface("Cutout", color=(0.2, 0.4, 0.8))
    image_node(card_material, alpha_image(0.0, 1.0), "Alpha",
               card_material.node_tree.nodes["Principled BSDF"].inputs["Alpha"], interpolation='Closest')
    card_scene(scene, card_material=card_material)
    ours, cycles = render_both(scene, tmp_path)
    card_colour = 0.2 * 3 / math.pi * math.cos(SUN_TILT)
    assert np.count_nonzero(np.isclose(cycles[..., 0], card_colour, rtol=1e-4)) == 32  # half the card
    assert_same(ours, cycles, atol=2e-3)


def test_partial_alpha_mixes_by_chance(scene, tmp_path):
    card_scene(scene, card_material=surface("Half", color=(0.2, 0.4, 0.8), Alpha=0.5))
    ours, cycles = render_both(scene, tmp_path, samples=64, ours=64)
    # 64 samples on each of the 128 pixels the card covers or shades: the mean's noise is below 3e-3
    assert_same(ours, cycles, atol=6e-3)


def normal_image(normal, size=4):
    image = bpy.data.images.new("Bumps", size, size, float_buffer=True)
    image.colorspace_settings.name = "Non-Color"
    color = (np.asarray(normal, dtype=np.float32) + 1.0) / 2.0
    image.pixels.foreach_set(np.tile(np.append(color, 1.0).astype(np.float32), size * size))
    return image


@pytest.mark.xfail(bpy.app.version < (5, 0, 0), strict=False,
                   reason="Cycles 4.2 shades the same normal map up to 2.2% apart from Cycles 5.0 (measured, not explained)")
@pytest.mark.parametrize("strength", [1.0, 0.4])
@pytest.mark.parametrize("tilt", [(0.35, 0.0), (0.1, -0.45), (-0.25, 0.2)])
def test_a_normal_map_shades_as_in_cycles(scene, tmp_path, tilt, strength):
    floor_material = surface("Bumpy")
    nodes = floor_material.node_tree.nodes
    normal_map = nodes.new("ShaderNodeNormalMap")
    normal_map.inputs["Strength"].default_value = strength
    floor_material.node_tree.links.new(normal_map.outputs["Normal"], nodes["Principled BSDF"].inputs["Normal"])
    x, y = tilt
    image_node(floor_material, normal_image((x, y, math.sqrt(1.0 - x * x - y * y))), "Color",
               normal_map.inputs["Color"])
    floor, card = card_scene(scene, floor_material=floor_material)
    floor.data.uv_layers.new()
    bpy.data.objects.remove(card)
    ours, cycles = render_both(scene, tmp_path)
    plain = 3.0 * math.cos(SUN_TILT) / math.pi
    assert abs(cycles[..., 0].mean() / plain - 1.0) > 0.02  # the map matters
    # with the sun overhead Cycles gives E cos / pi of the mapped normal exactly, as RESTframe does
    # (tests/core/test_visibility.py); with this sun, 45 degrees off, it comes out 0.13% (a normal
    # tilted 12 degrees) to 1.7% (37 degrees) darker, the same for either tilt direction: a scale on
    # its BSDF, not another normal (measured, not explained)
    assert_same(ours, cycles, rtol=1e-2)



def test_the_normal_pass_shows_the_mapped_normal_as_cycles_does(scene, tmp_path):
    floor_material = surface("Bumpy")
    nodes = floor_material.node_tree.nodes
    normal_map = nodes.new("ShaderNodeNormalMap")
    floor_material.node_tree.links.new(normal_map.outputs["Normal"], nodes["Principled BSDF"].inputs["Normal"])
    image_node(floor_material, normal_image((0.35, -0.2, math.sqrt(1.0 - 0.35**2 - 0.2**2))), "Color",
               normal_map.inputs["Color"])
    floor, card = card_scene(scene, floor_material=floor_material)
    floor.data.uv_layers.new()
    bpy.data.objects.remove(card)
    scene.render.resolution_x = scene.render.resolution_y = 4
    scene.view_layers[0].use_pass_normal = True
    normals = {}
    for engine in ('RESTFRAME', 'CYCLES'):
        scene.render.engine = engine
        scene.cycles.samples, scene.cycles.use_denoising = 4, False
        normals[engine] = render_exr(scene, tmp_path / f"{engine}.exr")["Normal"].reshape(-1, 3)
    np.testing.assert_allclose(normals['CYCLES'], [[0.35, -0.2, math.sqrt(1.0 - 0.35**2 - 0.2**2)]] * 16, atol=1e-6)
    np.testing.assert_allclose(normals['RESTFRAME'], normals['CYCLES'], atol=1e-6)


def eye_centroids(scene, tmp_path, engine):
    """The horizontal centroid (pixels) of a glowing square in each eye's image."""
    scene.render.engine = engine
    cycles = scene.cycles
    cycles.samples = scene.restframe.samples = 64
    cycles.device, cycles.use_adaptive_sampling, cycles.use_denoising = 'CPU', False, False
    cycles.pixel_filter_type, cycles.filter_width = 'BOX', 1.0  # uniform over the pixel, as RESTframe's samples
    centroids = []
    for image in render_eyes(scene, tmp_path / engine):
        weight = image[..., 0].sum(axis=0)
        centroids.append(float(weight @ np.arange(len(weight)) / weight.sum()))
    return centroids


@pytest.mark.parametrize("mode", ['OFFAXIS', 'TOE', 'PARALLEL'])
def test_stereo_eyes_see_what_cycles_eyes_see(scene, tmp_path, mode):
    """Stereoscopy: each eye is its own camera (Blender's model matrix and lens shift for the view)
    and observation event; a glowing square lands where Cycles puts it in each eye."""
    scene.render.resolution_x, scene.render.resolution_y = 64, 32
    scene.world = None
    camera = add_camera(scene, location=(0.0, 0.0, 6.0))
    stereo = camera.data.stereo
    stereo.interocular_distance, stereo.convergence_distance, stereo.convergence_mode = 0.5, 4.0, mode
    square = add_plane(scene, "Glow", size=0.5, location=(0.7, 0.0, 0.0))
    square.data.materials.append(glow("Glow"))
    scene.render.use_multiview = True
    ours = eye_centroids(scene, tmp_path, 'RESTFRAME')
    cycles = eye_centroids(scene, tmp_path, 'CYCLES')
    assert abs(cycles[0] - cycles[1]) > 3.0  # the eyes differ by pixels
    np.testing.assert_allclose(ours, cycles, atol=0.05)  # 64 samples per pixel at the square's edges


def test_export_takes_ray_visibility_and_holdout_from_the_object_its_instancer_and_collections(scene):
    """What Cycles combines: the object's and its instancer's Ray Visibility (both must allow a ray
    type), Indirect Only and Holdout of the (instancer's) collection, Holdout of either object."""
    from blender_helpers import export_now
    from restframe_addon.core.scene import RAY_ALL, RAY_CAMERA, RAY_GLOSSY, RAY_SHADOW

    add_camera(scene)
    add_plane(scene, "Plain")
    add_plane(scene, "Shy").visible_shadow = False
    held = add_plane(scene, "Held")
    in_collection(scene, held, "HeldOut").holdout = True
    indirect = add_plane(scene, "Indirect")
    in_collection(scene, indirect, "IndirectOnly").indirect_only = True
    source = bpy.data.collections.new("Source")  # instanced only: not in the scene
    member = bpy.data.objects.new("Member", bpy.data.meshes.new("Member"))
    member.data.from_pydata([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [], [(0, 1, 2)])
    member.visible_glossy = False
    source.objects.link(member)
    empty = bpy.data.objects.new("Instancer", None)
    empty.instance_type, empty.instance_collection = 'COLLECTION', source
    empty.visible_camera = False
    empty.is_holdout = True
    scene.collection.objects.link(empty)
    out, _, _ = export_now(scene)
    meshes = {m.name: m for m in out.meshes}
    assert (meshes["Plain"].visibility, meshes["Plain"].holdout) == (RAY_ALL, False)
    assert meshes["Shy"].visibility == RAY_ALL & ~RAY_SHADOW
    assert meshes["Held"].holdout and meshes["Held"].visibility == RAY_ALL
    assert meshes["Indirect"].visibility == RAY_ALL & ~RAY_CAMERA and not meshes["Indirect"].holdout
    instance = meshes["Instancer/Member"]
    assert instance.visibility == RAY_ALL & ~RAY_CAMERA & ~RAY_GLOSSY and instance.holdout


def test_the_command_line_refuses_multi_view_with_a_clear_error(scene, tmp_path):
    """Blender's save_render writes the _L / _R files of a multi-view result but reports failure, so the
    command line says what to do instead of a traceback (F12 and blender -b -E RESTFRAME write every view)."""
    import subprocess
    import sys
    from pathlib import Path

    add_camera(scene)
    add_plane(scene)
    scene.render.use_multiview = True
    blend = tmp_path / "stereo.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    done = subprocess.run([sys.executable, "-m", "restframe_addon", "render", str(blend), "-o", str(tmp_path / "out.png")],
                          cwd=Path(__file__).resolve().parents[2], capture_output=True, text=True, timeout=300)
    assert done.returncode != 0
    assert "restframe: error:" in done.stderr and "Stereoscopy" in done.stderr and "Traceback" not in done.stderr
    assert not list(tmp_path.glob("*out*"))  # nothing half-written


def test_a_panoramic_stereo_camera_is_warned_about(scene):
    from blender_helpers import export_now

    add_camera(scene, type='PANO')
    add_plane(scene)
    assert not any("spherical stereo" in w for w in export_now(scene)[2])
    scene.render.use_multiview = True
    assert sum("spherical stereo" in w for w in export_now(scene)[2]) == 1

"""Ray visibility, holdout, cut-outs and normal maps against closed forms.

A camera 1 above a white Lambert floor looks straight down at a tiny patch of it; a sun shines
on it.  Small quads above the floor block the view, cast the patch's shadow or glow, so each
feature's effect on the patch is a closed form (lit: E cos / pi, shadowed: 0, a glow: its
emission).
"""

import math

import numpy as np
import pytest
from shapes import look_at_camera, quad

from restframe_addon.core import tracer
from restframe_addon.core.frames import build_frames
from restframe_addon.core.render import render_image
from restframe_addon.core.scene import (RAY_ALL, RAY_CAMERA, RAY_GLOSSY, RAY_SHADOW, RAY_TRANSMISSION, Light,
                                        Material, Mesh, RenderSettings, Scene)

WHITE = Material("white", base_color=(1.0, 1.0, 1.0), specular_ior_level=0.0, roughness=1.0)
GREY = Material("grey", base_color=(0.5, 0.5, 0.5), specular_ior_level=0.0, roughness=1.0)
GLOW = Material("glow", base_color=(0.0, 0.0, 0.0), specular_ior_level=0.0, emission=(3.0, 2.0, 1.0))
MIRROR = Material("mirror", base_color=(1.0, 1.0, 1.0), metallic=1.0, roughness=0.0)
CLEAR = Material("clear", base_color=(1.0, 1.0, 1.0), transmission=1.0, ior=1.0, roughness=0.0)
SUN_TILT = math.radians(30)  # the sun's direction from the zenith, toward +x
SUN = 2.0
LIT = SUN * math.cos(SUN_TILT) / math.pi  # the white floor lit by the sun


def rotation_y(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def sun(tilt=SUN_TILT):
    return Light("sun", "SUN", (0, 0, 5.0), matrix=rotation_y(tilt), power=SUN)


def floor(material=0, **kw):
    return Mesh("floor", *quad((0, 0, 0), (100, 100)), material_indices=np.array([material, material]), **kw)


def blocker(material=0, in_view=True, **kw):
    """A small quad halfway up: in the camera's view, or where it shades the patch the camera sees."""
    x = 0.0 if in_view else 0.5 * math.tan(SUN_TILT)
    return Mesh("blocker", *quad((x, 0, 0.5), (0.2, 0.2)), material_indices=np.array([material, material]), **kw)


def render(meshes, materials=(WHITE,), lights=None, camera_z=1.0, **kw):
    camera = look_at_camera((0, 0, camera_z), (0, 0, 0), up=(0, 1, 0), fov_half_tan=0.01)
    scene = Scene(camera=camera, meshes=list(meshes), materials=list(materials),
                  lights=[sun()] if lights is None else lights, world_color=(0.0, 0.0, 0.0))
    kw.setdefault("resolution", (5, 5))
    return render_image(scene, RenderSettings(threads=1, **kw))


def patch(passes, name="Combined"):
    """The mean of a pass over the image."""
    return passes[name].reshape(-1, passes[name].shape[-1]).mean(axis=0)


def test_the_scene_is_what_the_closed_forms_say():
    assert patch(render([floor()]))[:3] == pytest.approx([LIT] * 3, rel=1e-6)
    assert np.all(patch(render([floor(), blocker(in_view=False)]))[:3] == 0.0)  # in its shadow
    assert patch(render([floor(), blocker(1)], (WHITE, GLOW)))[:3] == pytest.approx(GLOW.emission, rel=1e-6)


def test_hidden_from_the_camera_it_still_casts_its_shadow():
    """Visible to Camera off: the camera sees the floor behind it; Indirect Only is the same for direct light."""
    seen = patch(render([floor(), blocker(1, visibility=RAY_ALL & ~RAY_CAMERA)], (WHITE, GLOW)))
    assert seen[:3] == pytest.approx([LIT] * 3, rel=1e-6)
    shadow = render([floor(), blocker(in_view=False, visibility=RAY_ALL & ~RAY_CAMERA)])
    assert np.all(patch(shadow)[:3] == 0.0)
    # the passes see through it too
    assert patch(render([floor(), blocker(visibility=RAY_ALL & ~RAY_CAMERA)]), "Depth")[0] == pytest.approx(1.0, rel=1e-4)


def test_hidden_from_shadow_rays_it_casts_none():
    assert patch(render([floor(), blocker(in_view=False, visibility=RAY_ALL & ~RAY_SHADOW)]))[:3] == \
        pytest.approx([LIT] * 3, rel=1e-6)


def test_hidden_from_glossy_rays_a_mirror_does_not_show_it():
    """A mirror floor reflects a glow above the camera; Visible to Glossy off: the black world instead."""
    glow_above = Mesh("glow", *quad((0, 0, 2.0), (1.0, 1.0)), material_indices=np.array([1, 1]))
    seen = patch(render([floor(), glow_above], (MIRROR, GLOW), lights=[]))
    assert seen[:3] == pytest.approx(GLOW.emission, rel=1e-6)
    glow_above.visibility = RAY_ALL & ~RAY_GLOSSY
    assert np.all(patch(render([floor(), glow_above], (MIRROR, GLOW), lights=[]))[:3] == 0.0)
    glow_above.visibility = RAY_ALL & ~RAY_TRANSMISSION  # another ray type: still reflected
    assert patch(render([floor(), glow_above], (MIRROR, GLOW), lights=[]))[:3] == pytest.approx(GLOW.emission)


def test_hidden_from_transmission_rays_glass_does_not_show_it():
    """A clear pane (IOR 1: no reflection, no bending) in front of a glow."""
    pane = Mesh("pane", *quad((0, 0, 0.5), (1.0, 1.0)), material_indices=np.array([0, 0]))
    glow = floor(1)
    assert patch(render([pane, glow], (CLEAR, GLOW), lights=[]))[:3] == pytest.approx(GLOW.emission, rel=1e-6)
    glow.visibility = RAY_ALL & ~RAY_TRANSMISSION
    assert np.all(patch(render([pane, glow], (CLEAR, GLOW), lights=[]))[:3] == 0.0)


@pytest.mark.parametrize("transparent", [False, True])
def test_a_holdout_is_a_hole_that_still_casts_shadows(transparent):
    held = patch(render([floor(), blocker(holdout=True)], film_transparent=transparent))
    assert np.all(held == 0.0)  # colour and alpha
    assert np.all(patch(render([floor(), blocker(in_view=False, holdout=True)]))[:3] == 0.0)  # its shadow
    around = render([floor(), blocker(holdout=True)], film_transparent=transparent, resolution=(5, 5), camera_z=0.55)
    combined = around["Combined"]
    assert np.all(combined[2, 2] == 0.0)
    # a holdout seen in a mirror ends the path (black) but is no hole
    mirror = patch(render([floor(), Mesh("hole", *quad((0, 0, 2.0), (1.0, 1.0)), holdout=True)], (MIRROR,), lights=[],
                          film_transparent=transparent))
    assert mirror[3] == 1.0 and np.all(mirror[:3] == 0.0)


def texture(alpha_left, alpha_right, size=64):
    """An alpha image: its left half (u < 0.5) ``alpha_left``, its right half ``alpha_right``."""
    image = np.empty((size, size, 1), dtype=np.float32)
    image[:, : size // 2], image[:, size // 2:] = alpha_left, alpha_right
    return image


def uv_quad(center, size):
    """A quad with UVs (0, 0) .. (1, 1) from its -x -y corner: (vertices, triangles, corner UVs)."""
    vertices, triangles = quad(center, size)
    corner = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float64)
    return vertices, triangles, corner[triangles]


def test_cut_outs_from_an_alpha_image_show_what_is_behind():
    """The camera looks at the middle of one half of a quad whose alpha image is 0 there and 1 on the other half."""
    cut = Material("cut", base_color=(0, 0, 0), specular_ior_level=0.0, emission=(0.0, 1.0, 0.0),
                   alpha_texture=texture(0.0, 1.0))
    for x, expected in ((0.25, GLOW.emission), (-0.25, (0.0, 1.0, 0.0))):
        vertices, triangles, uvs = uv_quad((x, 0, 0.5), (1.0, 1.0))
        card = Mesh("card", vertices, triangles, material_indices=np.array([2, 2]), corner_uvs=uvs)
        seen = patch(render([floor(1), card], (WHITE, GLOW, cut), lights=[], samples=4))
        assert seen[:3] == pytest.approx(expected, abs=1e-6)


def test_partial_alpha_mixes_the_surface_and_what_is_behind_by_chance():
    """Alpha 0.3: 30% of the samples stop at the card (green), 70% see the glow behind; the film's
    alpha is 0.3 over a transparent background."""
    card = Mesh("card", *quad((0, 0, 0.5), (1.0, 1.0)), material_indices=np.array([2, 2]))
    ghost = Material("ghost", base_color=(0, 0, 0), specular_ior_level=0.0, emission=(0.0, 1.0, 0.0), alpha=0.3)
    samples = 64
    seen = patch(render([floor(1), card], (WHITE, GLOW, ghost), lights=[], samples=samples, resolution=(8, 8)))
    expected = 0.3 * np.array([0.0, 1.0, 0.0]) + 0.7 * np.array(GLOW.emission)
    noise = math.sqrt(0.3 * 0.7 / (samples * 64)) * 3.0  # |glow - green| <= 3
    assert seen[:3] == pytest.approx(expected, abs=4 * noise)
    alone = patch(render([card], (WHITE, GLOW, ghost), lights=[], samples=samples, resolution=(8, 8),
                         film_transparent=True))
    assert alone[3] == pytest.approx(0.3, abs=4 * math.sqrt(0.21 / (samples * 64)))
    # the passes see surfaces at least half opaque (Cycles' Alpha Threshold): the floor's depth
    assert patch(render([floor(1), card], (WHITE, GLOW, ghost), lights=[]), "Depth")[0] == pytest.approx(1.0, rel=1e-4)


@pytest.mark.parametrize("alpha, lit", [(0.0, 1.0), (1.0, 0.0), (0.5, 0.5)])
def test_shadows_through_cut_outs(alpha, lit):
    card = Material("card", base_color=(1, 1, 1), specular_ior_level=0.0, alpha=alpha)
    samples = 64
    seen = patch(render([floor(), blocker(1, in_view=False)], (WHITE, card), samples=samples, resolution=(8, 8)))
    tolerance = 4 * math.sqrt(0.25 / (samples * 64)) * LIT if 0 < alpha < 1 else 1e-6
    assert seen[0] == pytest.approx(lit * LIT, abs=tolerance)


def normal_image(normal, size=4):
    """A constant tangent-space normal map: the colour (n + 1) / 2 (Non-Color)."""
    return np.broadcast_to((np.asarray(normal, dtype=np.float32) + 1.0) / 2.0, (size, size, 3)).copy()


@pytest.mark.parametrize("tilt, strength", [(math.radians(20), 1.0), (math.radians(-25), 1.0),
                                            (math.radians(20), 0.5), (math.radians(20), 0.0)])
def test_a_normal_map_tilts_the_shading_normal_along_the_uv_tangent(tilt, strength):
    """The floor's U runs along +x: a normal map tilted by ``tilt`` toward +x in tangent space lights
    it as a floor tilted so: E cos(sun tilt - normal tilt) / pi (with the strength, as Cycles
    mixes: n + strength (N - n), normalised)."""
    mapped = Material("bumpy", base_color=(1, 1, 1), specular_ior_level=0.0, roughness=1.0,
                      normal_texture=normal_image((math.sin(tilt), 0.0, math.cos(tilt))), normal_strength=strength)
    vertices, triangles, uvs = uv_quad((0, 0, 0), (100, 100))
    ground = Mesh("ground", vertices, triangles, corner_uvs=uvs)
    n = np.array([0.0, 0.0, 1.0]) + strength * (np.array([math.sin(tilt), 0.0, math.cos(tilt)]) - [0.0, 0.0, 1.0])
    effective = math.atan2(n[0], n[2])
    passes = render([ground], (mapped,))
    assert patch(passes)[0] == pytest.approx(SUN * math.cos(SUN_TILT - effective) / math.pi, rel=1e-5)
    # the Normal pass shows the mapped normal, as Cycles' does
    np.testing.assert_allclose(patch(passes, "Normal"), [math.sin(effective), 0.0, math.cos(effective)], atol=1e-6)


def test_a_normal_mapped_hits_uvs_are_worked_out_once_a_shading_batch(monkeypatch):
    """The shading's base colour reuses the UVs the normal map looked up (one hit_uv a frame and
    batch, where it took two), and the image stays the closed form."""
    from restframe_addon.core import shading

    calls = {"hit_uv": 0, "batches": 0}
    hit_uv, shade = shading.hit_uv, shading.Shader._shade_surfaces

    def counted_uv(*args, **kw):
        calls["hit_uv"] += 1
        return hit_uv(*args, **kw)

    def counted_batch(self, *args, **kw):
        before = calls["hit_uv"]
        out = shade(self, *args, **kw)
        calls["batches"] += 1
        assert calls["hit_uv"] - before == len(args[0])  # one per frame of the batch
        return out

    monkeypatch.setattr(shading, "hit_uv", counted_uv)
    monkeypatch.setattr(shading.Shader, "_shade_surfaces", counted_batch)
    tilt = math.radians(20)
    mapped = Material("bumpy", base_color=(1, 1, 1), specular_ior_level=0.0, roughness=1.0,
                      normal_texture=normal_image((math.sin(tilt), 0.0, math.cos(tilt))))
    vertices, triangles, uvs = uv_quad((0, 0, 0), (100, 100))
    seen = patch(render([Mesh("ground", vertices, triangles, corner_uvs=uvs)], (mapped,), passes=()))
    assert calls["batches"] > 0
    assert seen[0] == pytest.approx(SUN * math.cos(SUN_TILT - tilt) / math.pi, rel=1e-5)


def test_a_normal_map_follows_the_uv_layout():
    """V along +y: a green tilt leans the normal toward +y; with the UVs mirrored (U along -x) a red tilt leans it toward -x."""
    tilt = math.radians(25)
    c, s = math.cos(SUN_TILT), math.sin(SUN_TILT)
    lamp = [Light("sun", "SUN", (0, 0, 5.0), matrix=np.array([[1, 0, 0], [0, c, s], [0, -s, c]]), power=SUN)]
    toward_y = lamp[0].matrix[:, 2]
    assert toward_y[1] > 0 and toward_y[0] == pytest.approx(0.0)
    green = Material("green", base_color=(1, 1, 1), specular_ior_level=0.0, roughness=1.0,
                     normal_texture=normal_image((0.0, math.sin(tilt), math.cos(tilt))))
    vertices, triangles, uvs = uv_quad((0, 0, 0), (100, 100))
    seen = patch(render([Mesh("ground", vertices, triangles, corner_uvs=uvs)], (green,), lights=lamp))
    normal = np.array([0.0, math.sin(tilt), math.cos(tilt)])
    assert seen[0] == pytest.approx(SUN * float(normal @ toward_y) / math.pi, rel=1e-5)
    red = Material("red", base_color=(1, 1, 1), specular_ior_level=0.0, roughness=1.0,
                   normal_texture=normal_image((math.sin(tilt), 0.0, math.cos(tilt))))
    mirrored = uvs.copy()
    mirrored[..., 0] = 1.0 - mirrored[..., 0]
    seen = patch(render([Mesh("ground", vertices, triangles, corner_uvs=mirrored)], (red,)))
    assert seen[0] == pytest.approx(SUN * math.cos(SUN_TILT + tilt) / math.pi, rel=1e-5)


def test_many_hidden_layers_are_all_passed():
    layers = [Mesh(f"layer{i}", *quad((0, 0, 0.1 + 0.01 * i), (1.0, 1.0)), visibility=RAY_ALL & ~RAY_CAMERA)
              for i in range(40)]
    assert patch(render([floor(), *layers], lights=[sun(0.0)]))[0] == pytest.approx(0.0)  # their shadow
    assert patch(render([floor(), *[Mesh(m.name, m.vertices, m.triangles, visibility=RAY_ALL & ~RAY_CAMERA & ~RAY_SHADOW)
                                    for m in layers]], lights=[sun(0.0)]))[0] == pytest.approx(SUN / math.pi)


def test_without_hidden_surfaces_the_tracer_does_no_extra_work():
    scene = Scene(camera=look_at_camera((0, 0, 1.0), (0, 0, 0)), meshes=[floor()])
    frames = build_frames(scene)
    assert frames.hidden_rays == 0 and not frames.has_holdout
    d = np.array([[0.0, 0.0, -1.0]])
    args = (frames, frames.camera, np.zeros(1), np.array([[0.0, 0.0, 1.0]]), d, 0.0, np.inf)
    plain = tracer.trace_nearest(*args)
    typed = tracer.trace_nearest(*args, ray=RAY_CAMERA)
    assert typed.s[0] == plain.s[0] == pytest.approx(1.0)

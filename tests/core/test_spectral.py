"""Spectral Doppler colour: data, uplift, and the physics of shifted spectra against direct integration."""

import math
import warnings

import numpy as np
import pytest
from shapes import look_at_camera, quad, uv_sphere

from restframe_addon.core import spectral
from restframe_addon.core.prepared import prepare
from restframe_addon.core.render import render_image
from restframe_addon.core.sampling import Samples
from restframe_addon.core.scene import Light, Material, Mesh, RenderSettings, Scene, Velocity

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    import colour

H, C, K = 6.62607015e-34, 299792458.0, 1.380649e-23


def planck_absolute(lam_nm, temperature):
    lam = np.asarray(lam_nm, float) * 1e-9
    return 2 * H * C**2 / lam**5 / np.expm1(H * C / (lam * K * temperature))


def gamma_of(beta):
    return 1.0 / math.sqrt((1.0 - beta) * (1.0 + beta))


def doppler_head_on(beta):
    """D for a source approaching (beta > 0) or receding (beta < 0) along the line of sight."""
    return math.sqrt((1 + beta) / (1 - beta))


# ---------------------------------------------------------------- data and uplift

def test_bundled_cie_data_matches_colour_science():
    data = spectral.colour_data()
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(colour.SpectralShape(360, 830, 1))
    assert np.array_equal(data["wavelength_nm"], cmfs.wavelengths)
    assert np.allclose(data["cmf_xyz"], cmfs.values, rtol=0, atol=1e-12)
    space = colour.RGB_COLOURSPACES["ITU-R BT.709"]
    assert np.allclose(data["xyz_to_rgb"], space.matrix_XYZ_to_RGB, atol=1e-12)
    assert np.allclose(data["bradford"], colour.adaptation.CAT_BRADFORD, atol=1e-12)


@pytest.mark.parametrize("count", [8, 32, 470])
def test_white_black_body_is_rec709_white(count):
    q = spectral.quadrature(count)
    assert np.allclose(q.observed_rgb(q.white[None]), 1.0, atol=1e-12)


@pytest.mark.parametrize("count", [16, 32, 470])
def test_uplift_reproduces_every_colour_exactly_and_stays_a_reflectance(count):
    q = spectral.quadrature(count)
    rng = np.random.default_rng(5)
    rgb = np.concatenate([rng.uniform(0, 1, (300, 3)), np.eye(3), [[1, 1, 1], [0, 0, 0], [0.18, 0.18, 0.18]]])
    coeffs = q.fit_reflectance(rgb)
    assert np.max(np.abs(q.reflectance_rgb(coeffs) - rgb)) < 1e-8
    lam = np.broadcast_to(np.linspace(100, 5000, 300), (len(rgb), 300))
    r = spectral.sigmoid_spectrum(coeffs, lam)
    assert np.all((r >= 0) & (r <= 1))


def test_uplift_agrees_with_colour_science_jakob2019():
    """Our solver and colour-science's find the same sigmoid spectrum for the same colour
    under the same illuminant (the model has one exact solution per colour)."""
    q = spectral.quadrature(470)
    shape = colour.SpectralShape(360, 830, 1)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(shape)
    illuminant = colour.sd_blackbody(spectral.WHITE_TEMPERATURE, shape)
    lam = cmfs.wavelengths[None]
    for rgb in ([0.8, 0.2, 0.1], [0.2, 0.6, 0.3], [0.3, 0.3, 0.9]):
        ours = spectral.sigmoid_spectrum(q.fit_reflectance([rgb]), lam)[0]
        # the XYZ of our spectrum under the illuminant (Y of the illuminant = 1), as colour's target
        p = illuminant.values
        xyz = (ours * p) @ cmfs.values / (p @ cmfs.values[:, 1])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sd = colour.recovery.XYZ_to_sd_Jakob2019(xyz, cmfs=cmfs, illuminant=illuminant,
                                                     optimisation_kwargs={"max_error": 1e-4})
        theirs = sd.copy().align(shape).values
        assert np.max(np.abs(theirs - ours)) < 1e-4, rgb


# ---------------------------------------------------------------- physics through the renderer

def emitter_scene(beta, k=470, searchlight=True, color=(1.0, 1.0, 1.0), distance=20.0):
    """A camera at the origin looking +y at a large emissive wall moving along -y with beta
    (beta > 0 approaching); the centre pixel looks along the motion."""
    wall = quad((0, distance, 0), (1e4, 1e4), normal_axis=1)
    scene = Scene(camera=look_at_camera((0, 0, 0), (0, 1, 0), fov_half_tan=0.01),
                  meshes=[Mesh("wall", *wall, velocity=Velocity((0, -beta, 0)), pivot=(0, distance, 0))],
                  materials=[Material("glow", base_color=(0, 0, 0), emission=color, specular_ior_level=0.0)],
                  world_color=(0, 0, 0))
    settings = RenderSettings(resolution=(3, 3), threads=1, doppler_mode="SPECTRAL", spectral_samples=k,
                              searchlight=searchlight)
    return scene, settings


def centre_values(renderer):
    """Spectral radiance (K,) of the centre camera ray, at the quadrature wavelengths."""
    pixel = np.array([4])
    tau, x, d, s_lo, s_hi = renderer.rays(np.array([1.5]), np.array([1.5]))
    lam = renderer.colour.camera_wavelengths(pixel, pixel * 0)
    values, hits = renderer.shader.radiance(renderer.frames.camera, tau, x, d, s_lo, s_hi, 0, Samples(pixel, pixel * 0),
                                            lam)
    return values[0], lam[0], 1.0 / hits.w[0]


@pytest.mark.parametrize("beta", [-0.9, -0.5, 0.0, 0.5, 0.9])
@pytest.mark.parametrize("k", [32, 470])
def test_moving_black_body_looks_like_a_black_body_at_d_times_t(beta, k):
    """D^5 B_T(lambda D) = B_{D T}(lambda): a thermal emitter seen with Doppler factor D is a black
    body at D T, in absolute radiance.  White emission is the 6504 K black body (1 at 560 nm)."""
    scene, settings = emitter_scene(beta, k)
    passes = render_image(scene, settings)
    d = doppler_head_on(beta)
    assert passes["Doppler"][1, 1, 0] == pytest.approx(d, rel=1e-6)
    q = spectral.quadrature(k)
    t = spectral.WHITE_TEMPERATURE
    expected = q.observed_rgb((planck_absolute(q.wavelengths, d * t) / planck_absolute(560.0, t))[None])[0]
    expected = np.maximum(expected, 0.0)  # a deep red black body lies just outside Rec.709: clipped
    assert passes["Combined"][1, 1, :3] == pytest.approx(expected, rel=2e-6, abs=1e-12)


def test_receding_at_0_9c_reddens_and_dims():
    rest = render_image(*emitter_scene(0.0, 64))["Combined"][1, 1, :3]
    away = render_image(*emitter_scene(-0.9, 64))["Combined"][1, 1, :3]
    lum = np.array([0.2126, 0.7152, 0.0722])
    assert away @ lum < 1e-2 * (rest @ lum)
    assert away[0] / away.sum() > rest[0] / rest.sum() + 0.2
    assert away[2] / away.sum() < rest[2] / rest.sum() - 0.2


@pytest.mark.parametrize("beta", [-0.6, 0.3, 0.8])
def test_flat_spectra_scale_as_d5_d3_and_the_total_as_d4(beta):
    """Luminance of a spectrum flat in wavelength scales as D^5, flat in frequency (1/lambda^2) as
    D^3; the wavelength-integrated radiance of any line as D^4 -- integrals over the rendered spectra."""
    d = doppler_head_on(beta)
    q = spectral.quadrature(470)
    y_bar = q.weights[:, 1]
    for spectrum, power in ((lambda lam: np.ones_like(lam), 5), (lambda lam: 1e5 / lam**2, 3)):
        seen = []
        for b in (0.0, beta):
            scene, settings = emitter_scene(b)
            renderer = prepare(scene, settings)
            renderer.colour.emission = lambda mat, lam, f=spectrum: f(lam)
            values, lam, doppler = centre_values(renderer)
            seen.append(values @ y_bar)
        assert seen[1] / seen[0] == pytest.approx(d**power, rel=1e-9)
    # a line well inside the band, after the shift too: total radiance ratio D^4
    line = lambda lam: np.exp(-0.5 * ((lam - 600.0) / 8.0) ** 2)
    totals = []
    for b in (0.0, beta):
        scene, settings = emitter_scene(b)
        renderer = prepare(scene, settings)
        renderer.colour.emission = lambda mat, lam: line(lam)
        values, lam, _ = centre_values(renderer)
        totals.append(values.sum() * 1.0)  # 1 nm nodes
    if 360 < 600 / d - 40 and 600 / d + 40 < 830:
        assert totals[1] / totals[0] == pytest.approx(d**4, rel=1e-6)


@pytest.mark.parametrize("target_d", [0.8, 1.0, 1.25])
def test_monochrome_emitter_moves_along_the_spectral_locus(target_d):
    """A narrow line at 550 nm seen with Doppler factor D has the chromaticity of the locus at 550/D."""
    beta = (target_d**2 - 1) / (target_d**2 + 1)
    scene, settings = emitter_scene(beta)
    renderer = prepare(scene, settings)
    renderer.colour.emission = lambda mat, lam: np.exp(-0.5 * ((lam - 550.0) / 3.0) ** 2)
    values, lam, d = centre_values(renderer)
    assert d == pytest.approx(target_d, rel=1e-9)
    xyz = values @ spectral.quadrature(470).weights
    xy = xyz[:2] / xyz.sum()
    locus = spectral.cmf(np.array(550.0 / target_d))
    assert np.allclose(xy, locus[:2] / locus.sum(), atol=3e-3)


@pytest.mark.parametrize("beta", [0.5, 0.9])
def test_static_light_on_an_approaching_wall_matches_direct_integration(beta):
    """A static lamp at the camera lights a white wall approaching head-on.  The wall sees the lamp
    with D_l = gamma (1 + beta) at the retarded distance r = D_l * s (s = the Depth pass, the
    lamp-frame distance), the camera sees the wall with D_c = D_l:
        L(lambda) = D_c^5 / pi * I(lambda D_c D_l) D_l^5 / r^2,
    integrated here on a fine grid independently of the renderer's quadrature."""
    wall = quad((0, 20.0, 0), (1e4, 1e4), normal_axis=1)
    scene = Scene(camera=look_at_camera((0, 0, 0), (0, 1, 0), fov_half_tan=0.01),
                  meshes=[Mesh("wall", *wall, velocity=Velocity((0, -beta, 0)), pivot=(0, 20.0, 0))],
                  materials=[Material("white", base_color=(1, 1, 1), specular_ior_level=0.0)],
                  lights=[Light("lamp", "POINT", (0.0, 0.0, 0.0), power=1000.0)], world_color=(0, 0, 0))
    passes = render_image(scene, RenderSettings(resolution=(3, 3), threads=1, doppler_mode="SPECTRAL",
                                                spectral_samples=256))
    s = float(passes["Depth"][1, 1, 0])
    d = doppler_head_on(beta)
    lam = np.linspace(360.0, 830.0, 47001)
    radiance = d**5 / math.pi * (1000.0 / (4 * math.pi)) * spectral.white_spectrum(lam * d * d) * d**5 / (d * s) ** 2
    xyz = np.trapz(radiance[:, None] * spectral.cmf(lam), lam, axis=0)
    expected = spectral.quadrature(470).xyz_to_rgb @ xyz
    assert passes["Combined"][1, 1, :3] == pytest.approx(expected, rel=2e-3)
    # the same wall carrying its lamp along is a different picture: only the camera's D acts
    scene.lights[0].velocity = Velocity((0, -beta, 0))
    scene.lights[0].pivot = (0, 0, 0)
    carried = render_image(scene, RenderSettings(resolution=(3, 3), threads=1, doppler_mode="SPECTRAL",
                                                 spectral_samples=256))["Combined"][1, 1, :3]
    assert not np.allclose(carried, passes["Combined"][1, 1, :3], rtol=0.1)


def rich_scene(beta=0.0):
    texture = np.random.default_rng(2).uniform(0, 1, (8, 8, 3))
    ball = uv_sphere((0, 0, 0.5), 1.0, 32, 16)
    floor = quad((0, 0, -0.5), (8, 8))
    uvs = np.random.default_rng(3).uniform(0, 1, (2, 3, 2))
    mats = [Material("red", base_color=(0.8, 0.2, 0.1), roughness=0.4),
            Material("tex", base_color=(1, 1, 1), base_color_texture=texture),
            Material("mirror", base_color=(1, 1, 1), metallic=1.0, roughness=0.0),
            Material("glow", base_color=(0, 0, 0), emission=(0.5, 2.0, 0.7))]
    mirror = quad((0, 3, 0), (4, 4), normal_axis=1)
    glow = quad((-2.5, 0, 0.5), (1, 1), normal_axis=0)
    return Scene(camera=look_at_camera((1.0, -7, 2.0), (0, 0, 0.3)),
                 meshes=[Mesh("ball", *ball, velocity=Velocity((beta, 0, 0))),
                         Mesh("floor", *floor, material_indices=np.ones(2, int), corner_uvs=uvs),
                         Mesh("mirror", *mirror, material_indices=np.full(2, 2)),
                         Mesh("glow", *glow, material_indices=np.full(2, 3))],
                 materials=mats, world_color=(0.05, 0.06, 0.09), tau_obs=2.0,
                 lights=[Light("key", "POINT", (2, -3, 4), power=900.0),
                         Light("sun", "SUN", (0, 0, 9), power=1.5, matrix=np.eye(3)),
                         Light("warm", "AREA", (-2, -2, 3), power=300.0, temperature=6504.0)])


@pytest.mark.parametrize("k", [3, 4, 6])
def test_very_few_wavelengths_still_fit_and_render(k):
    """Rank-deficient uplift fits (few wavelengths) stay solvable: exact at rest, finite when moving."""
    q = spectral.quadrature(k)
    rgb = np.random.default_rng(9).uniform(0, 1, (50, 3))
    assert np.all(np.isfinite(q.reflectance_rgb(q.fit_reflectance(rgb))))
    for beta in (0.0, 0.5):
        passes = render_image(*emitter_scene(beta, k))
        assert np.all(np.isfinite(passes["Combined"]))
    rest = render_image(*emitter_scene(0.0, k))["Combined"][1, 1, :3]
    assert rest == pytest.approx([1.0, 1.0, 1.0], rel=1e-6)


def test_nothing_moving_spectral_equals_rgb():
    """With nothing moving, Spectral colour reproduces the RGB render (1e-3 asked; exact here)."""
    rgb = render_image(rich_scene(), RenderSettings(resolution=(40, 30), samples=2, threads=1))["Combined"]
    spec = render_image(rich_scene(), RenderSettings(resolution=(40, 30), samples=2, threads=1,
                                                     doppler_mode="SPECTRAL", spectral_samples=24))["Combined"]
    assert np.max(np.abs(spec - rgb) / np.maximum(np.abs(rgb), 1e-3)) < 1e-3


def test_exposure_normalisation_restores_the_mean_brightness():
    """Approaching at 0.9c the image blows out; normalised it keeps the mean luminance of the
    geometry-only view (searchlight off, no colour shift)."""
    lum = np.array([0.2126, 0.7152, 0.0722])
    common = dict(resolution=(48, 48), threads=1, doppler_mode="SPECTRAL", spectral_samples=24)
    scene = emitter_scene(0.9, 24, color=(0.8, 0.8, 0.8))[0]
    scene.materials[0].base_color = (0.5, 0.5, 0.5)
    scene.lights = [Light("lamp", "POINT", (0.0, 0.0, 0.0), power=1e5, velocity=Velocity((0, -0.9, 0)))]
    plain = render_image(scene, RenderSettings(resolution=(48, 48), threads=1, searchlight=False))["Combined"][..., :3]
    blown = render_image(scene, RenderSettings(**common))["Combined"][..., :3]
    fixed = render_image(scene, RenderSettings(normalize_exposure=True, **common))["Combined"][..., :3]
    assert (blown @ lum).mean() > 10 * (plain @ lum).mean()
    assert (fixed @ lum).mean() == pytest.approx((plain @ lum).mean(), rel=0.05)

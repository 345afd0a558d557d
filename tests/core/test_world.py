"""The world light: Blender's equirectangular and Mapping conventions, importance sampling of an
environment image, the aberration Jacobian (numerical integration and closed form), and the
uniform-world closed forms of a moving Lambertian surface."""

import math

import mpmath
import numpy as np
import pytest

from restframe_addon.core import sampling, world
from restframe_addon.core.lorentz import Boost


def gamma_of(b):
    return 1.0 / math.sqrt((1.0 - b) * (1.0 + b))


def unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def grid(axis=(0.0, 0.0, 1.0), n_theta=800, n_phi=400, theta_max=math.pi):
    """Midpoint quadrature over directions within theta_max of axis: (directions, solid angles)."""
    z = unit(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = unit(np.cross(helper, z))
    y = np.cross(z, x)
    dt, dp = theta_max / n_theta, 2 * math.pi / n_phi
    th, ph = np.meshgrid((np.arange(n_theta) + 0.5) * dt, (np.arange(n_phi) + 0.5) * dp, indexing="ij")
    th, ph = th.ravel(), ph.ravel()
    d = (np.sin(th) * np.cos(ph))[:, None] * x + (np.sin(th) * np.sin(ph))[:, None] * y + np.cos(th)[:, None] * z
    return d, np.sin(th) * dt * dp


def test_image(h=24, w=48, sun=(16, 9), sun_value=2e4, seed=4):
    """A sky-like image (smooth gradient plus noise) with one very bright pixel."""
    rng = np.random.default_rng(seed)
    v = (np.arange(h)[:, None] + 0.5) / h
    sky = np.stack([0.2 + 0.6 * v, 0.3 + 0.5 * v, 0.8 + 0.0 * v], axis=-1) * np.ones((h, w, 1))
    image = sky * rng.uniform(0.5, 1.5, (h, w, 1))
    image[sun] = sun_value * np.array([1.0, 0.9, 0.7])
    return image


test_image.__test__ = False  # a helper, not a test


# ---------------------------------------------------------------------------- conventions
def test_equirectangular_matches_cycles_range_formula():
    """Cycles: u = (atan2(y, x) - pi) / (-2 pi), v = (acos(z) - pi) / (-pi); +X is the image centre."""
    rng = np.random.default_rng(2)
    d = rng.normal(size=(1000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    u, v = world.direction_to_equirectangular(d)
    cycles_u = (np.arctan2(d[:, 1], d[:, 0]) - math.pi) / (-2 * math.pi)
    cycles_v = (np.arccos(d[:, 2]) - math.pi) / (-math.pi)
    assert np.allclose(u, cycles_u % 1.0, atol=1e-12) and np.allclose(v, cycles_v, atol=1e-12)
    assert np.allclose(world.equirectangular_to_direction(u, v), d, atol=1e-12)
    axes = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [0, 0, -1.0]])
    u, v = world.direction_to_equirectangular(axes)
    assert np.allclose(u[:2], [0.5, 0.25]) and np.allclose(v, [0.5, 0.5, 1.0, 0.0])


def test_euler_rotation_is_blenders_xyz():
    """Against mathutils.Euler((0.1, 0.2, 0.3), 'XYZ').to_matrix() (Blender 5.0, float32) and Rz Ry Rx."""
    mathutils_matrix = [[0.936293363571, -0.275095850229, 0.218350663781],
                        [0.289629489183, 0.956425070763, -0.036957010627],
                        [-0.198669329286, 0.097843393683, 0.975170314312]]
    assert np.allclose(world.euler_rotation((0.1, 0.2, 0.3)), mathutils_matrix, atol=1e-7)

    def rot(axis, a):
        c, s = math.cos(a), math.sin(a)
        i, j = [(1, 2), (2, 0), (0, 1)][axis]
        m = np.eye(3)
        m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
        return m

    e = (1.1, -0.4, 2.5)
    assert np.allclose(world.euler_rotation(e), rot(2, e[2]) @ rot(1, e[1]) @ rot(0, e[0]), atol=1e-14)
    assert np.allclose(world.mapping_rotation(e, "TEXTURE"), world.euler_rotation(e).T)
    with pytest.raises(ValueError, match="Mapping node"):
        world.mapping_rotation(e, "WARP")


def test_image_lookup_bilinear_between_pixel_centres_and_closest():
    image = np.arange(12, dtype=np.float64).reshape(3, 4, 1) * np.ones(3)
    texels = world.Texels(image)
    centre = world.image_lookup(texels, np.array([1.5 / 4]), np.array([0.5 / 3]))
    assert np.allclose(centre, image[0, 1])
    between = world.image_lookup(texels, np.array([2.0 / 4]), np.array([1.0 / 3]))
    assert np.allclose(between, image[0:2, 1:3].mean(axis=(0, 1)))
    wrapped = world.image_lookup(texels, np.array([0.0]), np.array([0.5 / 3]))  # half way to the last column
    assert np.allclose(wrapped, 0.5 * (image[0, 0] + image[0, 3]))
    closest = world.image_lookup(texels, np.array([0.99 / 4, 3.2 / 4]), np.array([2.9 / 3, 0.1 / 3]), "Closest")
    assert np.allclose(closest, [image[2, 0], image[0, 3]])


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("channels", [1, 3, 4])
def test_texels_look_up_the_bits_of_a_plain_bilinear_repeat_lookup(dtype, channels):
    """world.Texels (a border row and column, RGB padded to 4 channels) looks up bit for bit what
    the bilinear blend written out with modulo indexing gives, and the nearest pixel (Closest)."""
    rng = np.random.default_rng(7)
    h, w = 5, 8
    image = rng.random((h, w, channels)).astype(dtype)
    texels = world.Texels(image)
    assert texels.pixels.shape == ((h + 1) * (w + 1), 4 if channels == 3 else channels)
    u, v = rng.uniform(-2.0, 3.0, 1000), rng.uniform(-2.0, 3.0, 1000)
    fx, fy = u * w - 0.5, v * h - 0.5
    x0, y0 = np.floor(fx), np.floor(fy)
    fx, fy = fx - x0, fy - y0
    x0, y0 = x0.astype(int) % w, y0.astype(int) % h
    x1, y1 = (x0 + 1) % w, (y0 + 1) % h
    expected = ((1 - fx) * (1 - fy))[:, None] * image[y0, x0]
    expected += ((1 - fy) * fx)[:, None] * image[y0, x1]
    expected += ((1 - fx) * fy)[:, None] * image[y1, x0]
    expected += (fx * fy)[:, None] * image[y1, x1]
    looked_up = world.image_lookup(texels, u, v)
    assert looked_up.dtype == np.float64
    np.testing.assert_array_equal(looked_up, expected)
    nearest = image[np.floor(v * h).astype(int) % h, np.floor(u * w).astype(int) % w]
    np.testing.assert_array_equal(world.image_lookup(texels, u, v, "Closest"), nearest)
    np.testing.assert_array_equal(world.image_lookup(texels, u, v, channels=1), expected[:, :1])


def test_colour_texels_blend_in_their_pixels_precision_to_a_few_float32_steps():
    """Texels(colour=True) of a float32 image blend in float32: within 3 float32 steps of the
    brightest pixel of the image of the float64 blend (Linear; Closest is a copy either way); a
    float64 image blends in float64 whatever ``colour`` says (the same bits)."""
    rng = np.random.default_rng(5)
    image = (rng.random((16, 32, 3)) ** 4 * 50.0).astype(np.float32)  # dark and bright pixels side by side
    u, v = rng.uniform(-3.0, 4.0, 20000), rng.uniform(-3.0, 4.0, 20000)
    fast, exact = (world.image_lookup(world.Texels(image, colour), u, v) for colour in (True, False))
    assert fast.dtype == exact.dtype == np.float64 and not np.array_equal(fast, exact)  # the trade is exercised
    np.testing.assert_allclose(fast, exact, rtol=0.0, atol=3 * np.finfo(np.float32).eps * image.max())
    for interpolation, dtype in (("Closest", np.float32), ("Linear", np.float64)):
        np.testing.assert_array_equal(*(world.image_lookup(world.Texels(image.astype(dtype), colour), u, v,
                                                           interpolation) for colour in (True, False)))


def test_mapping_rotates_the_lookup_and_the_samples():
    image = test_image()
    rotation = world.mapping_rotation((0.3, -0.2, 1.2))
    plain = world.EnvironmentWorld(image)
    turned = world.EnvironmentWorld(image, mapping=rotation)
    rng = np.random.default_rng(8)
    d = rng.normal(size=(500, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    assert np.allclose(turned.radiance(d), plain.radiance(d @ rotation.T))
    assert np.allclose(turned.pdf(d), plain.pdf(d @ rotation.T))
    u1, u2 = rng.random(500), rng.random(500)
    assert np.allclose(turned.sample(u1, u2)[0] @ rotation.T, plain.sample(u1, u2)[0], atol=1e-12)


def test_bad_environments_are_refused_with_the_worlds_name():
    with pytest.raises(ValueError, match="Sky: the environment image"):
        world.EnvironmentWorld(np.ones((4, 8)), name="Sky")
    with pytest.raises(ValueError, match="Sky: .*NaN"):
        world.EnvironmentWorld(np.full((4, 8, 3), np.nan), name="Sky")
    with pytest.raises(ValueError, match="Sky: environment interpolation 'Cubic'"):
        world.EnvironmentWorld(np.ones((4, 8, 3)), interpolation="Cubic", name="Sky")
    with pytest.raises(ValueError, match="Sky: the environment mapping must be a rotation"):
        world.EnvironmentWorld(np.ones((4, 8, 3)), mapping=2.0 * np.eye(3), name="Sky")


def test_black_worlds_say_so():
    assert world.UniformWorld((0.0, 0.0, 0.0), 5.0).is_black
    assert world.UniformWorld((0.05, 0.05, 0.05), 0.0).is_black
    assert not world.UniformWorld((0.05, 0.05, 0.05), 1.0).is_black
    black = world.EnvironmentWorld(np.zeros((4, 8, 3)))
    assert black.is_black and np.all(black.pdf(np.array([[0.0, 0.0, 1.0]])) == 0.0)


# ---------------------------------------------------------------------------- importance sampling
@pytest.mark.parametrize("interpolation", ["Linear", "Closest"])
def test_environment_pdf_is_normalised_and_samples_follow_it(interpolation):
    env = world.EnvironmentWorld(test_image(), strength=0.7, mapping=world.mapping_rotation((0.2, 0.1, 0.5)),
                                 interpolation=interpolation)
    d, omega = grid(n_theta=1200, n_phi=1200)
    assert np.sum(env.pdf(d) * omega) == pytest.approx(1.0, abs=2e-3)
    n = 400_000
    rng = np.random.default_rng(12)
    samples, pdf = env.sample(rng.random(n), rng.random(n))
    assert np.allclose(np.linalg.norm(samples, axis=1), 1.0, atol=1e-12)
    assert np.allclose(pdf, env.pdf(samples))
    # histogram of samples against the pdf, in bins of the texture's own (u, v)
    t = samples @ env.mapping.T
    u, v = world.direction_to_equirectangular(t)
    bins = (24, 12)
    observed, _, _ = np.histogram2d(u, v, bins, [[0, 1], [0, 1]])
    du, dv = 1.0 / 480, 1.0 / 480
    uu, vv = np.meshgrid((np.arange(480) + 0.5) * du, (np.arange(480) + 0.5) * dv, indexing="ij")
    tt = world.equirectangular_to_direction(uu.ravel(), vv.ravel())
    jac = 2 * math.pi * math.pi * np.sin(math.pi * vv.ravel()) * du * dv  # dOmega = 2 pi^2 sin(pi v) du dv
    expected, _, _ = np.histogram2d(uu.ravel(), vv.ravel(), bins, [[0, 1], [0, 1]],
                                    weights=env.pdf(tt @ env.mapping) * jac * n)
    keep = expected > 20
    chi2 = np.sum((observed[keep] - expected[keep]) ** 2 / expected[keep])
    dof = keep.sum()
    assert chi2 < dof + 6 * math.sqrt(2 * dof), (chi2, dof)


def test_the_cdf_inversion_picks_the_pixel_whose_interval_holds_the_random_numbers():
    """A Closest map's cells are the pixels: u1 picks the row by the rows' cumulative luminance x
    solid angle, u2 the column by the row's own, each by a plain float64 searchsorted here; the
    sample lies in that pixel and carries its density, luminance / total (per unit solid angle), to
    a few float64 steps of its row's cdf (the map keeps no densities: the difference of the cdf)."""
    image = test_image(sun_value=1e5)
    h, w = image.shape[:2]
    env = world.EnvironmentWorld(image, strength=0.7, interpolation="Closest")
    rng = np.random.default_rng(21)
    u1, u2 = rng.random(200_000), rng.random(200_000)
    d, pdf = env.sample(u1, u2)
    u, v = world.direction_to_equirectangular(d)
    luminance = 0.7 * image @ world.LUMINANCE_RGB
    omega = (2.0 * np.pi / w) * np.diff(-np.cos(np.pi * np.arange(h + 1) / h))
    weight = luminance * omega[:, None]
    row = np.searchsorted(np.cumsum(weight.sum(axis=1)) / weight.sum(), u1, side="right")
    row_cdf = np.cumsum(weight, axis=1) / weight.sum(axis=1, keepdims=True)
    column = np.array([np.searchsorted(row_cdf[r], x, side="right") for r, x in zip(row, u2)])
    np.testing.assert_array_equal(np.floor(v * h).astype(int), row)
    np.testing.assert_array_equal(np.floor(u * w).astype(int), column)
    row_density = weight.sum(axis=1)[row] / weight.sum() / omega[row]  # the density of a whole row's cdf
    error = np.abs(pdf - luminance[row, column] / weight.sum())
    assert np.all(error <= 4 * np.finfo(np.float64).eps * row_density), (error / row_density).max()
    assert np.array_equal(pdf, env.pdf(d))


def test_a_bright_sun_gives_no_fireflies():
    """radiance / pdf stays within 4x its mean (the integral) for a pixel 10^4 times the sky;
    uniform sphere sampling of the same world has a huge spread (the test can tell)."""
    env = world.EnvironmentWorld(test_image(sun_value=1e5))
    n = 200_000
    rng = np.random.default_rng(3)
    d, pdf = env.sample(rng.random(n), rng.random(n))
    ratio = (env.radiance(d) @ world.LUMINANCE_RGB) / pdf
    assert ratio.max() <= 4.0 * ratio.mean()
    uniform = world.UniformWorld((1, 1, 1))
    d, pdf = uniform.sample(rng.random(n), rng.random(n))
    spread = (env.radiance(d) @ world.LUMINANCE_RGB) / pdf
    assert spread.max() > 50.0 * spread.mean()
    assert spread.mean() == pytest.approx(ratio.mean(), rel=0.1)  # both estimate the same integral


def test_a_small_linear_hdri_is_sampled_by_its_interpolated_radiance():
    """Issue 16: a Linear environment's radiance is bilinear between pixel centres, so a density
    piecewise constant per pixel leaves radiance / pdf anywhere in 0..4x its mean across a bright
    pixel's neighbourhood (relative spread 0.9 here, the HDRI scene's world NEE twice Cycles'
    noise).  The sampling map resolves the interpolation: the estimate of the sphere's integral
    of luminance from one world sample has a relative spread under 0.1, as Closest has none."""
    image = test_image(sun_value=1e5)
    n = 200_000
    rng = np.random.default_rng(3)
    for interpolation, bound in (("Linear", 0.1), ("Closest", 1e-9)):
        env = world.EnvironmentWorld(image, interpolation=interpolation)
        d, pdf = env.sample(rng.random(n), rng.random(n))
        ratio = (env.radiance(d) @ world.LUMINANCE_RGB) / pdf
        assert ratio.std() < bound * ratio.mean(), interpolation


def test_the_sampling_maps_corners_are_the_linear_lookup():
    image = np.random.default_rng(8).random((7, 12, 3))
    luminance = image @ world.LUMINANCE_RGB
    v = np.concatenate([[0.0], np.sort(np.random.default_rng(9).random(20)), [1.0]])
    for split in (1, 3):
        corners = world._refined_lattice(luminance, v, split)
        uu, vv = np.meshgrid((np.arange(12 * split + 1) / split + 0.5) / 12, v)
        looked_up = world.image_lookup(world.Texels(luminance[..., None]), uu.ravel(), vv.ravel())
        np.testing.assert_allclose(corners, looked_up.reshape(uu.shape), rtol=1e-12, atol=1e-14)


def test_uniform_world_sampling_and_radiance():
    uniform = world.UniformWorld((0.2, 0.4, 0.8), strength=2.5)
    rng = np.random.default_rng(5)
    d, pdf = uniform.sample(rng.random(100_000), rng.random(100_000))
    assert np.allclose(pdf, 1 / (4 * math.pi)) and np.allclose(np.linalg.norm(d, axis=1), 1.0)
    assert np.allclose(d.mean(axis=0), 0.0, atol=0.01)  # isotropic
    assert np.allclose(uniform.radiance(d[:3]), [0.5, 1.0, 2.0])


# ---------------------------------------------------------------------------- the aberration Jacobian
def spherical_triangle_area(a, b, c):
    """Solid angle of spherical triangles (Van Oosterom & Strackee 1983), rows of unit vectors."""
    numerator = np.abs(np.einsum("ij,ij->i", a, np.cross(b, c)))
    denominator = 1.0 + np.einsum("ij,ij->i", a, b) + np.einsum("ij,ij->i", b, c) + np.einsum("ij,ij->i", c, a)
    return 2.0 * np.arctan2(numerator, denominator)


@pytest.mark.parametrize("b", [0.5, 0.9, 0.99])
def test_aberration_jacobian_by_mapping_cells(b):
    """Cells of S' mapped to S cover solid angles D^2 dOmega' (D = nu_S' / nu_S), and the Jacobian
    integrates to 4 pi over the sphere; closed form D = 1 / (gamma (1 - beta.d'))."""
    beta = b * unit([0.3, -0.7, 0.4])
    to_world = Boost.from_velocity(-beta)  # the surface moves with beta in S: S' -> S
    nt, nph = 500, 250
    th_edges = np.linspace(0, math.pi, nt + 1)
    ph_edges = np.linspace(0, 2 * math.pi, nph + 1)
    th, ph = np.meshgrid(th_edges, ph_edges, indexing="ij")
    corners = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1)
    mapped, _ = to_world.rays(corners.reshape(-1, 3))
    mapped = mapped.reshape(nt + 1, nph + 1, 3)

    def quad_area(c):
        a, bb, cc, dd = (c[:-1, :-1].reshape(-1, 3), c[1:, :-1].reshape(-1, 3), c[1:, 1:].reshape(-1, 3),
                         c[:-1, 1:].reshape(-1, 3))
        return spherical_triangle_area(a, bb, cc) + spherical_triangle_area(a, cc, dd)

    area_rest, area_world = quad_area(corners), quad_area(mapped)
    tc = 0.5 * (th_edges[1:] + th_edges[:-1])
    pc = 0.5 * (ph_edges[1:] + ph_edges[:-1])
    tcm, pcm = np.meshgrid(tc, pc, indexing="ij")
    centres = np.stack([np.sin(tcm) * np.cos(pcm), np.sin(tcm) * np.sin(pcm), np.cos(tcm)], axis=-1).reshape(-1, 3)
    _, w = to_world.rays(centres)
    jacobian = world.frame_pdf(np.ones(len(w)), 1.0 / w)  # p_S' / p_S = dOmega_S / dOmega_S'
    assert np.allclose(jacobian, 1.0 / (gamma_of(b) * (1.0 - centres @ beta)) ** 2, rtol=1e-12)
    cells = area_rest > 1e-9  # the degenerate pole rows
    assert np.allclose(area_world[cells], (jacobian * area_rest)[cells], rtol=2e-3 if b < 0.95 else 2e-2)
    assert np.sum(jacobian * area_rest) == pytest.approx(4 * math.pi, rel=1e-4)
    # the other power fails: 1/D^2 integrates to 4 pi gamma^2 (1 + b^2/3) instead
    assert np.sum(area_rest / jacobian) == pytest.approx(4 * math.pi * gamma_of(b) ** 2 * (1 + b * b / 3), rel=1e-3)


def test_world_samples_seen_from_a_moving_frame_follow_the_carried_pdf():
    """Directions drawn in S and mapped to S' are distributed as p_S D^2 (chi-square in S')."""
    env = world.EnvironmentWorld(test_image(sun_value=100.0))  # a sun the quadrature below resolves
    beta = 0.8 * unit([1.0, 0.5, -0.2])
    to_frame = Boost.from_velocity(beta)
    n = 300_000
    rng = np.random.default_rng(6)
    d_frame, pdf_frame, _, _ = world.sample_in_frame(env, to_frame, rng.random(n), rng.random(n))
    _, check, _ = world.look_up_from_frame(env, Boost.from_velocity(-beta), d_frame)
    assert np.allclose(pdf_frame, check, rtol=1e-9)
    d, omega = grid(n_theta=600, n_phi=600)
    _, pdf, _ = world.look_up_from_frame(env, Boost.from_velocity(-beta), d)
    assert np.sum(pdf * omega) == pytest.approx(1.0, abs=3e-3)
    edges = (np.linspace(-1, 1, 17), np.linspace(-math.pi, math.pi, 17))

    def hist(x, weights=None):
        return np.histogram2d(x[:, 2], np.arctan2(x[:, 1], x[:, 0]), edges, weights=weights)[0]

    observed, expected = hist(d_frame), hist(d, pdf * omega * n)
    keep = expected > 20
    chi2 = np.sum((observed[keep] - expected[keep]) ** 2 / expected[keep])
    assert chi2 < keep.sum() + 6 * math.sqrt(2 * keep.sum()), chi2


# ---------------------------------------------------------------------------- uniform-world closed forms
def test_received_radiance_ahead_and_behind():
    """A surface at 0.5c sees L D^4: ahead D = gamma (1 + b) = sqrt(3), so D^4 = 9; behind 1/9."""
    uniform = world.UniformWorld((1.0, 1.0, 1.0))
    beta = np.array([0.5, 0.0, 0.0])
    radiance, _, doppler = world.look_up_from_frame(uniform, Boost.from_velocity(-beta),
                                                    np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 1.0, 0]]))
    assert np.allclose(doppler**4, [9.0, 1 / 9.0, (1 / gamma_of(0.5)) ** 4], rtol=1e-12)
    assert np.allclose(radiance, 1.0)


@pytest.mark.parametrize("b", [0.5, 0.9])
def test_energy_density_estimate_converges_to_closed_form(b):
    """integral of L D^4 over the rest-frame sphere = 4 pi gamma^2 (1 + b^2/3) L, by world
    sampling in S carried into S' (the estimator) and by quadrature (the test's own)."""
    L = np.array([0.3, 0.6, 1.2])
    uniform = world.UniformWorld(L)
    beta = b * unit([0.2, 0.9, -0.4])
    n = 400_000
    pixel, sample = np.arange(n) // 16, np.arange(n) % 16
    estimate = world.sphere_integral_estimate(uniform, Boost.from_velocity(beta),
                                              sampling.uniform(pixel, sample, 10), sampling.uniform(pixel, sample, 11))
    closed = 4 * math.pi * gamma_of(b) ** 2 * (1 + b * b / 3) * L
    d, omega = grid(n_theta=2000, n_phi=64)
    quadrature = np.sum(omega / (gamma_of(b) * (1 - d @ beta)) ** 4) * L
    assert np.allclose(quadrature, closed, rtol=1e-4)
    assert np.allclose(estimate.mean(axis=0), closed, rtol=0.01)


def lambertian_reference(radiance_of_world_dir, beta, normal, n_theta=1000, n_phi=300):
    """(1/pi) integral over the rest-frame hemisphere of L(d_S) D^4 cos, with the aberration
    written out here: d_S = the backward direction d' seen in S, D = 1 / (gamma (1 - beta.d'))."""
    d, omega = grid(normal, n_theta, n_phi, math.pi / 2)
    b = np.linalg.norm(beta)
    g = gamma_of(b)
    n_hat = beta / b
    along = d @ n_hat
    # velocity addition for the photon (velocity -d' in S', S' moving with beta in S), negated
    d_par = (along - b) / (1 - b * along)
    d_perp = (d - along[:, None] * n_hat) / (g * (1 - b * along))[:, None]
    d_world = d_par[:, None] * n_hat + d_perp
    doppler = 1.0 / (g * (1 - d @ beta))
    return np.sum(radiance_of_world_dir(d_world) * (doppler**4 * (d @ normal) * omega / math.pi)[:, None], axis=0)


@pytest.mark.parametrize("b", [0.5, 0.9])
@pytest.mark.parametrize("facing", ["ahead", "behind", "side"])
def test_moving_lambertian_in_a_uniform_world(b, facing):
    """(1/pi) integral of L D^4 cos over the rest-frame hemisphere: closed form 3.75 L (0.5c,
    ahead) and 7/36 L (0.5c, behind); the MIS estimator converges to the quadrature to 1%."""
    L = np.array([1.0, 0.5, 0.25])
    uniform = world.UniformWorld(L)
    motion = unit([0.6, 0.0, 0.8])
    beta = b * motion
    normal = {"ahead": motion, "behind": -motion, "side": unit([0.8, 0.0, -0.6])}[facing]
    reference = lambertian_reference(uniform.radiance, beta, normal)
    closed_form = {(0.5, "ahead"): 3.75, (0.5, "behind"): 7.0 / 36.0}.get((b, facing))
    if closed_form is not None:
        assert np.allclose(reference, closed_form * L, rtol=1e-4)
    g, u = gamma_of(b), mpmath.mpf(1)
    sign = {"ahead": 1, "behind": -1}.get(facing)
    if sign is not None:  # the same integral by mpmath: 2 / gamma^4 int_0^1 x / (1 - s b x)^4 dx
        exact = 2 / g**4 * mpmath.quad(lambda x: x / (u - sign * b * x) ** 4, [0, 1])
        assert np.allclose(reference, float(exact) * L, rtol=1e-4)
    n = 200_000
    rng = np.random.default_rng(31)
    estimate = world.lambertian_radiance_estimate(uniform, Boost.from_velocity(-beta), Boost.from_velocity(beta),
                                                  np.broadcast_to(normal, (n, 3)), [rng.random(n) for _ in range(4)])
    assert np.allclose(estimate.mean(axis=0), reference, rtol=0.01)


def test_moving_lambertian_under_an_hdri_with_a_sun():
    """An environment with a bright sun, a surface at 0.6c: the MIS estimate (cosine + world
    sampling carried across frames by the Jacobian) converges to the quadrature to 1%."""
    env = world.EnvironmentWorld(test_image(sun=(15, 30), sun_value=300.0), strength=1.5,
                                 mapping=world.mapping_rotation((0.0, 0.0, 0.7)))
    beta = 0.6 * unit([-0.3, 0.8, 0.2])
    normal = unit([0.1, 0.4, 0.9])
    reference = lambertian_reference(env.radiance, beta, normal, n_theta=1000, n_phi=1000)
    n = 400_000
    rng = np.random.default_rng(41)
    estimate = world.lambertian_radiance_estimate(env, Boost.from_velocity(-beta), Boost.from_velocity(beta),
                                                  np.broadcast_to(normal, (n, 3)), [rng.random(n) for _ in range(4)])
    assert np.allclose(estimate.mean(axis=0), reference, rtol=0.01)
    # beta = 1e-12 is rest, sample by sample
    n = 50_000
    u = [rng.random(n) for _ in range(4)]
    at_rest = world.lambertian_radiance_estimate(env, Boost.from_velocity(-beta * 1e-12),
                                                 Boost.from_velocity(beta * 1e-12), np.broadcast_to(normal, (n, 3)), u)
    rest = world.lambertian_radiance_estimate(env, Boost.identity(), Boost.identity(),
                                              np.broadcast_to(normal, (n, 3)), u)
    assert np.allclose(at_rest, rest, rtol=1e-4)  # (directions grazing the surface amplify the 1e-12)
    assert np.allclose(at_rest.mean(axis=0), rest.mean(axis=0), rtol=1e-9)
    assert not np.allclose(rest.mean(axis=0), reference, rtol=0.05)  # and motion at 0.6c is not

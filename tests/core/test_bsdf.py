"""Rest-frame BSDFs: densities normalised (quadrature), samplers distributed as their densities
(binned chi-square), energy conservation (white furnace), reciprocity and closed forms."""

import math

import numpy as np
import pytest
from references import half_vector_ggx

from restframe_addon.core import bsdf, mis

NORMAL = np.array([0.3, -0.5, 0.81])
NORMAL = NORMAL / np.linalg.norm(NORMAL)


def basis(n):
    """An orthonormal frame (t, b, n) built independently of bsdf.tangent_frame."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t = np.cross(helper, n)
    t /= np.linalg.norm(t)
    return t, np.cross(n, t), n


def sphere_grid(n, n_theta=1500, n_phi=600, theta_max=math.pi):
    """Midpoint quadrature over directions with polar angle < theta_max about n:
    (directions (m, 3), solid angle weights (m,), theta (m,), phi (m,))."""
    t, b, z = basis(n)
    dtheta, dphi = theta_max / n_theta, 2 * math.pi / n_phi
    theta = (np.arange(n_theta) + 0.5) * dtheta
    phi = (np.arange(n_phi) + 0.5) * dphi
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    th, ph = th.ravel(), ph.ravel()
    d = (np.sin(th) * np.cos(ph))[:, None] * t + (np.sin(th) * np.sin(ph))[:, None] * b + np.cos(th)[:, None] * z
    weight = np.sin(th) * dtheta * dphi
    return d, weight, th, ph


def direction(n, theta, phi=0.4):
    t, b, z = basis(n)
    return np.sin(theta) * np.cos(phi) * t + np.sin(theta) * np.sin(phi) * b + np.cos(theta) * z


def mirror(view):
    return 2.0 * (view @ NORMAL) * NORMAL - view


def rows_of(v, m):
    return np.broadcast_to(v, (m, 3)).copy()


def chi_square_ok(samples, pdf, n, bins_theta=12, bins_phi=8, theta_max=math.pi, drawn=None):
    """Binned chi-square of sampled directions against a density: statistic below a bound
    that a correct sampler passes with overwhelming probability (dof + 6 sqrt(2 dof)).
    ``drawn``: how many were drawn when only the valid ``samples`` are passed."""
    d, weight, th, ph = sphere_grid(n, 1200, 480, theta_max)
    expected_density = pdf(d) * weight
    t, b, z = basis(n)
    s_th = np.arccos(np.clip(samples @ z, -1.0, 1.0))
    s_ph = np.arctan2(samples @ b, samples @ t) % (2 * math.pi)
    edges_th = np.linspace(0.0, theta_max, bins_theta + 1)
    edges_ph = np.linspace(0.0, 2 * math.pi, bins_phi + 1)
    observed, _, _ = np.histogram2d(s_th, s_ph, [edges_th, edges_ph])
    expected, _, _ = np.histogram2d(th, ph, [edges_th, edges_ph], weights=expected_density)
    expected *= len(samples) if drawn is None else drawn
    keep = expected > 5.0  # bins with few expected counts pooled into one
    stat = np.sum((observed[keep] - expected[keep]) ** 2 / expected[keep])
    rest_o, rest_e = observed[~keep].sum(), expected[~keep].sum()
    if rest_e > 0:
        stat += (rest_o - rest_e) ** 2 / max(rest_e, 1.0)
    dof = int(keep.sum())
    assert observed.sum() == pytest.approx(len(samples), abs=0.5)  # no sample outside the grid range
    return stat < dof + 6.0 * math.sqrt(2.0 * dof), (stat, dof)


def uniforms(m, k, seed=7):
    rng = np.random.default_rng(seed)
    return [rng.random(m) for _ in range(k)]


# ---------------------------------------------------------------------------- frames and Fresnel
def test_tangent_frame_is_orthonormal_and_right_handed_everywhere():
    rng = np.random.default_rng(3)
    n = rng.normal(size=(1000, 3))
    n = np.concatenate([n, [[0, 0, 1.0], [0, 0, -1.0], [1.0, 0, 0], [0, -1.0, 0], [0, 1e-18, -1.0]]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    t, b = bsdf.tangent_frame(n)
    for u, v in ((t, t), (b, b)):
        assert np.allclose(np.sum(u * v, axis=1), 1.0, atol=1e-12)
    for u, v in ((t, b), (t, n), (b, n)):
        assert np.allclose(np.sum(u * v, axis=1), 0.0, atol=1e-12)
    assert np.allclose(np.cross(t, b), n, atol=1e-12)


def test_fresnel_dielectric_closed_forms():
    eta = np.array([1 / 1.5, 1 / 1.5, 1.5, 1.5])
    brewster = math.atan(1.5)  # from air: rp = 0 there
    sin_t = math.sin(brewster) / 1.5
    cos_t = math.sqrt(1 - sin_t**2)
    rs = (math.cos(brewster) / 1.5 - cos_t) / (math.cos(brewster) / 1.5 + cos_t)
    cos_i = np.array([1.0, math.cos(brewster), 1.0, math.cos(math.radians(60))])  # last: beyond the critical angle
    f = bsdf.fresnel_dielectric(cos_i, eta)
    assert f[0] == pytest.approx(0.04, rel=1e-12)
    assert f[1] == pytest.approx(0.5 * rs**2, rel=1e-12)
    assert f[2] == pytest.approx(0.04, rel=1e-12)
    assert f[3] == 1.0
    assert bsdf.dielectric_f0(1.5) == pytest.approx(0.04)


def test_principled_and_f82_fresnel_reduce_to_their_limits():
    cos = np.linspace(0.0, 1.0, 101)
    eta = np.full(101, 1 / 1.45)
    f0 = np.full((101, 3), bsdf.dielectric_f0(1.45))
    exact = bsdf.fresnel_dielectric(cos, eta)
    remapped = bsdf.fresnel_principled_dielectric(cos, eta, f0, np.ones(101))
    assert np.allclose(remapped, exact[:, None], atol=1e-14)
    # remapping: F0..1 of the real curve becomes f0..f90
    half = bsdf.fresnel_principled_dielectric(cos, eta, 0.5 * f0, np.full(101, 0.5))
    assert half[-1, 0] == pytest.approx(0.5 * f0[0, 0], rel=1e-12) and half[0, 0] == pytest.approx(0.5)
    gold = np.broadcast_to([1.0, 0.78, 0.34], (101, 3))
    untinted = bsdf.fresnel_f82_tint(cos, gold, np.ones((101, 3)))
    assert np.allclose(untinted, bsdf.fresnel_schlick(cos, gold, np.ones(101)), atol=1e-14)
    tint = np.broadcast_to([0.9, 0.6, 0.3], (1, 3))
    at82 = bsdf.fresnel_f82_tint(np.array([1.0 / 7.0]), gold[:1], tint)
    schlick82 = bsdf.fresnel_schlick(np.array([1.0 / 7.0]), gold[:1], np.ones(1))
    assert np.allclose(at82, schlick82 * tint, rtol=1e-12)


# ---------------------------------------------------------------------------- diffuse
def test_diffuse_pdf_integrates_to_one_and_sampler_matches_it():
    d, w, _, _ = sphere_grid(NORMAL)
    m = len(d)
    assert np.sum(bsdf.diffuse_pdf(rows_of(NORMAL, m), d) * w) == pytest.approx(1.0, abs=2e-5)
    n = 200_000
    u1, u2 = uniforms(n, 2)
    light, pdf = bsdf.sample_diffuse(rows_of(NORMAL, n), u1, u2)
    assert np.allclose(np.linalg.norm(light, axis=1), 1.0, atol=1e-12)
    assert np.allclose(pdf, bsdf.diffuse_pdf(rows_of(NORMAL, n), light), atol=1e-12)
    ok, info = chi_square_ok(light, lambda x: bsdf.diffuse_pdf(rows_of(NORMAL, len(x)), x), NORMAL,
                             theta_max=math.pi / 2)
    assert ok, info
    # Lambertian white furnace: albedo exactly 1 (weight f cos / pdf = 1 per sample)
    assert np.mean(np.sum(light * NORMAL, axis=1) / np.pi / pdf) == pytest.approx(1.0, abs=1e-12)


def test_a_wrong_sampler_fails_the_chi_square():
    """The histogram test can fail: uniform hemisphere samples against the cosine density."""
    n = 200_000
    u1, u2 = uniforms(n, 2)
    z = u1
    r = np.sqrt(1 - z * z)
    t, b, nn = basis(NORMAL)
    light = (r * np.cos(2 * np.pi * u2))[:, None] * t + (r * np.sin(2 * np.pi * u2))[:, None] * b + z[:, None] * nn
    ok, _ = chi_square_ok(light, lambda x: bsdf.diffuse_pdf(rows_of(NORMAL, len(x)), x), NORMAL,
                          theta_max=math.pi / 2)
    assert not ok


# ---------------------------------------------------------------------------- GGX
ALPHAS = (0.05, 0.25, 0.6, 1.0)


@pytest.mark.parametrize("alpha", ALPHAS)
def test_ggx_ndf_projected_area_is_one(alpha):
    """integral of D(h) cos(h) over the hemisphere = 1 (the microsurface projects onto unit area)."""
    d, w, th, _ = sphere_grid(NORMAL, 4000, 16, math.pi / 2)
    assert np.sum(bsdf.ggx_ndf(np.cos(th), np.full(len(th), alpha)) * np.cos(th) * w) == pytest.approx(1.0, abs=1e-4)


@pytest.mark.parametrize("alpha", ALPHAS)
@pytest.mark.parametrize("theta_v", (0.0, 0.7, 1.4))
def test_visible_normal_pdf_integrates_to_one(alpha, theta_v):
    """integral of G1(v) max(v.h, 0) D(h) / cos_v dh = 1: Smith's G1 in closed form (Heitz 2014)."""
    d, w, _, _ = sphere_grid(NORMAL, 2000, 200, math.pi / 2)
    m = len(d)
    view = rows_of(direction(NORMAL, theta_v), m)
    pdf = bsdf.ggx_vndf_pdf(rows_of(NORMAL, m), view, d, np.full(m, alpha))
    assert np.sum(pdf * w) == pytest.approx(1.0, abs=2e-3 if alpha < 0.1 else 5e-4)


def test_smith_lambda_closed_form():
    """Lambda = (-1 + sqrt(1 + alpha^2 tan^2)) / 2; at alpha = 1, 60 degrees: (sqrt(4) - 1) / 2 = 1/2."""
    assert bsdf.ggx_lambda(np.array([0.5]), np.array([1.0]))[0] == pytest.approx(0.5, rel=1e-12)
    assert bsdf.ggx_g2(np.array([0.5]), np.array([0.5]), np.array([1.0]))[0] == pytest.approx(0.5, rel=1e-12)
    assert bsdf.ggx_g1(np.array([1.0]), np.array([0.7]))[0] == 1.0


def test_ggx_from_cosines_matches_the_half_vector_form():
    """bsdf.ggx_single (three dot products, no half vector) and ggx_visibility (G2 / (4 cos_v
    cos_l) multiplied out) against the half-vector form they replaced, for unit directions above
    the surface, alpha 1e-3 .. 1, grazing and head-on included: 1e-13 relative at 99% of the pairs,
    1e-10 near the peak of narrow lobes (1 - (n.h)^2 ~ alpha^2 there amplifies the rounding of
    either form; the float32 Combined pass rounds at 6e-8)."""
    rng = np.random.default_rng(11)
    m = 20000
    v, l = (rng.normal(size=(m, 3)) for _ in range(2))
    v[:200] = v[200:400] = l[:200] = NORMAL  # head-on, and the specular peak
    for x in (v, l):
        x /= np.linalg.norm(x, axis=1, keepdims=True)
        x[x @ NORMAL < 0] *= -1
    l[200:400] = 2.0 * (v[200:400] @ NORMAL)[:, None] * NORMAL - v[200:400]
    alpha = np.exp(rng.uniform(np.log(1e-3), 0.0, m))
    normal = rows_of(NORMAL, m)
    single, cos_vh = bsdf.ggx_single(v @ NORMAL, l @ NORMAL, np.sum(v * l, axis=1), alpha)
    expected, expected_vh = half_vector_ggx(normal, v, l, alpha)
    np.testing.assert_allclose(single, expected, rtol=1e-10, atol=0.0)
    assert np.quantile(np.abs(single - expected) / expected, 0.99) < 1e-13
    np.testing.assert_allclose(cos_vh, expected_vh, rtol=1e-13, atol=0.0)
    cos_v, cos_l = rng.uniform(0.0, 1.0, (2, m))
    cos_v[:100] = 1e-9  # below the clip
    clipped = np.clip(cos_v, 1e-6, 1.0), np.clip(cos_l, 1e-6, 1.0)
    np.testing.assert_allclose(bsdf.ggx_visibility(cos_v, cos_l, alpha),
                               bsdf.ggx_g2(*clipped, alpha) / (4.0 * clipped[0] * clipped[1]), rtol=1e-13, atol=0.0)
    f0, f90 = rng.uniform(0, 1, (m, 3)), rng.uniform(0, 1, m)
    schlick = (1.0 - expected_vh) ** 5
    np.testing.assert_allclose(bsdf.ggx_reflection(normal, v, l, alpha, f0, f90),
                               (f0 * (1.0 - schlick)[:, None] + (f90 * schlick)[:, None]) * expected[:, None],
                               rtol=1e-10, atol=0.0)


@pytest.mark.parametrize("alpha", (0.1, 0.4, 1.0))
@pytest.mark.parametrize("theta_v", (0.2, 1.2))
def test_ggx_reflection_sampler_matches_its_pdf(alpha, theta_v):
    n_rays = 200_000
    normal = rows_of(NORMAL, n_rays)
    view = rows_of(direction(NORMAL, theta_v), n_rays)
    u1, u2 = uniforms(n_rays, 2, seed=11)
    light, pdf, weight = bsdf.sample_ggx_reflection(normal, view, np.full(n_rays, alpha), u1, u2)
    assert np.allclose(np.linalg.norm(light, axis=1), 1.0, atol=1e-12)
    assert np.allclose(pdf, bsdf.ggx_reflection_pdf(normal, view, light, np.full(n_rays, alpha)), rtol=1e-9)
    # the pdf over all light directions (some reflected below the horizon) is normalised
    d, w, _, _ = sphere_grid(mirror(view[0]), 2000, 300)
    m = len(d)
    total = np.sum(bsdf.ggx_reflection_pdf(rows_of(NORMAL, m), rows_of(view[0], m), d, np.full(m, alpha)) * w)
    assert total == pytest.approx(1.0, abs=1e-3)

    def density(x):
        k = len(x)
        return bsdf.ggx_reflection_pdf(rows_of(NORMAL, k), rows_of(view[0], k), x, np.full(k, alpha))

    ok, info = chi_square_ok(light, density, NORMAL)
    assert ok, info


@pytest.mark.parametrize("alpha", (0.02, 0.3, 1.0))
@pytest.mark.parametrize("theta_v", (0.0, 0.8, 1.45))
def test_ggx_white_furnace_and_eval_pdf_consistency(alpha, theta_v):
    """With F = 1 the single-scattering albedo integral of f cos is <= 1, equals the mean
    sample weight G2 / G1 (eval and pdf agree), and tends to 1 for smooth surfaces."""
    view_dir = direction(NORMAL, theta_v)
    d, w, _, _ = sphere_grid(mirror(view_dir), 2000, 300)  # the pole on the lobe's peak
    m = len(d)
    f = bsdf.ggx_reflection(rows_of(NORMAL, m), rows_of(view_dir, m), d, np.full(m, alpha),
                            np.ones((m, 3)), np.ones(m))[:, 0]
    albedo = np.sum(f * (d @ NORMAL) * w)
    n_rays = 400_000
    u1, u2 = uniforms(n_rays, 2, seed=5)
    _, _, weight = bsdf.sample_ggx_reflection(rows_of(NORMAL, n_rays), rows_of(view_dir, n_rays),
                                              np.full(n_rays, alpha), u1, u2)
    assert albedo <= 1.0 + 1e-3
    assert np.all(weight <= 1.0 + 1e-12)
    assert np.mean(weight) == pytest.approx(albedo, abs=max(4 * np.std(weight) / math.sqrt(n_rays), 3e-3))
    if alpha <= 0.02 and theta_v < 1.0:
        assert albedo == pytest.approx(1.0, abs=2e-3)
    if alpha == 1.0:
        assert albedo < 0.95  # single scattering loses energy on rough surfaces


def test_ggx_reflection_is_reciprocal_and_a_known_value():
    rng = np.random.default_rng(9)
    m = 1000
    v = rng.normal(size=(m, 3))
    l = rng.normal(size=(m, 3))
    for x in (v, l):
        x /= np.linalg.norm(x, axis=1, keepdims=True)
        x[x @ NORMAL < 0] *= -1
    alpha = rng.uniform(0.05, 1.0, m)
    f0 = rng.uniform(0, 1, (m, 3))
    f90 = rng.uniform(0, 1, m)
    normal = rows_of(NORMAL, m)
    assert np.allclose(bsdf.ggx_reflection(normal, v, l, alpha, f0, f90),
                       bsdf.ggx_reflection(normal, l, v, alpha, f0, f90), rtol=1e-12)
    # normal incidence and exit, alpha = 1: D = 1/pi, G2 = 1, F = f0 -> f0 / (4 pi)
    z = np.array([[0, 0, 1.0]])
    value = bsdf.ggx_reflection(z, z, z, np.array([1.0]), np.array([[0.5, 0.2, 1.0]]), np.array([1.0]))
    assert np.allclose(value, np.array([0.5, 0.2, 1.0]) / (4 * np.pi), rtol=1e-12)


# ---------------------------------------------------------------------------- glass
@pytest.mark.parametrize("eta", (1 / 1.5, 1.5))
@pytest.mark.parametrize("alpha", (0.15, 0.6))
@pytest.mark.parametrize("theta_v", (0.3, 1.1))
def test_rough_glass_pdf_sampler_and_energy(eta, alpha, theta_v):
    """Reflection + transmission densities integrate to 1 over the sphere, samples follow them,
    and the mean weight equals the albedo integral of f |cos| (<= 1)."""
    d, w, _, _ = sphere_grid(NORMAL, 2000, 400)
    m = len(d)
    view_dir = direction(NORMAL, theta_v)
    value, pdf = bsdf.dielectric_eval(rows_of(NORMAL, m), rows_of(view_dir, m), d, np.full(m, eta), np.full(m, alpha))
    albedo = np.sum(value * w)
    assert albedo <= 1.0 + 1e-3
    n_rays = 100_000
    u1, u2, u3 = uniforms(n_rays, 3, seed=13)
    light, s_pdf, weight, transmitted = bsdf.sample_dielectric(
        rows_of(NORMAL, n_rays), rows_of(view_dir, n_rays), np.full(n_rays, eta), np.full(n_rays, alpha),
        u1, u2, u3, np.zeros(n_rays, bool))
    valid = s_pdf > 0
    # the valid samples' density is normalised to the fraction of samples that are valid
    assert np.sum(pdf * w) == pytest.approx(np.mean(valid), abs=3e-3)
    assert np.mean(valid) > 0.7  # rough glass from inside loses many rays to the wrong side
    assert np.all(weight[~valid] == 0.0)
    assert np.allclose(np.linalg.norm(light[valid], axis=1), 1.0, atol=1e-9)
    assert np.array_equal(transmitted[valid], (light @ NORMAL < 0)[valid])
    _, check = bsdf.dielectric_eval(rows_of(NORMAL, n_rays), rows_of(view_dir, n_rays), light,
                                    np.full(n_rays, eta), np.full(n_rays, alpha))
    assert np.allclose(s_pdf[valid], check[valid], rtol=1e-9)
    assert np.mean(weight) == pytest.approx(albedo, abs=max(4 * np.std(weight) / math.sqrt(n_rays), 3e-3))

    def density(x):
        k = len(x)
        return bsdf.dielectric_eval(rows_of(NORMAL, k), rows_of(view_dir, k), x, np.full(k, eta),
                                    np.full(k, alpha))[1]

    ok, info = chi_square_ok(light[valid], density, NORMAL, drawn=n_rays)
    assert ok, info


def test_rough_glass_generalised_reciprocity():
    """Without radiance compression (as Cycles), f(l -> v; 1/eta) = eta^2 f(v -> l; eta)."""
    rng = np.random.default_rng(21)
    m = 6000
    v = rng.normal(size=(m, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v[v @ NORMAL < 0] *= -1
    l = rng.normal(size=(m, 3))
    l /= np.linalg.norm(l, axis=1, keepdims=True)
    l[l @ NORMAL > 0] *= -1
    normal, alpha, eta = rows_of(NORMAL, m), np.full(m, 0.4), np.full(m, 1 / 1.5)
    forward, _ = bsdf.dielectric_eval(normal, v, l, eta, alpha)
    backward, _ = bsdf.dielectric_eval(-normal, l, v, 1 / eta, alpha)
    cos_v, cos_l = np.abs(v @ NORMAL), np.abs(l @ NORMAL)
    ok = forward > 1e-8
    assert ok.sum() > 500
    assert np.allclose((backward / cos_v)[ok], (eta**2 * forward / cos_l)[ok], rtol=1e-9)


def test_smooth_glass_chooses_by_fresnel_and_obeys_snell():
    n_rays = 200_000
    theta = 0.9
    view = rows_of(direction(NORMAL, theta), n_rays)
    u1, u2, u3 = uniforms(n_rays, 3, seed=17)
    eta = np.full(n_rays, 1 / 1.5)
    light, pdf, weight, transmitted = bsdf.sample_dielectric(rows_of(NORMAL, n_rays), view, eta, np.zeros(n_rays),
                                                             u1, u2, u3, np.ones(n_rays, bool))
    fresnel = bsdf.fresnel_dielectric(np.array([math.cos(theta)]), eta[:1])[0]
    assert np.isinf(pdf).all() and np.all(weight == 1.0)
    assert np.mean(~transmitted) == pytest.approx(fresnel, abs=4 * math.sqrt(fresnel / n_rays))
    sin_in = math.sin(theta)
    cos_out = -(light[transmitted] @ NORMAL)
    assert np.allclose(np.sqrt(1 - cos_out**2), sin_in / 1.5, rtol=1e-12)
    assert np.allclose(light[~transmitted] @ NORMAL, math.cos(theta), rtol=1e-12)
    # from inside beyond the critical angle: everything reflects
    inside = bsdf.sample_dielectric(rows_of(NORMAL, 100), view[:100], np.full(100, 1.5), np.zeros(100),
                                    u1[:100], u2[:100], u3[:100], np.ones(100, bool))
    assert not inside[3].any()


# ---------------------------------------------------------------------------- MIS
def test_power_heuristic_weights_sum_to_one_and_handle_deltas():
    rng = np.random.default_rng(1)
    a, b = rng.uniform(0, 10, 1000), rng.uniform(0, 10, 1000)
    assert np.allclose(mis.power_heuristic(a, b) + mis.power_heuristic(b, a), 1.0, atol=1e-14)
    assert mis.power_heuristic(np.array([2.0]), np.array([1.0]))[0] == pytest.approx(0.8)
    inf = np.array([np.inf])
    assert mis.power_heuristic(inf, np.array([3.0]))[0] == 1.0
    assert mis.power_heuristic(np.array([3.0]), inf)[0] == 0.0
    assert mis.power_heuristic(np.array([0.0]), np.array([0.0]))[0] == 0.0
    assert mis.power_heuristic(np.array([1e-300]), np.array([1e300]))[0] == 0.0


# ---------------------------------------------------------------------------- energy compensation
@pytest.mark.parametrize("alpha", (0.07, 0.35, 0.8))
@pytest.mark.parametrize("theta_v", (0.3, 1.0, 1.35))
def test_multiscatter_compensation_makes_the_white_furnace_one(alpha, theta_v):
    """Single-scattering albedo (quadrature, off the table's knots) x Cycles' multiscatter factor
    with F = 1 (F_ms = 1: factor 1 / E) is 1; the table E agrees with the quadrature to 1e-3."""
    view_dir = direction(NORMAL, theta_v)
    d, w, _, _ = sphere_grid(mirror(view_dir), 2000, 300)
    m = len(d)
    f = bsdf.ggx_reflection(rows_of(NORMAL, m), rows_of(view_dir, m), d, np.full(m, alpha), np.ones((m, 3)),
                            np.ones(m))[:, 0]
    albedo = np.sum(f * np.maximum(d @ NORMAL, 0.0) * w)
    cos_v, a = np.array([math.cos(theta_v)]), np.array([alpha])
    assert bsdf.ggx_albedo(cos_v, a)[0] == pytest.approx(albedo, abs=1e-3)
    factor = bsdf.ggx_energy_compensation(cos_v, a, np.ones((1, 3)))
    assert np.allclose(albedo * factor, 1.0, atol=1.5e-3)
    assert np.allclose(bsdf.ggx_energy_compensation(cos_v, a, np.zeros((1, 3))), 1.0)  # black Fresnel: nothing


def test_average_albedo_and_fresnel_averages_by_quadrature():
    mu = (np.arange(20000) + 0.5) / 20000
    for alpha in (0.1, 0.5, 1.0):
        e = bsdf.ggx_albedo(mu, np.full(len(mu), alpha))
        assert bsdf.ggx_average_albedo(np.array([alpha]))[0] == pytest.approx(2 * np.mean(e * mu), abs=1e-3)
    f0 = np.array([[0.9, 0.6, 0.2]])
    tint = np.array([[0.5, 0.8, 1.0]])

    def average(values):  # 2 int F mu dmu, midpoint rule
        return 2 * np.mean(values * mu[:, None], axis=0)

    n = len(mu)
    assert np.allclose(bsdf.fresnel_average_schlick(f0, np.array([0.7])),
                       average(bsdf.fresnel_schlick(mu, np.repeat(f0, n, 0), np.full(n, 0.7))), atol=1e-7)
    assert np.allclose(bsdf.fresnel_average_f82_tint(f0, tint),
                       average(bsdf.fresnel_f82_tint(mu, np.repeat(f0, n, 0), np.repeat(tint, n, 0))), atol=1e-7)
    for eta in (1 / 1.5, 1 / 1.2, 1.33):
        exact = 2 * np.mean(bsdf.fresnel_dielectric(mu, np.full(n, eta)) * mu)
        assert bsdf.fresnel_average_dielectric(np.array([eta]))[0] == pytest.approx(exact, abs=1e-5)


@pytest.mark.parametrize("alpha", (0.04, 0.3, 0.8))
@pytest.mark.parametrize("theta_v", (0.4, 1.2))
@pytest.mark.parametrize("ior", (1.45, 2.4))
def test_dielectric_specular_albedo_and_layering_conserve_energy(alpha, theta_v, ior):
    """The table's albedo of the Principled dielectric lobe equals the quadrature of its Fresnel
    interpolation weight over the lobe; a white Principled dielectric (compensated specular over
    diffuse scaled by 1 - albedo, as Cycles layers them) reflects all light when smooth, and
    on rough ones loses at most what single scattering loses (Cycles' layering counts the
    specular lobe as compensated to albedo 1: the multiply scattered light that the Fresnel
    lets through to the diffuse base is not added there)."""
    view_dir = direction(NORMAL, theta_v)
    d, w, _, _ = sphere_grid(mirror(view_dir), 1500, 200)
    m = len(d)
    normal, view = rows_of(NORMAL, m), rows_of(view_dir, m)
    f_ss = bsdf.ggx_reflection(normal, view, d, np.full(m, alpha), np.ones((m, 3)), np.ones(m))[:, 0]
    h = (view + d) / np.linalg.norm(view + d, axis=1, keepdims=True)
    eta = np.full(m, 1.0 / ior)
    f_real = bsdf.fresnel_dielectric(np.sum(view * h, axis=1), eta)
    f0_real = ((ior - 1) / (ior + 1)) ** 2
    shape = np.clip((f_real - f0_real) / (1 - f0_real), 0, 1)
    cos_l = np.maximum(d @ NORMAL, 0.0)
    s_quadrature = np.sum(shape * f_ss * cos_l * w) / np.sum(f_ss * cos_l * w)
    f0, f90 = np.array([[0.7 * f0_real, f0_real, 1.3 * f0_real]]), np.array([0.9])
    cos_v, a, e = np.array([math.cos(theta_v)]), np.array([alpha]), np.array([1.0 / ior])
    albedo = bsdf.ggx_dielectric_albedo(cos_v, a, e, f0, f90)
    assert np.allclose(albedo, f0 + (f90[:, None] - f0) * s_quadrature, atol=5e-3)
    # white dielectric: specular (Principled Fresnel, Multiscatter GGX) + diffuse x (1 - albedo)
    f0w = np.full((1, 3), f0_real)
    fresnel = bsdf.fresnel_principled_dielectric(np.sum(view * h, axis=1), eta, np.repeat(f0w, m, 0), np.ones(m))
    compensation = bsdf.ggx_energy_compensation(cos_v, a, bsdf.fresnel_average_principled_dielectric(e, f0w,
                                                                                                    np.ones(1)))
    specular = np.sum((fresnel[:, 0] * f_ss * cos_l * w)) * compensation[0, 0]
    diffuse = 1.0 - bsdf.ggx_dielectric_albedo(cos_v, a, e, f0w, np.ones(1))[0, 0]
    single_scattering_loss = 1.0 - bsdf.ggx_albedo(cos_v, a)[0]
    assert 1.0 - single_scattering_loss - 5e-3 <= specular + diffuse <= 1.0 + 5e-3
    if alpha < 0.1:
        assert specular + diffuse == pytest.approx(1.0, abs=5e-3)

"""Rough glass as the Path Tracing integrator scatters it (``integrator._Lobes``): GGX microfacet
transmission sampled by visible normals, against an independent plain-numpy quadrature of Walter
et al.'s (2007) rough dielectric written here, and its white furnace (single scattering loses
energy to the microfacets' inter-reflections; Cycles' multiscatter glass, and so RESTframe's,
scales the lobes by 1 / the single-scattering albedo)."""

import math

import numpy as np
import pytest

from restframe_addon.core.integrator import _COAT, _GLOSSY, _TRANSMIT, _Lobes
from restframe_addon.core.scene import Material
from restframe_addon.core.shading import MaterialTable

NORMAL = np.array([0.0, 0.0, 1.0])


# ---------------------------------------------------------------------------- the reference, from the paper
def fresnel(cos_i, eta):
    """Unpolarised Fresnel reflectance from the s and p amplitudes; eta = n_incident / n_transmitted."""
    sin_t2 = eta**2 * (1.0 - cos_i**2)
    cos_t = np.sqrt(np.clip(1.0 - sin_t2, 0.0, None))
    with np.errstate(invalid="ignore", divide="ignore"):  # 0/0 where v.h = 0: no light there
        rs = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
        rp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    return np.where(sin_t2 >= 1.0, 1.0, 0.5 * (rs * rs + rp * rp))


def smith_lambda(cos, alpha):
    tan2 = (1.0 - cos * cos) / (cos * cos)
    return 0.5 * (np.sqrt(1.0 + alpha * alpha * tan2) - 1.0)


def walter(view, light, eta, alpha):
    """f |cos_l| of the rough dielectric for unit rows ``light``, the view above z: reflection
    F D G2 / (4 cos_v) and transmission (1 - F) D G2 |v.h| |l.h| / (cos_v (eta v.h + l.h)^2)
    (Walter's eq. 21 with eta = n_view / n_light, without the 1/eta^2 radiance compression, as
    Cycles), height-correlated Smith G2.  Returns (reflected, transmitted)."""
    cos_v, cos_l = view @ NORMAL, light @ NORMAL
    below = cos_l < 0.0
    h = np.where(below[:, None], -(eta * view + light), view + light)
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    h *= np.where(h @ NORMAL < 0.0, -1.0, 1.0)[:, None]
    vh, lh, cos_h = np.einsum("ij,ij->i", h, view), np.einsum("ij,ij->i", light, h), h @ NORMAL
    d = alpha**2 / (math.pi * (cos_h**2 * (alpha**2 - 1.0) + 1.0) ** 2)
    g2 = 1.0 / (1.0 + smith_lambda(cos_v, alpha) + smith_lambda(np.abs(cos_l), alpha))
    f = fresnel(np.clip(vh, 0.0, 1.0), eta)
    reflected = np.where(~below & (vh > 0.0) & (lh > 0.0), f * d * g2 / (4.0 * cos_v), 0.0)
    transmitted = np.where(below & (vh > 0.0) & (lh < 0.0),
                           (1.0 - f) * d * g2 * np.abs(vh * lh) / (cos_v * (eta * vh + lh) ** 2), 0.0)
    return reflected, transmitted


def sphere_about(axis, nodes=600):
    """Directions and solid-angle weights covering the sphere, crowded near ``axis``: the polar
    angle psi = pi s^2 (Gauss-Legendre in s), midpoints in the azimuth."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    s, w_s = 0.5 * (x + 1.0), 0.5 * w
    psi = math.pi * s * s
    dpsi = 2.0 * math.pi * s * w_s
    phi = (np.arange(2 * nodes) + 0.5) * math.pi / nodes
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t1 = np.cross(axis, helper)
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(axis, t1)
    sin = np.sin(psi)[:, None, None]
    d = sin * (np.cos(phi)[None, :, None] * t1 + np.sin(phi)[None, :, None] * t2) + np.cos(psi)[:, None, None] * axis
    weight = (np.sin(psi) * dpsi)[:, None] * np.full(len(phi), math.pi / nodes)[None, :]
    return d.reshape(-1, 3), weight.ravel()


def albedos(theta_v, eta, alpha):
    """(reflected, transmitted) directional albedo by quadrature, each grid crowded about its peak."""
    view = np.array([math.sin(theta_v), 0.0, math.cos(theta_v)])
    mirror = np.array([-view[0], 0.0, view[2]])
    sin_t = eta * math.sin(theta_v)
    through = (np.array([-sin_t, 0.0, -math.sqrt(1.0 - sin_t**2)]) if sin_t < 1.0 else -NORMAL)
    d, w = sphere_about(mirror)
    reflected = float(np.sum(walter(np.broadcast_to(view, d.shape), d, eta, alpha)[0] * w))
    d, w = sphere_about(through)
    transmitted = float(np.sum(walter(np.broadcast_to(view, d.shape), d, eta, alpha)[1] * w))
    return reflected, transmitted


# ---------------------------------------------------------------------------- the integrator's lobes
def glass_lobes(theta_v, roughness, inside, n):
    mats = MaterialTable([Material("glass", base_color=(1.0, 1.0, 1.0), roughness=roughness, transmission=1.0,
                                   ior=1.5)])
    view = np.broadcast_to([math.sin(theta_v), 0.0, math.cos(theta_v)], (n, 3)).copy()
    return _Lobes(mats, np.ones((n, 3)), np.zeros(n, dtype=np.int64), np.broadcast_to(NORMAL, (n, 3)).copy(), view,
                  np.full(n, inside))


def uniforms(n, seed):
    rng = np.random.default_rng(seed)
    return rng.random(n), rng.random(n), rng.random(n)


@pytest.mark.parametrize("inside", [False, True])
@pytest.mark.parametrize("roughness", [0.3, 0.7])
@pytest.mark.parametrize("theta_v", [0.3, 1.1])
def test_rough_transmission_matches_walter_by_quadrature(theta_v, roughness, inside):
    """The transmission lobe's mean sample weight is its directional albedo, the quadrature of
    Walter's f_t |cos| over the far side (entering glass of ior 1.5 and leaving it, where total
    internal reflection takes part of it), over the single-scattering albedo of the whole
    interface (reflection + transmission: the energy compensation)."""
    n = 200_000
    lobes = glass_lobes(theta_v, roughness, inside, n)
    u0, u1, u2 = uniforms(n, 5)
    light, weight, pdf = lobes.sample(np.full(n, _TRANSMIT), np.ones(n), u1, u2)
    eta = 1.5 if inside else 1.0 / 1.5
    reflected, transmitted = albedos(theta_v, eta, roughness**2)
    assert transmitted > 0.01  # from inside at 1.1 rad most of it reflects totally
    expected = transmitted / (reflected + transmitted)
    mean, error = weight[:, 0].mean(), weight[:, 0].std() / math.sqrt(n)
    assert mean == pytest.approx(expected, abs=4.0 * error + 1e-3)
    assert np.all(light[weight[:, 0] > 0.0] @ NORMAL < 0.0)
    assert np.all(np.isinf(pdf))  # no light samples through the glass: its MIS density is a delta's


@pytest.mark.parametrize("roughness", [0.3, 0.7])
@pytest.mark.parametrize("theta_v", [0.3, 1.1])
def test_rough_glass_white_furnace(theta_v, roughness):
    """Reflection plus transmission of clear rough glass, sampled as the path tracer does: the
    single-scattering albedo (quadrature) misses what the microfacets scatter more than once
    (0.1 % at roughness 0.3, 11 % at 0.7 and 1.1 rad); the energy-compensated lobes, as Cycles'
    multiscatter glass, return all of it: 1 within the albedo table's interpolation."""
    n = 200_000
    lobes = glass_lobes(theta_v, roughness, False, n)
    u0, u1, u2 = uniforms(n, 9)
    lobe, probability = lobes.choose(u0)
    assert set(np.unique(lobe)) == {_GLOSSY, _TRANSMIT}
    _, weight, _ = lobes.sample(lobe, probability, u1, u2)
    single = sum(albedos(theta_v, 1.0 / 1.5, roughness**2))
    mean, error = weight[:, 0].mean(), weight[:, 0].std() / math.sqrt(n)
    print(f"rough glass furnace, roughness {roughness}, theta {theta_v}: {mean:.4f} (single scattering {single:.4f})")
    assert mean == pytest.approx(1.0, abs=4.0 * error + 2e-3)
    assert 0.85 < single < 1.0


# ---------------------------------------------------------------------------- the coat
def coated_lobes(coat_roughness, base, n, theta_v=0.8):
    mats = MaterialTable([Material("coated", base_color=(base,) * 3, roughness=1.0, specular_ior_level=0.0,
                                   coat_weight=1.0, coat_roughness=coat_roughness, coat_ior=1.5)])
    view = np.broadcast_to([math.sin(theta_v), 0.0, math.cos(theta_v)], (n, 3)).copy()
    return _Lobes(mats, np.full((n, 3), base), np.zeros(n, dtype=np.int64), np.broadcast_to(NORMAL, (n, 3)).copy(),
                  view, np.zeros(n, dtype=bool))


@pytest.mark.parametrize("coat_roughness", [0.02, 0.3])
def test_a_clear_coat_over_white_keeps_the_furnace_white(coat_roughness):
    """A clear coat (IOR 1.5) over a white Lambertian base: what the coat reflects the base does not
    get, so the layers return all the light; the coat alone over black returns its albedo."""
    n = 200_000
    u0, u1, u2 = uniforms(n, 3)
    for base in (1.0, 0.0):
        lobes = coated_lobes(coat_roughness, base, n)
        lobe, probability = lobes.choose(u0)
        _, weight, _ = lobes.sample(lobe, probability, u1, u2)
        mean, error = weight[:, 0].mean(), weight[:, 0].std() / math.sqrt(n)
        coat_only = fresnel(np.array([math.cos(0.8)]), 1.0 / 1.5)[0] if coat_roughness < 0.05 else None
        expected = 1.0 if base else coat_only
        if expected is not None:
            assert mean == pytest.approx(expected, abs=4.0 * error + 3e-3)
        else:
            assert 0.03 < mean < 0.1


def test_the_rough_coat_is_evaluated_as_it_is_sampled():
    """The value the light samples see (f cos, by uniform directions over the hemisphere) and the
    sampled coat lobe's weights (f cos / pdf) integrate to the same albedo, and its pdf is the
    density of its samples (their mean 1 / pdf is the hemisphere's solid angle)."""
    n = 400_000
    lobes = coated_lobes(0.3, 0.0, n)
    rng = np.random.default_rng(11)
    z, phi = rng.random(n), 2.0 * math.pi * rng.random(n)
    r = np.sqrt(1.0 - z * z)
    uniform = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    by_value = float(np.mean(lobes.value(uniform)[:, 0] * z) * 2.0 * math.pi)
    u0, u1, u2 = uniforms(n, 4)
    light, weight, pdf = lobes.sample(np.full(n, _COAT), np.ones(n), u1, u2)
    by_samples = float(weight[:, 0].mean())
    assert by_samples == pytest.approx(by_value, rel=0.01)
    coat_pdf = lobes.pdf(np.arange(n), lobes.ns, lobes.view, light) / lobes.probability[:, _COAT]
    up = (light @ NORMAL > 0.0) & (coat_pdf > 0.0)
    assert np.mean(np.where(up, 1.0 / np.where(up, coat_pdf, 1.0), 0.0)) == pytest.approx(2.0 * math.pi * up.mean(),
                                                                                              rel=0.02)


def mixed_lobes(n, seed):
    """The lobes of random points of every kind of surface (diffuse only, plastic, metal, mirror,
    rough and smooth glass seen from both sides, rough and mirror coats), random views."""
    mats = MaterialTable([Material("diffuse", (0.7, 0.2, 0.1), specular_ior_level=0.0, roughness=1.0),
                          Material("plastic", (0.2, 0.5, 0.9), roughness=0.4),
                          Material("metal", (0.9, 0.6, 0.3), metallic=1.0, roughness=0.3),
                          Material("half metal", (0.4, 0.6, 0.8), metallic=0.4, roughness=0.5),
                          Material("mirror", (0.9, 0.9, 0.9), metallic=1.0, roughness=0.0),
                          Material("rough glass", roughness=0.3, transmission=1.0, ior=1.45),
                          Material("glass", roughness=0.0, transmission=1.0),
                          Material("coat", (0.7, 0.1, 0.1), roughness=0.6, coat_weight=1.0, coat_roughness=0.3),
                          Material("mirror coat", (0.1, 0.5, 0.1), coat_weight=0.7, coat_roughness=0.0)])
    rng = np.random.default_rng(seed)
    mat = rng.integers(0, len(mats.materials), n)
    view = rng.normal(size=(n, 3))
    view[:, 2] = np.abs(view[:, 2])
    view /= np.linalg.norm(view, axis=1)[:, None]
    lobes = _Lobes(mats, mats.base_color(mat, None), mat, np.broadcast_to(NORMAL, (n, 3)).copy(), view,
                   rng.random(n) < 0.3)
    return lobes, mats, mat, rng


def test_lobes_of_some_points_are_those_points_own():
    """The lobes are worked out only where a material has them, and evaluated at some points by
    index: the same numbers, bit for bit, as the lobes of just those points (``take``), and a
    surface without a specular layer (Specular IOR Level 0) is its plain Lambertian base."""
    n = 4000
    lobes, mats, mat, rng = mixed_lobes(n, 5)
    light = rng.normal(size=(n, 3))
    light /= np.linalg.norm(light, axis=1)[:, None]
    some = np.flatnonzero(rng.random(n) < 0.4)
    own = lobes.take(some)
    np.testing.assert_array_equal(lobes.value(light[some], some), own.value(light[some]))
    np.testing.assert_array_equal(lobes.fresnel(lobes.cos_v[some], index=some), own.fresnel(own.cos_v))
    np.testing.assert_array_equal(lobes.pdf(some, lobes.ns[some], lobes.view[some], light[some]),
                                  own.pdf(np.arange(len(some)), own.ns, own.view, light[some]))
    plain = mat == 0
    lambertian = mats.base[0] * mats.diffuse_weight[0]
    np.testing.assert_array_equal(lobes.diffuse[plain], np.tile(lambertian, (plain.sum(), 1)))


def test_a_lobe_is_chosen_by_its_probability_over_every_lobe():
    """Choosing among the lobes some point has is choosing among all six by their cumulative
    probabilities (the absent ones add 0); past the last (rounding, or nothing scatters) the
    last lobe, of probability 0 there."""
    n = 4000
    lobes, _, _, rng = mixed_lobes(n, 6)
    u = rng.random(n)
    u[:10] = 1.0 - 1e-17  # (rounds to 1: past every cumulative probability)
    lobe, probability = lobes.choose(u)
    every = np.minimum((u[:, None] >= np.cumsum(lobes.probability, axis=1)).sum(axis=1), 5)
    np.testing.assert_array_equal(lobe, every)
    np.testing.assert_array_equal(probability, lobes.probability[np.arange(n), every])
    assert set(np.unique(lobe)) >= {0, 1, 2, 3, 4}

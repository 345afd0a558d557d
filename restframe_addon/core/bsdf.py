"""BSDF evaluation and importance sampling in a surface's rest frame, after Cycles' conventions.

Everything here holds in the frame where the surface is at rest (the only frame where
the law of reflection, Snell's law and Fresnel hold); carrying light between frames is
the caller's business.  All directions are unit (n, 3) rows pointing *away* from the
surface: ``n`` the shading normal on the viewer's side, ``view`` toward whoever looks
(the negated backward ray that hit), ``light`` toward where light comes from (the
backward direction of a bounce or shadow ray).  Scalars per ray are (n,) arrays,
colours (n, C).  Random numbers are arrays of uniforms in [0, 1), so the
deterministic per-(pixel, sample, dimension) numbers of :mod:`.sampling` feed them.

Conventions, as in Cycles:

* ``alpha = roughness^2`` (GGX width); isotropic.
* Smith masking-shadowing is height-correlated: ``G2 = 1 / (1 + Lambda(v) + Lambda(l))``.
* Sampling functions return the sampled direction, its pdf per unit solid angle and the
  throughput weight ``f * |cos(n, light)| / pdf``.  A delta lobe (smooth glass) has
  ``pdf = inf`` (so a light-sampling MIS weight against it is 0) and its weight is the
  lobe's value over its discrete probability.
* Transmission follows Cycles: no ``1/eta^2`` radiance compression (it cancels for
  closed bodies, and Cycles leaves it out).
* Multiscatter GGX (the Principled BSDF's default) as Cycles: the single-scattering lobe
  times :func:`ggx_energy_compensation`, from a directional-albedo table computed here by
  quadrature; a dielectric specular layer scales the diffuse lobe under it by
  ``1 - ggx_dielectric_albedo``.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from . import rows

_MIN_COS = 1e-6  # keeps 1/cos finite for directions grazing the surface
_TWO_PI = 2.0 * np.pi
_ALBEDO_KNOTS = 33  # roughness and cos(view) knots of the albedo table (Cycles: 32 x 32)
_ALBEDO_STRATA = 64  # Gauss-Legendre nodes in theta_h per knot (twice as many in phi)
_SPECULAR_KNOTS = 17  # roughness, cos(view) and sqrt(|(ior - 1) / (ior + 1)|) knots (Cycles: 16^3)
_SPECULAR_STRATA = 32


# ---------------------------------------------------------------------------- Fresnel
def dielectric_f0(ior):
    """Reflectance at normal incidence of a dielectric of relative index ``ior``."""
    return ((ior - 1.0) / (ior + 1.0)) ** 2


def fresnel_dielectric(cos_i, eta):
    """Unpolarised Fresnel reflectance; eta = n_incident / n_transmitted; 1 for total internal reflection."""
    cos_i = np.clip(cos_i, 0.0, 1.0)
    sin_t2 = eta**2 * (1.0 - cos_i**2)
    cos_t = np.sqrt(np.maximum(1.0 - sin_t2, 0.0))
    rs = (eta * cos_i - cos_t) / np.maximum(eta * cos_i + cos_t, 1e-300)
    rp = (cos_i - eta * cos_t) / np.maximum(cos_i + eta * cos_t, 1e-300)
    return np.where(sin_t2 >= 1.0, 1.0, 0.5 * (rs**2 + rp**2))


def fresnel_schlick(cos_i, f0, f90):
    """Schlick's reflectance from ``f0`` (n, C) at normal incidence to ``f90`` (n,) at grazing
    (a new array; the temporaries reused in place: each fresh one costs page faults)."""
    s = np.subtract(1.0, rows.clipped(cos_i, 0.0, 1.0))
    schlick = s * s
    schlick *= schlick
    schlick *= s  # (s^5 by multiplications: pow costs as much as ten of them)
    out = rows.scale(f0, np.subtract(1.0, schlick, out=s))
    out += np.multiply(schlick, f90, out=schlick)[:, None]
    return out


def fresnel_f82_tint(cos_i, f0, tint):
    """Cycles' metallic Fresnel (F82-Tint, Kutz et al.): Schlick from ``f0`` (n, C), with its
    value near 82 degrees multiplied by ``tint`` (n, C) (the Principled BSDF's Specular Tint)."""
    f = 6.0 / 7.0  # 1 - cos(82 degrees) with cos = 1/7
    b = (f0 + (1.0 - f0) * f**5) * (7.0 / f**6) * (1.0 - tint)
    s = (1.0 - np.clip(cos_i, 0.0, 1.0))[:, None]
    schlick = f0 + (1.0 - f0) * s**5
    return np.clip(schlick - b * np.asarray(cos_i)[:, None] * s**6, 0.0, 1.0)


def fresnel_principled_dielectric(cos_i, eta, f0, f90):
    """The Principled BSDF's dielectric Fresnel: the exact dielectric curve remapped from its
    own normal-incidence value to ``f0`` (n, C) .. ``f90`` (n,) (Specular IOR Level and Tint).
    With f0 = dielectric_f0 and f90 = 1 it is :func:`fresnel_dielectric` itself."""
    real = fresnel_dielectric(cos_i, eta)
    real_f0 = dielectric_f0(eta)
    s = np.clip((real - real_f0) / np.maximum(1.0 - real_f0, 1e-300), 0.0, 1.0)
    return rows.scale(f0, 1.0 - s) + (f90 * s)[:, None]


# ---------------------------------------------------------------------------- GGX terms
def ggx_ndf(cos_h, alpha):
    """GGX (Trowbridge-Reitz) distribution D(h) of microfacet normals, per unit solid angle of h."""
    return np.where(cos_h > 0.0, _ggx_ndf_of_squared(np.minimum(cos_h**2, 1.0), alpha), 0.0)


def _ggx_ndf_of_squared(c2, alpha):
    """GGX D(h) (n.h > 0) from c2 = (n.h)^2 in [0, 1]: a^2 / (pi (1 - c2 + a^2 c2)^2), in place
    (c2 overwritten)."""
    a2 = alpha**2
    d = np.subtract(1.0, c2)
    d += np.multiply(c2, a2, out=c2)
    d *= d
    d *= np.pi
    return np.divide(a2, d, out=d)


def ggx_lambda(cos, alpha):
    """Smith's Lambda for GGX (Heitz 2014, eq. 72) at a direction ``cos`` from the normal."""
    c2 = np.clip(cos**2, _MIN_COS**2, 1.0)
    return 0.5 * (np.sqrt(1.0 + alpha**2 * (1.0 / c2 - 1.0)) - 1.0)


def ggx_g1(cos, alpha):
    """Smith masking of one direction."""
    return 1.0 / (1.0 + ggx_lambda(cos, alpha))


def ggx_g2(cos_v, cos_l, alpha):
    """Height-correlated Smith masking-shadowing of a direction pair (as Cycles)."""
    return 1.0 / (1.0 + ggx_lambda(cos_v, alpha) + ggx_lambda(cos_l, alpha))


def ggx_visibility(cos_v, cos_l, alpha):
    """G2 / (4 cos_v cos_l) of :func:`ggx_g2` multiplied out: 1 / (2 (cos_l S_v + cos_v S_l)) with
    S = sqrt(alpha^2 + (1 - alpha^2) cos^2), the cosines clipped to [_MIN_COS, 1] (in place: a
    third of the passes of the Lambdas)."""
    a2 = alpha * alpha
    cos_v, cos_l = rows.clipped(cos_v, _MIN_COS, 1.0), rows.clipped(cos_l, _MIN_COS, 1.0)
    s_v, s_l = cos_v * cos_v, cos_l * cos_l
    for s, other in ((s_v, cos_l), (s_l, cos_v)):
        s *= 1.0 - a2
        s += a2
        np.sqrt(s, out=s)
        s *= other
    s_v += s_l
    s_v *= 2.0
    return np.divide(1.0, s_v, out=s_v)


def ggx_single(cos_v, cos_l, cos_vl, alpha):
    """One GGX lobe's D G2 / (4 cos_v cos_l) (without Fresnel; valid where both directions are
    above the surface) and the half vector's cosine with the view (for the caller's Fresnel term)
    from the cosines of the normal with view and light and of view with light: h = (v + l) / |v + l|
    with |v + l|^2 = 2 (1 + v.l), so n.h = (cos_v + cos_l) / |v + l| and v.h = |v + l| / 2 (three
    dot products, where the half vector took five)."""
    half = np.add(cos_vl, 1.0)  # |v + l|^2 / 2
    np.maximum(half, 1e-300, out=half)
    c2 = np.add(cos_v, cos_l)
    c2 *= c2
    c2 /= half
    c2 *= 0.5
    single = _ggx_ndf_of_squared(np.minimum(c2, 1.0, out=c2), alpha)
    single *= ggx_visibility(cos_v, cos_l, alpha)
    half *= 0.5
    return single, np.sqrt(half, out=half)


def ggx_single_scattering(n, view, light, alpha):
    """:func:`ggx_single` toward ``light``, with the mask of pairs above the horizon."""
    cos_v, cos_l = rows.dot(n, view), rows.dot(n, light)
    single, cos_vh = ggx_single(cos_v, cos_l, rows.dot(view, light), alpha)
    return single, (cos_v > 0.0) & (cos_l > 0.0), cos_vh


def ggx_reflection(n, view, light, alpha, f0, f90, cos_l=None, cos_v=None):
    """GGX specular BRDF value f (n, C), without the cosine: D G2 F / (4 cos_v cos_l), Schlick
    Fresnel from f0 (n, C) to f90 (n,) at the half vector.  0 where either direction is below;
    ``cos_l`` = n . light and ``cos_v`` = n . view where the caller has them."""
    cos_v = rows.dot(n, view) if cos_v is None else cos_v
    cos_l = rows.dot(n, light) if cos_l is None else cos_l
    single, cos_vh = ggx_single(cos_v, cos_l, rows.dot(view, light), alpha)
    if not (len(cos_v) and cos_v.min() > 0.0 and cos_l.min() > 0.0):  # (a NaN's min fails too: masked)
        np.copyto(single, 0.0, where=~((cos_v > 0.0) & (cos_l > 0.0)))
    value = fresnel_schlick(cos_vh, f0, f90)
    return rows.scale(value, single, out=value)  # (its own array: in place)


# ---------------------------------------------------------------------------- local frames
def tangent_frame(n):
    """Two unit tangents (t, b) with (t, b, n) right-handed orthonormal, per row of unit n
    (Duff et al. 2017: continuous except across n_z = 0, no branches)."""
    nx, ny, nz = n[:, 0], n[:, 1], n[:, 2]
    sign = np.where(nz >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    t = np.empty_like(n)
    t[:, 0] = 1.0 + sign * nx * nx * a
    t[:, 1] = sign * b
    t[:, 2] = -sign * nx
    bt = np.empty_like(n)
    bt[:, 0] = b
    bt[:, 1] = sign + ny * ny * a
    bt[:, 2] = -ny
    return t, bt


def _to_world(x, y, z, t, b, n):
    """Rows x t + y b + z n from local coordinates (x, y, z), each (n,)."""
    out = np.empty_like(n)
    for axis in range(3):
        out[:, axis] = x * t[:, axis] + y * b[:, axis] + z * n[:, axis]
    return out


def _concentric_disk(u1, u2):
    """Shirley-Chiu map of the unit square onto the unit disc (keeps strata compact)."""
    a = 2.0 * u1 - 1.0
    b = 2.0 * u2 - 1.0
    first = np.abs(a) > np.abs(b)
    r = np.where(first, a, b)
    quarter = (np.pi / 4.0) * (np.where(first, b, a) / np.where(r == 0.0, 1.0, r))  # (r = 0: any angle)
    phi = np.where(first, quarter, np.pi / 2.0 - quarter)
    return r * np.cos(phi), r * np.sin(phi)


# ---------------------------------------------------------------------------- diffuse
def diffuse_pdf(n, light, cos=None):
    """Cosine-weighted hemisphere density cos/pi per unit solid angle (0 below the surface);
    ``cos`` = n . light where the caller has it."""
    return np.maximum(rows.dot(n, light) if cos is None else cos, 0.0) / np.pi


def sample_diffuse(n, u1, u2):
    """Cosine-weighted directions about n.  Returns (light, pdf); the Lambertian weight
    f cos / pdf is the albedo itself (f = albedo / pi)."""
    x, y = _concentric_disk(u1, u2)
    z = np.sqrt(np.maximum(1.0 - x * x - y * y, 0.0))
    t, b = tangent_frame(n)
    return _to_world(x, y, z, t, b, n), z / np.pi


# ---------------------------------------------------------------------------- GGX sampling
def sample_ggx_vndf(n, view, alpha, u1, u2):
    """Microfacet normals h drawn from the distribution of normals visible from ``view``
    (Heitz 2018), density :func:`ggx_vndf_pdf`.  Needs view above the surface."""
    t, b = tangent_frame(n)
    vx, vy, vz = rows.dot(view, t), rows.dot(view, b), np.maximum(rows.dot(view, n), _MIN_COS)
    # the view direction in the stretched configuration where the distribution is a hemisphere
    sx, sy, sz = alpha * vx, alpha * vy, vz
    length = np.sqrt(sx * sx + sy * sy + sz * sz)
    sx, sy, sz = sx / length, sy / length, sz / length
    lensq = sx * sx + sy * sy
    tiny = lensq <= 1e-14  # normal incidence: any tangent basis
    inv = 1.0 / np.sqrt(np.where(tiny, 1.0, lensq))
    t1x, t1y = np.where(tiny, 1.0, -sy * inv), np.where(tiny, 0.0, sx * inv)
    # T2 = S x T1 with T1 = (t1x, t1y, 0)
    t2x, t2y, t2z = -sz * t1y, sz * t1x, sx * t1y - sy * t1x
    r = np.sqrt(u1)
    phi = _TWO_PI * u2
    p1, p2 = r * np.cos(phi), r * np.sin(phi)
    s = 0.5 * (1.0 + sz)
    p2 = (1.0 - s) * np.sqrt(np.maximum(1.0 - p1 * p1, 0.0)) + s * p2
    p3 = np.sqrt(np.maximum(1.0 - p1 * p1 - p2 * p2, 0.0))
    hx = p1 * t1x + p2 * t2x + p3 * sx
    hy = p1 * t1y + p2 * t2y + p3 * sy
    hz = p2 * t2z + p3 * sz
    # back to the ellipsoid configuration
    hx, hy, hz = alpha * hx, alpha * hy, np.maximum(hz, 0.0)
    length = np.sqrt(hx * hx + hy * hy + hz * hz)
    return _to_world(hx / length, hy / length, hz / length, t, b, n)


def ggx_vndf_pdf(n, view, h, alpha):
    """Density of :func:`sample_ggx_vndf` per unit solid angle of h: G1(v) max(v.h, 0) D(h) / cos_v."""
    cos_v = np.maximum(rows.dot(n, view), _MIN_COS)
    return ggx_g1(cos_v, alpha) * np.maximum(rows.dot(view, h), 0.0) * ggx_ndf(rows.dot(n, h), alpha) / cos_v


def ggx_reflection_pdf(n, view, light, alpha):
    """Density per unit solid angle of light directions from :func:`sample_ggx_reflection`:
    D_v(h) / (4 v.h) = G1(v) D(h) / (4 cos_v)."""
    h = rows.normalized(view + light)
    cos_v = np.maximum(rows.dot(n, view), _MIN_COS)
    pdf = ggx_g1(cos_v, alpha) * ggx_ndf(rows.dot(n, h), alpha) / (4.0 * cos_v)
    return np.where(rows.dot(view, h) > 0.0, pdf, 0.0)


def reflect(view, h):
    """Mirror ``view`` about the (micro)normal h: 2 (v.h) h - v."""
    return rows.add_scaled(-view, 2.0 * rows.dot(view, h), h)


def sample_ggx_reflection(n, view, alpha, u1, u2):
    """Light directions for a GGX lobe by visible-normal sampling.

    Returns (light, pdf, weight): pdf per unit solid angle (:func:`ggx_reflection_pdf`) and
    the scalar weight f cos_l / pdf without Fresnel, G2 / G1(v) (0 where light is below the
    surface).  Multiply it by the lobe's Fresnel at (view . h) = (light . h).
    """
    h = sample_ggx_vndf(n, view, alpha, u1, u2)
    light = reflect(view, h)
    cos_v = np.maximum(rows.dot(n, view), _MIN_COS)
    cos_l = rows.dot(n, light)
    masking = 1.0 + ggx_lambda(cos_v, alpha)  # 1 / G1(v)
    pdf = ggx_ndf(rows.dot(n, h), alpha) / (4.0 * cos_v * masking)
    weight = np.where(cos_l > 0.0, masking / (masking + ggx_lambda(np.maximum(cos_l, _MIN_COS), alpha)), 0.0)
    return light, pdf, weight


# ---------------------------------------------------------------------------- glass
def refract(view, h, eta):
    """Direction transmitted through a (micro)normal h on view's side; eta = n_view / n_other.

    Returns (direction, ok); ok is False at total internal reflection (direction then 0)."""
    cos_i = rows.dot(view, h)
    k2 = 1.0 - eta**2 * (1.0 - cos_i**2)
    ok = k2 > 0.0
    along = eta * cos_i - np.sqrt(np.maximum(k2, 0.0))
    out = rows.add_scaled(rows.scale(view, -eta), along, h)
    out[~ok] = 0.0
    return out, ok


def sample_ggx_transmission(n, view, eta, alpha, u1, u2):
    """Directions through a rough dielectric interface (the transmission half of
    :func:`dielectric_eval`, Walter et al. 2007): a visible microfacet normal h, the view refracted
    through it.  eta = n_view / n_other per ray.

    Returns (light, weight): the scalar throughput weight f_t |cos_l| / pdf_t = (1 - F(v.h)) G2 / G1(v)
    (0 where h reflects totally or sends the ray back to the viewer's side: such samples are lost),
    pdf_t the density of this sampler alone, :func:`dielectric_eval`'s pdf / (1 - F).
    """
    h = sample_ggx_vndf(n, view, alpha, u1, u2)
    light, ok = refract(view, h, eta)
    cos_v = np.maximum(rows.dot(n, view), _MIN_COS)
    cos_l = -rows.dot(n, light)
    ok &= cos_l > 0.0
    masking = 1.0 + ggx_lambda(cos_v, alpha)  # 1 / G1(v)
    through = 1.0 - fresnel_dielectric(rows.dot(view, h), eta)
    weight = np.where(ok, through * masking / (masking + ggx_lambda(np.maximum(cos_l, _MIN_COS), alpha)), 0.0)
    return light, weight


def _glass_half_vector(n, view, light, eta):
    """Microfacet normal joining view and light (reflection or refraction), on n's side."""
    transmitted = rows.dot(n, light) < 0.0
    h = np.where(transmitted[:, None], -(rows.scale(view, eta) + light), view + light)
    h = rows.normalized(h)
    return rows.scale(h, np.where(rows.dot(n, h) < 0.0, -1.0, 1.0)), transmitted


def dielectric_eval(n, view, light, eta, alpha):
    """A rough dielectric interface (Walter et al. 2007 with the visible-normal pdf, Fresnel
    ``fresnel_dielectric``): returns (f |cos_l| (n,), pdf (n,)) for light on either side.
    eta = n_view / n_other per ray.  Use only for alpha above the smooth limit."""
    h, transmitted = _glass_half_vector(n, view, light, eta)
    cos_v = np.maximum(rows.dot(n, view), _MIN_COS)
    cos_l = np.abs(rows.dot(n, light))
    v_h, l_h = rows.dot(view, h), rows.dot(light, h)
    fresnel = fresnel_dielectric(v_h, eta)
    d = ggx_ndf(rows.dot(n, h), alpha)
    visible = ggx_g1(cos_v, alpha) * d / cos_v  # D_v(h) / (v.h)
    g2 = ggx_g2(cos_v, np.maximum(cos_l, _MIN_COS), alpha)
    denom = np.maximum((eta * v_h + l_h) ** 2, 1e-300)
    jacobian = np.where(transmitted, np.abs(v_h * l_h) / denom, 0.25)  # (v.h) |dh / dl|
    # a direction pair is valid when both sides agree with the microfacet
    valid = (v_h > 0.0) & np.where(transmitted, l_h < 0.0, l_h > 0.0) & (rows.dot(n, view) > 0.0)
    lobe = np.where(transmitted, 1.0 - fresnel, fresnel)
    pdf = np.where(valid, lobe * visible * jacobian, 0.0)
    value = np.where(valid, lobe * g2 * d / cos_v * jacobian, 0.0)
    return value, pdf


def sample_dielectric(n, view, eta, alpha, u1, u2, u3, smooth):
    """Reflection or transmission at a dielectric interface, chosen by Fresnel.

    eta = n_view / n_other per ray; ``smooth`` (n,) bool selects the delta interface (mirror
    and Snell directions about n itself) over rough GGX glass.  Returns
    (light, pdf, weight, transmitted): pdf per unit solid angle (inf for smooth rays) and
    the scalar throughput weight f |cos_l| / pdf (1 for smooth glass: the Fresnel choice is
    exact; G2 / G1(v) for rough glass).  A rough sample sent by its microfacet to the wrong
    side of the surface has pdf 0 and weight 0 (the path ends there), so the densities of
    the valid samples, :func:`dielectric_eval`'s pdf, integrate to less than 1.
    """
    h = n.copy()
    rough = ~smooth
    if rough.any():
        h[rough] = sample_ggx_vndf(n[rough], view[rough], alpha[rough], u1[rough], u2[rough])
    fresnel = fresnel_dielectric(rows.dot(view, h), eta)
    transmit = u3 >= fresnel
    refracted, ok = refract(view, h, eta)
    transmit &= ok  # total internal reflection already has fresnel == 1: only rounding gets here
    light = np.where(transmit[:, None], refracted, reflect(view, h))
    pdf = np.full(len(n), np.inf)
    weight = np.ones(len(n))
    if rough.any():
        value, pdf_r = dielectric_eval(n[rough], view[rough], light[rough], eta[rough], alpha[rough])
        # a microfacet may send light to the wrong side of the surface: such samples are lost
        # (weight 0), and the pdf of a valid direction is that of its own route only
        wrong_side = transmit[rough] != (rows.dot(n[rough], light[rough]) < 0.0)
        pdf_r[wrong_side] = 0.0
        pdf[rough] = pdf_r
        weight[rough] = np.where(pdf_r > 0.0, value / np.where(pdf_r > 0.0, pdf_r, 1.0), 0.0)
    return light, pdf, weight, transmit


# ---------------------------------------------------------------------------- energy compensation
def fresnel_average_schlick(f0, f90):
    """Cosine-weighted hemispherical average 2 int F mu dmu of Schlick's Fresnel: f0 + (f90 - f0) / 21."""
    return f0 + (np.asarray(f90)[:, None] - f0) / 21.0


def fresnel_average_f82_tint(f0, tint):
    """The same average of :func:`fresnel_f82_tint` (Cycles' ``fresnel_f82_Fss``)."""
    f = 6.0 / 7.0
    b = (f0 + (1.0 - f0) * f**5) * (7.0 / f**6) * (1.0 - tint)
    return f0 + (1.0 - f0) / 21.0 - b / 126.0


@lru_cache(maxsize=None)
def _gauss_legendre(nodes: int):
    """numpy's Gauss-Legendre nodes and weights, computed once (6 ms each time: half of a small
    scene's rebuild in every worker process), read-only."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    x.flags.writeable = w.flags.writeable = False
    return x, w


def fresnel_average_dielectric(eta):
    """The same average of :func:`fresnel_dielectric`: below the critical cosine (eta > 1) F = 1
    contributes mu_c^2 exactly, the rest by Gauss-Legendre."""
    eta = np.asarray(eta, dtype=np.float64)
    mu_c = np.sqrt(np.maximum(1.0 - 1.0 / eta**2, 0.0))[..., None]
    x, w = _gauss_legendre(48)
    mu = mu_c + 0.5 * (x + 1.0) * (1.0 - mu_c)
    values = fresnel_dielectric(mu, eta[..., None])
    return mu_c[..., 0] ** 2 + (1.0 - mu_c[..., 0]) * np.sum(values * mu * w, axis=-1)


def _microfacet_quadrature(alpha, mu, strata):
    """Nodes of the integral over microfacet normals h about n = z, seen from cos_v = mu (in the
    x-z plane): (v.h, cos_l of the reflection, weight, cos_h), each broadcast to (mu, s, phi), where weight
    includes D(h) dOmega_h.  tan(theta_h) = alpha tan(pi s / 2), Gauss-Legendre in s, makes
    D(h) dOmega_h bounded and smooth, heavy GGX tail included (a midpoint grid of the
    visible-normal sampler misses that tail)."""
    x, w_s = np.polynomial.legendre.leggauss(strata)
    s = 0.5 * (x + 1.0)
    phi = (np.arange(2 * strata) + 0.5) * (np.pi / strata)  # [0, 2 pi), midpoints
    t = np.tan(0.5 * np.pi * s)[None, :, None]
    tan_h = alpha * t
    cos_h = 1.0 / np.sqrt(1.0 + tan_h * tan_h)
    sin_h = tan_h * cos_h
    mu = np.asarray(mu)[:, None, None]
    v_h = np.sqrt(1.0 - mu * mu) * sin_h * np.cos(phi)[None, None, :] + mu * cos_h
    cos_l = 2.0 * v_h * cos_h - mu
    # D(h) sin(theta_h) dtheta_h / ds, simplified, times the Gauss-Legendre and phi weights
    weight = t / (2.0 * cos_h * (1.0 + t * t)) * (0.5 * w_s)[None, :, None] * (np.pi / strata)
    return v_h, cos_l, weight, cos_h


def _albedo_integrand(alpha, mu, v_h, cos_l):
    """(v.h)+ G2(v, l) / cos_v where l is above the surface: the F = 1 albedo per unit D dOmega_h."""
    g2 = 1.0 / (1.0 + ggx_lambda(mu, alpha) + ggx_lambda(np.maximum(cos_l, _MIN_COS), alpha))
    return np.where((v_h > 0.0) & (cos_l > 0.0), v_h * g2 / mu, 0.0)


@lru_cache(maxsize=1)
def _albedo_tables():
    """E(roughness, cos_v): the single-scattering albedo of GGX with F = 1 on a knot grid, and
    E_avg(roughness) = 2 int E mu dmu."""
    knots = np.linspace(0.0, 1.0, _ALBEDO_KNOTS)
    mu = np.maximum(knots, 1e-4)
    albedo = np.empty((len(knots), len(knots)))
    for i, roughness in enumerate(knots):
        alpha = max(roughness * roughness, 1e-4)
        v_h, cos_l, weight, _ = _microfacet_quadrature(alpha, mu, _ALBEDO_STRATA)
        albedo[i] = np.sum(_albedo_integrand(alpha, mu[:, None, None], v_h, cos_l) * weight, axis=(1, 2))
    x, w = np.polynomial.legendre.leggauss(24)
    nodes = 0.5 * (x + 1.0)
    average = np.array([np.sum(np.interp(nodes, knots, row) * nodes * w) for row in albedo])
    return knots, albedo, average


def ggx_albedo(cos_v, alpha):
    """Directional albedo E of the single-scattering GGX lobe with F = 1 (table, bilinear)."""
    knots, albedo, _ = _albedo_tables()
    r = np.clip(np.sqrt(alpha), 0.0, 1.0) * (len(knots) - 1)
    m = np.clip(cos_v, 0.0, 1.0) * (len(knots) - 1)
    r0 = np.minimum(np.floor(r).astype(np.int64), len(knots) - 2)
    m0 = np.minimum(np.floor(m).astype(np.int64), len(knots) - 2)
    fr, fm = r - r0, m - m0
    return ((1 - fr) * ((1 - fm) * albedo[r0, m0] + fm * albedo[r0, m0 + 1])
            + fr * ((1 - fm) * albedo[r0 + 1, m0] + fm * albedo[r0 + 1, m0 + 1]))


def ggx_average_albedo(alpha):
    """Cosine-weighted average albedo E_avg of the single-scattering GGX lobe with F = 1."""
    knots, _, average = _albedo_tables()
    return np.interp(np.sqrt(alpha), knots, average)


def fresnel_average_principled_dielectric(eta, f0, f90):
    """The hemispherical average of :func:`fresnel_principled_dielectric` (as Cycles: the real
    curve's average remapped like the curve itself)."""
    real_f0 = dielectric_f0(eta)
    s = np.clip((fresnel_average_dielectric(eta) - real_f0) / np.maximum(1.0 - real_f0, 1e-300), 0.0, 1.0)
    return rows.scale(f0, 1.0 - s) + (f90 * s)[:, None]


@lru_cache(maxsize=1)
def _dielectric_albedo_table():
    """s(roughness, cos_v, z): over the reflected light of a GGX lobe seen from cos_v, the average
    of the Principled Fresnel's interpolation weight (F_real - F0_real) / (1 - F0_real), for
    light arriving from outside a dielectric of ior = (1 + z^2) / (1 - z^2)."""
    knots = np.linspace(0.0, 1.0, _SPECULAR_KNOTS)
    mu = np.maximum(knots, 1e-4)
    z = np.minimum(knots, 0.99)[:, None, None, None]
    eta = (1.0 - z * z) / (1.0 + z * z)  # n_outside / n_inside
    real_f0 = dielectric_f0(eta)
    table = np.empty((len(knots), len(knots), len(knots)))
    for i, roughness in enumerate(knots):
        alpha = max(roughness * roughness, 1e-4)
        v_h, cos_l, weight, _ = _microfacet_quadrature(alpha, mu, _SPECULAR_STRATA)
        albedo = _albedo_integrand(alpha, mu[:, None, None], v_h, cos_l) * weight
        shape = np.clip((fresnel_dielectric(v_h[None], eta) - real_f0) / (1.0 - real_f0), 0.0, 1.0)
        table[i] = (np.sum(shape * albedo[None], axis=(2, 3)) / np.sum(albedo, axis=(1, 2))[None, :]).T
    return knots, table


def _trilinear(table, knots, a, b, c):
    """Trilinear interpolation of table[i, j, k] on the same knots along each axis, at (a, b, c) in [0, 1]."""
    last = len(knots) - 1
    out = 0.0
    corners = []
    for x in (a, b, c):
        x = np.clip(x, 0.0, 1.0) * last
        x0 = np.minimum(np.floor(x).astype(np.int64), last - 1)
        corners.append((x0, x - x0))
    (i, fi), (j, fj), (k, fk) = corners
    for di, wi in ((0, 1.0 - fi), (1, fi)):
        for dj, wj in ((0, 1.0 - fj), (1, fj)):
            for dk, wk in ((0, 1.0 - fk), (1, fk)):
                out = out + wi * wj * wk * table[i + di, j + dj, k + dk]
    return out


def ggx_dielectric_albedo(cos_v, alpha, eta, f0, f90):
    """Directional albedo (n, C) of an energy-compensated GGX lobe with the Principled dielectric
    Fresnel (``fresnel_principled_dielectric`` from f0 (n, C) to f90 (n,)), as Cycles estimates it
    to layer the lobe over the diffuse one (which it scales by 1 - albedo): f0 + (f90 - f0) s,
    s from a table.  For light from outside (eta = n_view / n_other < 1); eta > 1 is read as
    its reciprocal."""
    knots, table = _dielectric_albedo_table()
    ior = np.where(eta < 1.0, 1.0 / eta, eta)
    z = np.sqrt(np.abs((ior - 1.0) / (ior + 1.0)))
    s = _trilinear(table, knots, np.sqrt(alpha), cos_v, z)
    return rows.scale(f0, 1.0 - s) + (f90 * s)[:, None]


def ggx_energy_compensation(cos_v, alpha, fresnel_average):
    """Cycles' Multiscatter GGX factor (n, C) on a single-scattering GGX lobe seen from cos_v:
    ``1 + F_ms (1 - E) / E`` with ``F_ms = F_avg E_avg / (1 - F_avg (1 - E_avg))`` (Kulla and Conty
    2017); ``fresnel_average`` (n, C) is the lobe's hemispherical Fresnel average (the
    ``fresnel_average_*`` functions).  With F = 1 it is 1 / E: the white furnace is exactly 1.
    """
    e = np.maximum(ggx_albedo(cos_v, alpha), 1e-6)[:, None]
    e_avg = ggx_average_albedo(alpha)[:, None]
    f_ms = fresnel_average * e_avg / (1.0 - fresnel_average * (1.0 - e_avg))
    return 1.0 + f_ms * (1.0 - e) / e


@lru_cache(maxsize=1)
def _glass_albedo_tables():
    """E(roughness, cos_v, z) of single-scattering GGX glass (reflection and refraction, Fresnel of
    the interface, as :func:`dielectric_eval`), for light arriving from outside (eta = n_view / n_other
    = 1 / ior) and from inside (eta = ior), ior = (1 + z^2) / (1 - z^2)."""
    knots = np.linspace(0.0, 1.0, _SPECULAR_KNOTS)
    mu = np.maximum(knots, 1e-4)
    z = np.minimum(knots, 0.99)[:, None, None, None]
    ior = (1.0 + z * z) / (1.0 - z * z)
    tables = []
    for eta in (1.0 / ior, ior):
        table = np.empty((len(knots), len(knots), len(knots)))
        for i, roughness in enumerate(knots):
            alpha = max(roughness * roughness, 1e-4)
            v_h, cos_r, weight, cos_h = _microfacet_quadrature(alpha, mu, _SPECULAR_STRATA)
            m = mu[:, None, None]
            fresnel = fresnel_dielectric(v_h[None], eta)
            k2 = 1.0 - eta**2 * (1.0 - v_h[None] ** 2)
            cos_t = -eta * m + (eta * v_h[None] - np.sqrt(np.maximum(k2, 0.0))) * cos_h  # the refracted ray's
            g1 = 1.0 + ggx_lambda(m, alpha)
            g2_r = 1.0 / (g1 + ggx_lambda(np.maximum(cos_r, _MIN_COS), alpha))
            g2_t = 1.0 / (g1 + ggx_lambda(np.maximum(-cos_t, _MIN_COS), alpha))
            visible = np.where(v_h > 0.0, v_h / m, 0.0)[None] * weight[None]  # D (v.h) / cos_v dOmega_h
            integrand = (np.where(cos_r[None] > 0.0, fresnel * g2_r, 0.0)
                         + np.where((k2 > 0.0) & (cos_t < 0.0), (1.0 - fresnel) * g2_t, 0.0))
            table[i] = np.sum(integrand * visible, axis=(2, 3)).T
        tables.append(table)
    return knots, tables


def ggx_glass_albedo(cos_v, alpha, eta):
    """Directional albedo of single-scattering GGX glass seen from cos_v (reflection plus
    transmission, < 1 by what the microfacets scatter more than once); eta = n_view / n_other
    (below 1: from outside).  Cycles scales its multiscatter glass by 1 / this (energy preserved)."""
    knots, (outside, inside) = _glass_albedo_tables()
    ior = np.where(eta < 1.0, 1.0 / eta, eta)
    z = np.sqrt(np.abs((ior - 1.0) / (ior + 1.0)))
    a = np.sqrt(alpha)
    return np.where(eta < 1.0, _trilinear(outside, knots, a, cos_v, z), _trilinear(inside, knots, a, cos_v, z))

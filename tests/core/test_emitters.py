"""Emissive triangles as lights: power-proportional choice, uniform points, densities per area and
solid angle, irradiance against Lambert's polygon formula (with MIS), and across frames."""

import math

import numpy as np
import pytest

from restframe_addon.core import bsdf, mis, world
from restframe_addon.core.emitters import EmitterTable, solid_angle_pdf
from restframe_addon.core.lorentz import Boost


def square(centre, half, z_down=True):
    """Two triangles of a horizontal square at height centre[2] (normal -Z when z_down)."""
    c = np.asarray(centre, dtype=np.float64)
    a, b, cc, d = (c + [-half, -half, 0], c + [half, -half, 0], c + [half, half, 0], c + [-half, half, 0])
    tris = np.array([[a, cc, b], [a, d, cc]]) if z_down else np.array([[a, b, cc], [a, cc, d]])
    return tris, np.array([a, b, cc, d])


def lambert_polygon_irradiance(x, n, polygon, radiance):
    """Irradiance at x (normal n) from a Lambertian polygon of uniform radiance (Lambert's formula):
    E = L/2 |sum_i angle(r_i, r_i+1) n . unit(r_i x r_i+1)|, the polygon wholly above the surface."""
    r = polygon - x
    r /= np.linalg.norm(r, axis=1, keepdims=True)
    total = 0.0
    for i in range(len(r)):
        a, b = r[i], r[(i + 1) % len(r)]
        cross = np.cross(a, b)
        total += math.acos(np.clip(a @ b, -1, 1)) * (n @ cross) / np.linalg.norm(cross)
    return 0.5 * radiance * abs(total)


def test_triangles_are_drawn_by_area_times_luminance_and_points_are_uniform():
    rng = np.random.default_rng(1)
    vertices = rng.normal(size=(5, 3, 3))
    emission = np.array([[1.0, 1, 1], [0.0, 0, 0], [5.0, 0.1, 0.0], [0.2, 0.2, 3.0], [1.0, 2.0, 0.5]])
    table = EmitterTable(vertices, emission, prims=np.array([10, 11, 12, 13, 14]))
    area = 0.5 * np.linalg.norm(np.cross(vertices[:, 1] - vertices[:, 0], vertices[:, 2] - vertices[:, 0]), axis=1)
    luminance = emission @ np.array([0.2126, 0.7152, 0.0722])
    expected = area * luminance / np.sum(area * luminance)
    assert np.allclose(table.probability, expected, rtol=1e-12)
    n = 200_000
    index, point, normal, pdf = table.sample(rng.random(n), rng.random(n), rng.random(n))
    counts = np.bincount(index, minlength=5)
    assert counts[1] == 0  # no luminance: never drawn
    keep = expected > 0
    chi2 = np.sum((counts[keep] - n * expected[keep]) ** 2 / (n * expected[keep]))
    assert chi2 < 4 + 6 * math.sqrt(8)
    assert np.allclose(pdf, expected[index] / area[index], rtol=1e-12)
    assert np.sum(table.pdf_area(np.arange(5)) * area) == pytest.approx(1.0, rel=1e-12)
    assert np.array_equal(table.prims[index[:3]], index[:3] + 10)
    # barycentric coordinates of the points on one triangle: uniform over it
    sel = index == 4
    e1, e2 = vertices[4, 1] - vertices[4, 0], vertices[4, 2] - vertices[4, 0]
    rel = point[sel] - vertices[4, 0]
    b = np.linalg.lstsq(np.stack([e1, e2], axis=1), rel.T, rcond=None)[0].T
    assert np.allclose(np.stack([e1, e2], axis=1) @ b.T, rel.T, atol=1e-10)  # in the plane
    assert np.all(b >= -1e-12) and np.all(b.sum(axis=1) <= 1 + 1e-12)
    # uniform: the fraction of points in the sub-triangle b1 + b2 < 1/2 is 1/4, b1 < 1/2 is 3/4
    m = sel.sum()
    assert np.mean(b.sum(axis=1) < 0.5) == pytest.approx(0.25, abs=4 * math.sqrt(0.25 * 0.75 / m))
    assert np.mean(b[:, 0] < 0.5) == pytest.approx(0.75, abs=4 * math.sqrt(0.25 * 0.75 / m))
    assert np.allclose(np.abs(normal[sel] @ np.cross(e1, e2)), np.linalg.norm(np.cross(e1, e2)))


def test_empty_table():
    table = EmitterTable(np.zeros((1, 3, 3)), np.ones((1, 3)))
    assert table.is_empty
    with pytest.raises(ValueError, match="no emissive triangle"):
        table.sample(np.zeros(1), np.zeros(1), np.zeros(1))
    with pytest.raises(ValueError, match="2 triangles but 1 emissions"):
        EmitterTable(np.zeros((2, 3, 3)), np.ones((1, 3)))


def test_irradiance_from_an_emissive_square_by_light_sampling_and_mis():
    """A square panel of radiance L above a tilted surface: light sampling alone, and MIS with
    cosine sampling (rays intersected with the panel here), both give Lambert's exact formula."""
    tris, polygon = square((0.3, -0.2, 1.0), 0.4)
    L = 2.0
    table = EmitterTable(tris, np.full((2, 3), L))
    x = np.array([0.0, 0.0, 0.0])
    n_surf = np.array([0.2, 0.1, 1.0]) / np.linalg.norm([0.2, 0.1, 1.0])
    exact = lambert_polygon_irradiance(x, n_surf, polygon, L)
    m = 200_000
    rng = np.random.default_rng(2)
    index, point, normal, pdf_area = table.sample(rng.random(m), rng.random(m), rng.random(m))
    direction, _, pdf_light = solid_angle_pdf(pdf_area, np.broadcast_to(x, (m, 3)), point, normal)
    cos = np.maximum(direction @ n_surf, 0.0)
    light_only = L * cos / pdf_light
    assert light_only.mean() == pytest.approx(exact, rel=0.01)
    # cosine-sampled directions: where they hit the panel, their light-sampling density
    d, pdf_bsdf = bsdf.sample_diffuse(np.broadcast_to(n_surf, (m, 3)), rng.random(m), rng.random(m))
    t = np.where(d[:, 2] > 0, 1.0 / np.maximum(d[:, 2], 1e-300), np.inf)
    hit_point = d * t[:, None]
    inside = (np.abs(hit_point[:, 0] - 0.3) < 0.4) & (np.abs(hit_point[:, 1] + 0.2) < 0.4) & np.isfinite(t)
    _, _, pdf_light_b = solid_angle_pdf(np.where(inside, table.pdf_area(np.zeros(m, int)), 0.0),
                                        np.broadcast_to(x, (m, 3)), np.where(inside[:, None], hit_point, 1.0),
                                        np.broadcast_to([0, 0, -1.0], (m, 3)))
    cos_b = np.maximum(d @ n_surf, 0.0)
    from_bsdf = np.where(inside, mis.power_heuristic(pdf_bsdf, pdf_light_b) * L * cos_b / pdf_bsdf, 0.0)
    from_light = mis.power_heuristic(pdf_light, cos / math.pi) * light_only
    assert (from_bsdf + from_light).mean() == pytest.approx(exact, rel=0.01)


def test_a_moving_receiver_sees_the_panel_through_the_jacobian():
    """A receiver moving at 0.7c under a panel at rest in S: emitter points drawn in S, their
    solid-angle density carried into the receiver's frame by D^2, estimate integral L D^4 cos
    dOmega'; the reference integrates over the receiver's hemisphere, ray by ray."""
    tris, _ = square((0.0, 0.0, 1.0), 0.5)
    L = 1.0
    table = EmitterTable(tris, np.full((2, 3), L))
    beta = np.array([0.7, 0.0, 0.0])
    to_frame, to_world = Boost.from_velocity(beta), Boost.from_velocity(-beta)
    n_surf = np.array([0.0, 0.0, 1.0])  # the receiver's normal in its frame
    m = 400_000
    rng = np.random.default_rng(3)
    x = np.zeros((m, 3))  # the receiving event, at the origin of both frames
    index, point, normal, pdf_area = table.sample(rng.random(m), rng.random(m), rng.random(m))
    direction, _, pdf_s = solid_angle_pdf(pdf_area, x, point, normal)
    d_frame, doppler = to_frame.rays(direction)
    pdf_frame = world.frame_pdf(pdf_s, doppler)
    estimate = np.mean(L * doppler**4 * np.maximum(d_frame @ n_surf, 0.0) / pdf_frame)
    # reference: quadrature over the receiver's hemisphere, each direction mapped to S and
    # intersected with the panel there
    nt, nph = 1500, 1500
    th, ph = np.meshgrid((np.arange(nt) + 0.5) * (math.pi / 2 / nt), (np.arange(nph) + 0.5) * (2 * math.pi / nph),
                         indexing="ij")
    th, ph = th.ravel(), ph.ravel()
    d = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=1)
    d_s, w = to_world.rays(d)
    t = np.where(d_s[:, 2] > 0, 1.0 / np.maximum(d_s[:, 2], 1e-300), np.inf)
    hit = (np.abs(d_s[:, 0] * t) < 0.5) & (np.abs(d_s[:, 1] * t) < 0.5)
    omega = np.sin(th) * (math.pi / 2 / nt) * (2 * math.pi / nph)
    reference = np.sum(np.where(hit, L * (1.0 / w) ** 4 * np.cos(th) * omega, 0.0))
    assert estimate == pytest.approx(reference, rel=0.01)
    at_rest = lambert_polygon_irradiance(np.zeros(3), n_surf, square((0, 0, 1.0), 0.5)[1], L)
    assert abs(reference / at_rest - 1.0) > 0.1  # motion matters here

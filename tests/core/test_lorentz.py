"""Lorentz maths against an arbitrary-precision (mpmath) reference, from b = 1e-12 to gamma = 1e8."""

import math

import mpmath as mp
import numpy as np
import pytest

from restframe_addon.core.frames import FrameMap
from restframe_addon.core.lorentz import Boost, compose_velocities, events_of_boosts

mp.mp.dps = 60

SPEEDS = [1e-12, 1e-9, 1e-6, 1e-3, 0.1, 0.5, 0.8, 0.9, 0.99, 1 - 1e-6, 1 - 1e-9, 1 - 1e-12]
GAMMAS = [1.0 + 1e-9, 2.0, 1e3, 1e6, 1e8]
AXIS = np.array([0.36, -0.48, 0.8])  # exactly unit in decimal, close to unit in binary


def mp_vec(v):
    return [mp.mpf(float(c)) for c in v]


def mp_unit(v):
    v = mp_vec(v)
    norm = mp.sqrt(sum(c * c for c in v))
    return [c / norm for c in v]


def mp_boost_parts(boost, beta=None, gamma=None):
    """(n, b, gamma) in mpmath, from the exact float inputs.

    The direction is the boost's own float unit vector taken as exact: the
    aberration amplifies a direction's last-bit uncertainty by up to 2 gamma, an
    error of the input, not of the algorithm under test.
    """
    n = mp_unit(boost.n)
    if beta is not None:
        b = mp.sqrt(sum(c * c for c in mp_vec(beta)))
        return n, b, 1 / mp.sqrt(1 - b * b)
    g = mp.mpf(gamma)
    return n, mp.sqrt(1 - 1 / (g * g)), g


def mp_rays(parts, d):
    n, b, g = parts
    d = mp_unit(d)
    nd = sum(a * c for a, c in zip(n, d))
    bd = b * nd
    w = g * (1 + bd)
    k = g * g / (g + 1)
    d_new = [(dc + (k * b * bd + g * b) * nc) / w for dc, nc in zip(d, n)]
    return d_new, w


def mp_events(parts, tau, x):
    n, b, g = parts
    x = mp_vec(x)
    tau = mp.mpf(float(tau))
    nx = sum(a * c for a, c in zip(n, x))
    x_new = [xc + ((g - 1) * nx - g * b * tau) * nc for xc, nc in zip(x, n)]
    return g * (tau - b * nx), x_new


def directions_for(n):
    """Head-on, receding, grazing and near-axis directions relative to the unit axis n."""
    n = np.asarray(n, float) / np.linalg.norm(n)
    t = np.cross(n, [1.0, 0.0, 0.0])
    t /= np.linalg.norm(t)
    out = [-n, n, t]
    for angle in (1e-9, 1e-6, 1e-3, 0.3, 2.0, math.pi - 1e-6):
        out.append(math.cos(math.pi - angle) * n + math.sin(math.pi - angle) * t)
    rng = np.random.default_rng(1)
    for _ in range(4):
        v = rng.normal(size=3)
        out.append(v / np.linalg.norm(v))
    return [d / np.linalg.norm(d) for d in out]


def boosts():
    for b in SPEEDS:
        beta = b * AXIS
        boost = Boost.from_velocity(beta)
        yield f"beta={b}", boost, mp_boost_parts(boost, beta=beta)
        axis_beta = (0.0, 0.0, -b)  # along an axis the speed is exact
        boost = Boost.from_velocity(axis_beta)
        yield f"beta_z=-{b}", boost, mp_boost_parts(boost, beta=axis_beta)
    for g in GAMMAS:
        boost = Boost.from_velocity(AXIS, lorentz_factor=g)
        yield f"gamma={g}", boost, mp_boost_parts(boost, gamma=g)


BOOSTS = list(boosts())


def rel(a, b):
    return abs(mp.mpf(float(a)) - b) / abs(b)


@pytest.mark.parametrize("label,boost,ref", BOOSTS, ids=[b[0] for b in BOOSTS])
def test_speed_and_gamma_match_reference(label, boost, ref):
    n, b, g = ref
    assert rel(boost.gamma, g) < 4e-16
    assert rel(boost.b, b) < 4e-16
    assert rel(boost.one_minus_b, 1 - b) < 1e-15
    if g - 1 > 0:
        assert rel(boost.gamma_minus_one, g - 1) < 1e-9 if g - 1 < 1e-8 else rel(boost.gamma_minus_one, g - 1) < 1e-15


@pytest.mark.parametrize("label,boost,ref", BOOSTS, ids=[b[0] for b in BOOSTS])
def test_aberration_and_doppler_match_reference(label, boost, ref):
    """d' and D to ~1e-15 relative at head-on, grazing and receding angles; never NaN."""
    n = boost.n
    ds = np.array(directions_for(n))
    d_new, w = boost.rays(ds)
    assert np.all(np.isfinite(d_new)) and np.all(np.isfinite(w)) and np.all(w > 0)
    for i, d in enumerate(ds):
        ref_d, ref_w = mp_rays(ref, d)
        assert rel(w[i], ref_w) < 5e-15, (d, float(w[i]), ref_w)
        # parallel and perpendicular parts, each to relative accuracy
        nn = ref[0]
        par = sum(a * c for a, c in zip(ref_d, nn))
        perp = [a - par * c for a, c in zip(ref_d, nn)]
        got_par = float(d_new[i] @ n)
        got_perp = d_new[i] - got_par * n
        assert abs(mp.mpf(got_par) - par) < 5e-15 * max(abs(par), mp.mpf(1e-300)) + 1e-15 * mp.norm(perp)
        perp_norm = mp.sqrt(sum(c * c for c in perp))
        err = mp.sqrt(sum((mp.mpf(float(a)) - c) ** 2 for a, c in zip(got_perp, perp)))
        assert err <= 5e-15 * perp_norm + 1e-15 * abs(par), (d, float(err), float(perp_norm))


@pytest.mark.parametrize("label,boost,ref", BOOSTS, ids=[b[0] for b in BOOSTS])
def test_doppler_closed_forms(label, boost, ref):
    """Head-on approach D = gamma (1 + b), recession D = 1/(gamma (1 + b)), across the motion
    (in the observer frame) D = 1/gamma."""
    n, b, g = ref
    t = np.cross(boost.n, [1.0, 0.0, 0.0])
    t /= np.linalg.norm(t)
    d_head, d_back, d_side = boost.doppler(np.array([-boost.n, boost.n, t]))
    assert rel(d_head, g * (1 + b)) < 5e-15
    assert rel(d_back, 1 / (g * (1 + b))) < 5e-15
    assert rel(d_side, 1 / g) < 5e-15


@pytest.mark.parametrize("label,boost,ref", BOOSTS, ids=[b[0] for b in BOOSTS])
def test_event_boost_round_trip_and_interval(label, boost, ref):
    rng = np.random.default_rng(7)
    tau = rng.normal(size=20) * 10.0
    x = rng.normal(size=(20, 3)) * 10.0
    tau2, x2 = boost.events(tau, x)
    back_tau, back_x = boost.inverse().events(tau2, x2)
    g = float(ref[2])
    for i in range(20):
        ref_tau, ref_x = mp_events(ref, tau[i], x[i])
        scale = abs(ref_tau) + mp.norm(ref_x)
        assert abs(mp.mpf(float(tau2[i])) - ref_tau) < 4e-16 * 4 * scale
        assert max(abs(mp.mpf(float(a)) - c) for a, c in zip(x2[i], ref_x)) < 4e-16 * 4 * scale
        # the interval tau^2 - |x|^2 is invariant, to the precision the magnitudes allow
        before = tau[i] ** 2 - x[i] @ x[i]
        after = tau2[i] ** 2 - x2[i] @ x2[i]
        assert abs(after - before) <= 1e-14 * (tau2[i] ** 2 + x2[i] @ x2[i])
    # the round trip loses at most what gamma amplifies
    scale = np.abs(tau) + np.linalg.norm(x, axis=1)
    assert np.all(np.abs(back_tau - tau) <= 1e-15 * 8 * g * g * scale)
    assert np.all(np.linalg.norm(back_x - x, axis=1) <= 1e-15 * 8 * g * g * scale)


def test_rays_are_continuous_at_rest():
    """b = 1e-12 is indistinguishable from b = 0 (no 0/0 at rest)."""
    ds = np.array(directions_for(AXIS))
    still, w0 = Boost.from_velocity((0.0, 0.0, 0.0)).rays(ds)
    slow, w1 = Boost.from_velocity(1e-12 * AXIS).rays(ds)
    assert np.all(w0 == 1.0)
    assert np.max(np.abs(slow - still)) < 3e-12
    assert np.max(np.abs(w1 - 1.0)) < 2e-12


def test_light_ray_maps_to_light_ray():
    """A backward light ray (s, -s... ) stays null: s' = w s and |d'| = 1."""
    boost = Boost.from_velocity(0.9 * AXIS)
    ds = np.array(directions_for(AXIS))
    d_new, w = boost.rays(ds)
    assert np.allclose(np.linalg.norm(d_new, axis=1), 1.0, atol=1e-15)
    tau, x = boost.events(-np.ones(len(ds)), ds)  # the ray's step per unit s: (-1, d)
    assert np.allclose(-tau, w, rtol=1e-14)
    assert np.allclose(x / w[:, None], d_new, atol=1e-14)


@pytest.mark.parametrize("bad", [(1.0, 0.0, 0.0), (0.6, 0.8, 0.0), (0.0, 0.0, -1.5), (math.nan, 0, 0), (math.inf, 0, 0)])
def test_invalid_speeds_raise_naming_the_object(bad):
    with pytest.raises(ValueError, match="Rocket"):
        Boost.from_velocity(bad, name="Rocket")


@pytest.mark.parametrize("factor", [0.5, -2.0, math.nan, math.inf])
def test_invalid_lorentz_factors_raise(factor):
    with pytest.raises(ValueError, match="Rocket"):
        Boost.from_velocity((1.0, 0.0, 0.0), lorentz_factor=factor, name="Rocket")


def test_lorentz_factor_sets_speed_and_velocity_the_direction():
    boost = Boost.from_velocity((0.0, 2.0, 0.0), lorentz_factor=1e6)
    assert boost.gamma == 1e6
    assert np.array_equal(boost.n, [0.0, 1.0, 0.0])
    assert rel(boost.one_minus_b, 1 - mp.sqrt(1 - mp.mpf(10) ** -12)) < 1e-15


def mp_compose(u, v):
    """Velocity of a body moving with v in S, measured in the frame moving with u."""
    u, v = mp_vec(u), mp_vec(v)
    u2 = sum(c * c for c in u)
    gu = 1 / mp.sqrt(1 - u2)
    uv = sum(a * c for a, c in zip(u, v))
    return [(vc / gu - uc + gu / (gu + 1) * uv * uc) / (1 - uv) for uc, vc in zip(u, v)]


@pytest.mark.parametrize("u,v", [
    ((0.9, 0.0, 0.0), (0.0, 0.9, 0.0)),
    ((0.5, 0.3, -0.1), (-0.2, 0.7, 0.4)),
    ((1e-12, 0.0, 0.0), (0.0, 0.0, 1e-12)),
    ((0.0, 0.0, 1 - 1e-9), (0.0, 0.0, -(1 - 1e-9))),
    ((0.6, 0.0, 0.0), (0.6, 0.0, 0.0)),
    ((1 - 1e-12, 0.0, 0.0), (1 - 1e-9, 0.0, 0.0)),
    ((0.0, 0.0, 1 - 1e-12), (0.0, 0.0, 1 - 1e-12)),
    ((0.0, 1 - 1e-12, 0.0), (1 - 1e-9, 0.0, 0.0)),
])
def test_velocity_composition(u, v):
    got, gamma = compose_velocities(u, v)
    ref = mp_compose(u, v)
    scale = max(mp.norm(ref), mp.mpf(1e-15))  # equal velocities: at rest to float rounding
    assert max(abs(mp.mpf(float(a)) - c) for a, c in zip(got, ref)) < 1e-13 * scale
    # gamma carries the speed even where the velocity rounds to |v| = 1 in float64
    assert rel(gamma, 1 / mp.sqrt(1 - sum(c * c for c in ref))) < 1e-14


@pytest.mark.parametrize("b", [1e-12, 0.5, 0.9, 1 - 1e-6, 1 - 1e-9, 1 - 1e-12])
@pytest.mark.parametrize("direction", [(1.0, 0.0, 0.0), (0.36, -0.48, 0.8), (0.6, 0.8, 0.0)])
def test_a_body_moving_with_the_frame_is_exactly_at_rest_in_it(b, direction):
    """u = v: the composed velocity is 0 and gamma 1, not the rounding of v_par - b or v_perp
    divided by 1 - u.v = 1/gamma^2 (which left 5.6e-8 c at 1 - 1e-9 along (0.36, -0.48, 0.8))."""
    u = tuple(b * np.asarray(direction))
    velocity, gamma = compose_velocities(u, u)
    assert np.array_equal(velocity, np.zeros(3))
    assert gamma == pytest.approx(1.0, abs=1e-15)


def textbook_boost(beta):
    """The Lorentz boost matrix into a frame moving with beta, written out (acting on (tau, x, y, z))."""
    beta = np.asarray(beta, dtype=np.float64)
    gamma = 1.0 / math.sqrt(1.0 - beta @ beta)
    m = np.eye(4)
    m[0, 0] = gamma
    m[0, 1:] = m[1:, 0] = -gamma * beta
    m[1:, 1:] += (gamma - 1.0) * np.outer(beta, beta) / (beta @ beta)
    return m


def test_frame_chain_is_two_boosts_not_one_composed_boost():
    """Mapping between two moving frames goes through S: it equals the product of the two
    textbook boost matrices (which includes the Wigner rotation), not one boost of the composed velocity."""
    a = Boost.from_velocity((0.9, 0.0, 0.0))
    b = Boost.from_velocity((0.0, 0.9, 0.0))
    chain = FrameMap([a.inverse(), b])
    rng = np.random.default_rng(3)
    tau, x = rng.normal(size=5), rng.normal(size=(5, 3))
    got_tau, got_x = chain.events(tau, x)
    m = textbook_boost((0.0, 0.9, 0.0)) @ textbook_boost((-0.9, 0.0, 0.0))  # into S, then into b's frame
    expect = (m @ np.column_stack([tau, x]).T).T
    assert np.allclose(got_tau, expect[:, 0], rtol=1e-13, atol=1e-13)
    assert np.allclose(got_x, expect[:, 1:], rtol=1e-13, atol=1e-13)
    single = Boost.from_velocity(-compose_velocities((-0.9, 0.0, 0.0), (0.0, 0.9, 0.0))[0])
    # the composed-velocity boost differs from the chain by a spatial rotation
    assert not np.allclose(single.matrix(), m, atol=1e-3)


def test_a_velocity_is_worked_out_once_and_its_boost_shared_read_only():
    """from_velocity keeps each velocity's boost: the same object again, its axis read-only, and
    the same bits as working it out afresh; -0.0 is a velocity of its own (the axis keeps the
    sign of its zero), and a bad velocity raises naming the object every time."""
    beta = (0.3, -0.0, 0.4)
    boost = Boost.from_velocity(beta, name="first")
    assert Boost.from_velocity(np.array(beta), name="second") is boost
    assert not boost.n.flags.writeable
    fresh = Boost._worked_out(beta, 0.0, "fresh")
    assert (boost.n.tobytes(), boost.b, boost.gamma, boost.gamma_minus_one, boost.one_minus_b) == (
        fresh.n.tobytes(), fresh.b, fresh.gamma, fresh.gamma_minus_one, fresh.one_minus_b)
    positive = Boost.from_velocity((0.3, 0.0, 0.4))
    assert positive is not boost and np.signbit(boost.n[1]) and not np.signbit(positive.n[1])
    assert Boost.from_velocity((0.6, 0.0, 0.0), 2.0) is Boost.from_velocity((0.6, 0.0, 0.0), 2.0)
    for name in ("lamp", "cube"):
        with pytest.raises(ValueError, match=name):
            Boost.from_velocity((0.8, 0.7, 0.0), name=name)


def test_events_of_many_boosts_at_once_are_each_boosts_own():
    """events_of_boosts (every source frame's body boxes in one pass) gives each boost's own events,
    to rounding, at rest, obliquely and at gamma = 1e6 (each boost's exact numbers, no 1 - b^2)."""
    rng = np.random.default_rng(3)
    tau, x = rng.uniform(-50.0, 50.0, 20), rng.uniform(-50.0, 50.0, (20, 3))
    boosts = [Boost.identity(), Boost.from_velocity((0.5, -0.4, 0.3)), Boost.from_velocity(AXIS, lorentz_factor=1e6),
              Boost.from_velocity((0.0, 0.6, -0.79))]
    t_all, x_all = events_of_boosts(boosts, tau, x)
    for boost, t_one, x_one in zip(boosts, t_all, x_all):
        t_ref, x_ref = boost.events(tau, x)
        scale = boost.gamma * 100.0  # |coordinates| after the boost, at most
        np.testing.assert_allclose(t_one, t_ref, rtol=0, atol=1e-15 * scale)
        np.testing.assert_allclose(x_one, x_ref, rtol=0, atol=1e-15 * scale)

"""Lorentz boosts of events and light rays, accurate from beta = 0 to gamma = 1e8.

Units: c = 1, time carried as tau = c t.  A :class:`Boost` maps coordinates of
an inertial frame A to those of a frame B that moves with velocity ``beta``
relative to A (axes parallel, common origin event)::

    x'   = x + ((gamma - 1) n.x - gamma b tau) n
    tau' = gamma (tau - b n.x)

with ``beta = b n``.  Writing ``gamma - 1`` instead of the paper's
``(gamma - 1)/|v|^2 * |v|^2`` removes its 0/0 at rest and its cancellation.

Backward light rays -- events ``(tau0 - s, x0 + s d)`` -- are mapped by
:meth:`Boost.rays`: the direction becomes ``d'`` and the path length ``s' = w s``
with ``w = gamma (1 + beta.d) = 1/D``, D the Doppler factor (observed over
emitted frequency) of light that reaches A's observer from direction d.
Near c the literal formula cancels twice (in ``1 + beta.d`` and in the
aberration), so it is written with ``h = 1 + n.d = |n + d|^2 / 2`` and
``1 - b = 1 / (gamma^2 (1 + b))`` (``docs/physics.md#backward-light-rays``).
"""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np

from . import validation


_BOOSTS: dict[tuple, "Boost"] = {}  # Boost.from_velocity's, by the bits of the velocity
_MAX_BOOSTS = 4096  # velocities kept (an animation's many): start afresh past this


class Boost:
    """The Lorentz boost into a frame moving with velocity ``b * n`` (units of c).

    Build with :meth:`from_velocity`; the identity boost has ``b == 0``.
    """

    __slots__ = ("n", "b", "gamma", "gamma_minus_one", "one_minus_b")

    def __init__(self, n, b: float, gamma: float, gamma_minus_one: float, one_minus_b: float):
        self.n = np.array(n, dtype=np.float64)
        self.n.flags.writeable = False  # boosts are shared (from_velocity keeps them)
        self.b = float(b)
        self.gamma = float(gamma)
        self.gamma_minus_one = float(gamma_minus_one)
        self.one_minus_b = float(one_minus_b)

    # ------------------------------------------------------------------ construction
    @classmethod
    def identity(cls) -> "Boost":
        return cls(np.array([1.0, 0.0, 0.0]), 0.0, 1.0, 0.0, 1.0)

    @classmethod
    def from_velocity(cls, beta, lorentz_factor: float = 0.0, name: str = "velocity") -> "Boost":
        """Boost for a velocity given as ``beta`` (units of c), or as a direction plus gamma.

        Raises ValueError naming ``name`` for speeds >= c, NaN or infinite input.  Worked out in
        exact arithmetic once per velocity (by the inputs' bits: -0.0 is not 0.0) and kept: each
        render builds the frames of its scene's velocities again.
        """
        key = (*(float(c).hex() for c in beta), float(lorentz_factor).hex())
        boost = _BOOSTS.get(key)
        if boost is None:
            boost = cls._worked_out(beta, lorentz_factor, name)
            if len(_BOOSTS) >= _MAX_BOOSTS:
                _BOOSTS.clear()
            _BOOSTS[key] = boost
        return boost

    @classmethod
    def _worked_out(cls, beta, lorentz_factor: float, name: str) -> "Boost":
        """:meth:`from_velocity`, from scratch."""
        beta, lorentz_factor = validation.check_velocity(beta, lorentz_factor, name)
        if lorentz_factor != 0.0:
            if lorentz_factor == 1.0:
                return cls.identity()
            return cls.from_gamma(np.array(beta) / math.sqrt(math.fsum(c * c for c in beta)), lorentz_factor)
        one_minus_b2 = validation.one_minus_speed_squared(beta)
        b2 = float(sum(Fraction(c) ** 2 for c in beta))
        if b2 == 0.0:
            return cls.identity()
        b = math.sqrt(b2)
        n = np.array(beta) / b
        gamma = 1.0 / math.sqrt(one_minus_b2)
        return cls(n, b, gamma, gamma * gamma * b2 / (gamma + 1.0), one_minus_b2 / (1.0 + b))

    @classmethod
    def from_gamma(cls, n, gamma: float) -> "Boost":
        """Boost along unit vector ``n`` with Lorentz factor ``gamma`` (no loss near c)."""
        n = np.asarray(n, dtype=np.float64)
        n = n / np.linalg.norm(n)
        gamma_minus_one = gamma - 1.0
        b = math.sqrt(gamma_minus_one * (gamma + 1.0)) / gamma
        return cls(n, b, gamma, gamma_minus_one, 1.0 / (gamma * gamma * (1.0 + b)))

    # ------------------------------------------------------------------ properties
    @property
    def beta(self) -> np.ndarray:
        return self.b * self.n

    @property
    def is_identity(self) -> bool:
        return self.b == 0.0

    @property
    def rapidity(self) -> float:
        return math.log1p(self.b) / 2.0 - math.log(self.one_minus_b) / 2.0

    def inverse(self) -> "Boost":
        return Boost(-self.n, self.b, self.gamma, self.gamma_minus_one, self.one_minus_b)

    def same_as(self, other: "Boost") -> bool:
        """True when both boosts are the same velocity (so their frames are at rest relative to each other)."""
        if self.is_identity or other.is_identity:
            return self.is_identity and other.is_identity
        return self.gamma == other.gamma and bool(np.all(self.n == other.n))

    def contracted(self, offset):
        """Offsets (..., 3) of points at rest in this frame, as S measures them at one world time:
        shortened along n by 1/gamma (Lorentz contraction, docs/physics.md#rest-shapes)."""
        offset = np.asarray(offset, dtype=np.float64)
        if self.is_identity:
            return offset
        return offset - (self.gamma_minus_one / self.gamma) * (offset @ self.n)[..., None] * self.n

    def matrix(self) -> np.ndarray:
        """The 4x4 matrix acting on (tau, x, y, z)."""
        n, g = self.n, self.gamma
        m = np.empty((4, 4))
        m[0, 0] = g
        m[0, 1:] = -g * self.b * n
        m[1:, 0] = -g * self.b * n
        m[1:, 1:] = np.eye(3) + self.gamma_minus_one * np.outer(n, n)
        return m

    # ------------------------------------------------------------------ maps
    def events(self, tau, x):
        """Boost events ``(tau, x)``: tau (...,), x (..., 3) -> (tau', x')."""
        tau = np.asarray(tau, dtype=np.float64)
        x = np.asarray(x, dtype=np.float64)
        if self.is_identity:
            return tau, x
        nx = x @ self.n
        tau_new, shift = _boosted_time_and_shift(tau, nx, self.b, self.gamma, self.gamma_minus_one)
        x_new = np.empty(np.broadcast_shapes(x.shape, shift.shape + (3,)))
        for axis in range(3):  # one axis at a time: numpy is slow along a length-3 last axis
            x_new[..., axis] = x[..., axis] + shift * self.n[axis]
        return tau_new, x_new

    def rays(self, d):
        """Map backward light-ray directions: unit d (..., 3) -> (d', w) with s' = w s, w = 1/D.

        Accurate near c and at grazing or head-on angles (see module docstring).  Written one
        axis at a time, as :meth:`events`, without masked steps (a mask that changes from ray
        to ray costs branch misses: 10x an unmasked step), into scratch rows reused from step to step.
        """
        d = np.asarray(d, dtype=np.float64)
        if self.is_identity:
            return d, np.ones(d.shape[:-1])
        n, b = self.n, self.b
        shape = d.shape[:-1]
        moving = [i for i in range(3) if n[i] != 0.0]  # axes along which n has a component
        toward = (d @ n) < 0.0  # d close to -n: h is small, use d + n (exact there)
        # half the sign (+1 toward -n, else -1): times 2 n it is +-n, and times |diff|^2 it is
        # sign |diff|^2 / 2, each rounded as sign times the halved square was (scaling by +-1/2 or
        # by 2 rounds once either way): two float passes fewer, one over the bools more
        half_sign = np.subtract(toward, 0.5, out=np.empty(shape))
        # d + n or d - n: the small difference vector
        diff = [d[..., i] for i in range(3)]
        for i in moving:
            diff[i] = np.multiply(half_sign, 2.0 * n[i], out=np.empty(shape))
            diff[i] += d[..., i]
        scratch, spare = np.empty(shape), np.empty(shape)
        s2 = np.multiply(diff[0], diff[0], out=np.empty(shape))
        for i in (1, 2):
            s2 += np.multiply(diff[i], diff[i], out=scratch)
        # h = 1 + n.d: |diff|^2 / 2 toward -n, else 2 - |diff|^2 / 2 (as (1 - sign) + sign |diff|^2 / 2)
        along = np.multiply(half_sign, s2, out=s2)  # the part of the difference along n
        h = np.multiply(np.logical_not(toward), 2.0, out=half_sign)  # 1 - sign
        h += along
        # d_perp = d - (n.d) n, from the difference vector for accuracy
        perp = diff
        for i in moving:
            perp[i] -= np.multiply(along, n[i], out=scratch)
        # inputs a few ulps off unit length leave a residue along n; remove it exactly
        # (summed from 0 as ``sum`` does: a -0 product becomes +0)
        residue = np.zeros(shape)
        for i in moving:
            residue += np.multiply(perp[i], n[i], out=scratch)
        one_plus_bd = np.multiply(b, h, out=along)
        one_plus_bd += self.one_minus_b
        par = np.subtract(h, self.one_minus_b, out=h)
        par /= one_plus_bd
        inverse = np.multiply(self.gamma, one_plus_bd, out=np.empty(shape))
        np.divide(1.0, inverse, out=inverse)
        d_new = np.empty(d.shape)
        for i in range(3):  # each axis worked out in contiguous rows, then written into its column once
            if i in moving:
                np.multiply(residue, n[i], out=scratch)
                np.subtract(perp[i], scratch, out=scratch)
                scratch *= inverse
                np.add(np.multiply(par, n[i], out=spare), scratch, out=d_new[..., i])
            else:
                np.multiply(perp[i], inverse, out=d_new[..., i])
        one_plus_bd *= self.gamma
        return d_new, one_plus_bd

    def doppler(self, d):
        """Doppler factor D = 1/(gamma (1 + beta.d)) for backward directions d."""
        return 1.0 / self.rays(d)[1]


def events_of_boosts(boosts, tau, x):
    """:meth:`Boost.events` of each of ``boosts`` at once: events tau (e,), x (e, 3) -> (tau', x'),
    (len(boosts), e) and (len(boosts), e, 3) -- the same formula with each boost's own numbers
    (exact near c), n.x of every pair in one product (its rounding may differ by an ulp)."""
    n = np.array([boost.n for boost in boosts])
    b, gamma, gamma_minus_one = (np.array([[getattr(boost, name)] for boost in boosts])
                                 for name in ("b", "gamma", "gamma_minus_one"))
    nx = n @ np.asarray(x, dtype=np.float64).T  # (boosts, e)
    tau_new, shift = _boosted_time_and_shift(np.asarray(tau, dtype=np.float64), nx, b, gamma, gamma_minus_one)
    return tau_new, x + shift[:, :, None] * n[:, None, :]


def _boosted_time_and_shift(tau, nx, b, gamma, gamma_minus_one):
    """A boost's events once n.x is known (numbers or arrays): the boosted times, and how far
    each event moves along n (x' = x + shift n)."""
    return gamma * (tau - b * nx), gamma_minus_one * nx - gamma * b * tau


def compose_velocities(u, v):
    """Velocity of a body moving with ``v`` (in S) as measured in the frame moving with ``u``.

    Both in units of c.  Returns ``(beta, gamma)``: the body's 4-velocity boosted
    into the frame, so the result is the exact relativistic composition
    (direction included); gamma keeps the speed where beta rounds to 1.
    """
    boost = Boost.from_velocity(u, name="frame velocity")
    body = Boost.from_velocity(v, name="body velocity")
    # gamma' = gamma_u gamma_v (1 - u.v), with 1 - u.v exact from the float inputs (as 1 - b^2 in
    # from_velocity): near c it is the small difference that carries the whole result
    exact_u, exact_v = [Fraction(float(a)) for a in u], [Fraction(float(c)) for c in v]
    u_dot_v = sum(a * c for a, c in zip(exact_u, exact_v))
    one_minus_uv = float(1 - u_dot_v)
    gamma = boost.gamma * body.gamma * one_minus_uv
    if boost.is_identity:
        return body.b * body.n, body.gamma
    # v' = ((v_par - b) n + v_perp / gamma_u) / (1 - u.v): the textbook numerator
    # v/gamma_u - u + gamma_u/(gamma_u + 1) (u.v) u with its parallel part simplified exactly;
    # v_par - b = u.(v - u) / |u| and v_perp = v - (u.v / u.u) u exact from the float inputs, as
    # 1 - u.v: near c both are small differences divided by the small 1 - u.v (a body moving
    # with the frame is exactly at rest in it)
    u_dot_u = sum(a * a for a in exact_u)
    v_par_minus_b = float(u_dot_v - u_dot_u) / boost.b
    v_perp = np.array([float(c - u_dot_v / u_dot_u * a) for a, c in zip(exact_u, exact_v)])
    velocity = (v_par_minus_b * boost.n + v_perp / boost.gamma) / one_minus_uv
    norm = float(np.linalg.norm(velocity))
    if norm > 0.5:  # near c the speed is better known from gamma, which has no cancellation
        velocity *= (math.sqrt((gamma - 1.0) * (gamma + 1.0)) / gamma) / norm
    return velocity, gamma


class RowBoosts:
    """One boost per row: row i maps coordinates of A to those of the frame moving with
    ``beta[i]`` relative to A (the momentary rest frames of an accelerating camera's samples
    or of a lamp at each of its retarded events).

    The formulas of :class:`Boost` with ``k = gamma^2 / (gamma + 1)`` (no 0/0 at rest); the
    velocities come from world lines (animated cameras and lamps, well below ``1 - 1e-9``), so
    the literal ``1 + beta.d`` is accurate enough here.
    """

    def __init__(self, beta):
        self.beta = np.atleast_2d(np.asarray(beta, dtype=np.float64))
        b2 = np.einsum("ij,ij->i", self.beta, self.beta)
        if not np.all(b2 < 1.0):
            raise ValueError("a velocity of a world line reaches the speed of light")
        self.gamma = 1.0 / np.sqrt(1.0 - b2)
        self.k = self.gamma**2 / (self.gamma + 1.0)

    def inverse(self) -> "RowBoosts":
        return RowBoosts(-self.beta)

    def events(self, tau, x):
        """Boost events (n,), (n, 3) -> (tau', x')."""
        tau = np.asarray(tau, dtype=np.float64)
        bx = np.einsum("ij,ij->i", self.beta, x)
        return self.gamma * (tau - bx), x + (self.k * bx - self.gamma * tau)[:, None] * self.beta

    def rays(self, d):
        """Backward directions d (n, 3) -> (d', w), s' = w s, w = gamma (1 + beta.d) = 1/D."""
        bd = np.einsum("ij,ij->i", self.beta, d)
        w = self.gamma * (1.0 + bd)
        return (d + (self.k * bd + self.gamma)[:, None] * self.beta) / w[:, None], w

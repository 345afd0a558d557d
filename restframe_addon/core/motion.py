"""Motion beyond constant velocity: world lines from animation, and rotation.

An animated body's pivot follows the world line ``X(tau)`` in S, given as samples
of its animation.  Between samples the pivot moves inertially; at every sample
where the velocity changes, the corner is rounded into constant acceleration
over a proper time of at least ``r_max |delta(gamma beta)|`` (>= ``r_max |delta
beta|``, docs/physics.md#accelerated-bodies: a sudden turn is smoothed so the Born-rigid body never
tears).  Where neighbouring samples leave no room for that, the turn is as
smooth as the samples allow and a warning names the frame.

For tracing, the world line is cut into *inertial segments*: on each, the body
is replaced by the same body moving with the segment's mid velocity, i.e. a
static body in that segment's rest frame (Born rigidity: its points lie on the
pivot's momentary simultaneity slice).  Segments are halved until the body
points, pivot included, stay within the user's ``tolerance`` of the true
Born-rigid motion.  A segment only holds between the body's simultaneity slices
at its ends, shared with its neighbours (``frames.Window``), which the tracer
applies as a clip range on each ray.

Rotation at constant angular velocity is exactly rigid in the inertial frame of
the axis (docs/physics.md#rotation).  Each ray meets the body in the pose of its own hit time:
the tracer poses the body at a guessed time, intersects, re-poses it at the hit
time and repeats; the guess moves the hit by at most ``omega r`` times the time
change, so the iteration contracts (rim speed < c) and stops once a hit moves by
less than the tolerance.  Approximations, stated: a rotating surface is lit and
shaded in the axis frame (the aberration and Doppler shift of the light it
*receives*, due to its local speed ``omega x r``, are left out); the light it
*sends* carries the Doppler factor of its local speed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .lorentz import RowBoosts
from .validation import check_finite_motion, too_many_segments

_MAX_DEPTH = 40
# Inertial segments of a world line: at most SEGMENTS_PER_SAMPLE per animation sample, and never a
# limit below MIN_SEGMENT_LIMIT (a gentle motion needs about one per sample at tolerance 1e-3, a
# random 41-sample motion of a large body 46, and tolerance 1e-9 millions).
SEGMENTS_PER_SAMPLE = 64
MIN_SEGMENT_LIMIT = 20000


@dataclass
class Trajectory:
    """A pivot's world line from animation samples: ``tau`` (increasing, c*t) and ``position`` (N, 3) in S.

    ``frames`` are the Blender frame numbers of the samples (for messages);
    ``body_radius`` the largest distance of a body point from the pivot.  ``smooth`` (a point:
    an observer or a lamp) rounds every corner as widely as the samples allow, so the world
    line is a chain of constant accelerations whose velocity at a sample is the mean of its
    neighbouring chords' (second-order accurate for a smooth keyed path).
    Raises ValueError naming ``name`` and the frames where the speed reaches c.
    """

    tau: np.ndarray
    position: np.ndarray
    name: str = "object"
    frames: np.ndarray | None = None
    body_radius: float = 0.0
    warnings: list = field(default_factory=list)
    smooth: bool = False

    def __post_init__(self):
        self.tau = np.asarray(self.tau, dtype=np.float64)
        self.position = np.asarray(self.position, dtype=np.float64).reshape(-1, 3)
        if len(self.tau) < 2 or len(self.tau) != len(self.position):
            raise ValueError(f"{self.name}: an animated motion needs at least two samples")
        check_finite_motion(self.tau, self.name)
        check_finite_motion(self.position, self.name)
        if np.any(np.diff(self.tau) <= 0):
            raise ValueError(f"{self.name}: animation samples must be in increasing time")
        frames = self.frames if self.frames is not None else np.arange(len(self.tau))
        self.beta = np.diff(self.position, axis=0) / np.diff(self.tau)[:, None]  # per interval
        speed = np.linalg.norm(self.beta, axis=1)
        fast = np.flatnonzero(~(speed < 1.0))
        if len(fast):
            spans = ", ".join(f"{frames[i]:g}-{frames[i + 1]:g}" for i in fast[:5])
            more = f" and {len(fast) - 5} more" if len(fast) > 5 else ""
            raise ValueError(
                f"{self.name}: the animation moves at {speed[fast].max():.6g} c, not below the speed of light, "
                f"between frames {spans}{more}: slow it down or raise the scene's speed of light")
        self._round_corners(frames)
        self._proper = self._proper_time_at_knots()

    # ------------------------------------------------------------------ corners
    def _round_corners(self, frames):
        """Half-widths (world time) of the rounded corners at the interior samples.

        A turn changing the 4-velocity's spatial part u = gamma beta by du, spread over a
        proper time of at least R |du|, keeps the proper acceleration a <= 1/R, so every
        point of a body of radius R keeps 1 + a.r' > 0 (no Born-rigid tearing); this is at
        least R |d beta| (docs/physics.md#accelerated-bodies).  World time runs gamma times faster.
        """
        lengths = np.diff(self.tau)
        u = self.beta / np.sqrt(1.0 - np.einsum("ij,ij->i", self.beta, self.beta))[:, None]
        gamma = np.sqrt(1.0 + np.einsum("ij,ij->i", u, u))
        jump = np.linalg.norm(np.diff(u, axis=0), axis=1)
        wanted = 0.5 * np.maximum(gamma[:-1], gamma[1:]) * self.body_radius * jump
        room = 0.5 * np.minimum(lengths[:-1], lengths[1:])
        if self.smooth:
            self.half = np.where(jump > 0.0, room, 0.0)
            return
        self.half = np.minimum(wanted, room)
        short = np.flatnonzero(wanted > room * (1 + 1e-9))
        if len(short):
            i = short[np.argmax((wanted - room)[short])]
            self.warnings.append(
                f"{self.name}: the turn at frame {frames[i + 1]:g} is too sharp for a rigid body of radius "
                f"{self.body_radius:.3g}: it is smoothed over {2 * room[i]:.3g} units of c*t instead of "
                f"{2 * wanted[i]:.3g}, so points far from the pivot may be placed inconsistently")

    def carried(self, offset, name: str) -> "Trajectory":
        """The world line of a point at ``offset`` from this pivot in the pivot's momentary rest
        frames (a point of the Born-rigid body, docs/physics.md#accelerated-bodies): each sample's
        event moved by the offset laid off on the pivot's simultaneity slice there; a point's
        (``smooth``).  Raises ValueError naming ``name`` where the offset lies beyond the horizon of
        the acceleration (its events would not follow one another)."""
        position, beta = self.state(self.tau)
        count = len(self.tau)
        d_tau, d_x = RowBoosts(beta).inverse().events(np.zeros(count), np.broadcast_to(offset, (count, 3)))
        return Trajectory(tau=self.tau + d_tau, position=position + d_x, name=name, frames=self.frames,
                          smooth=True)

    def _locate(self, tau):
        """Interval index (clamped to the end pieces) of each time."""
        return np.clip(np.searchsorted(self.tau, tau, side="right") - 1, 0, len(self.tau) - 2)

    def state(self, tau):
        """Position (n, 3) and velocity (n, 3) of the pivot at world times tau (n,)."""
        tau = np.atleast_1d(np.asarray(tau, dtype=np.float64))
        i = self._locate(tau)
        beta = self.beta[i].copy()
        pos = self.position[i] + beta * (tau - self.tau[i])[:, None]
        # inside a rounded corner around interior knot j: constant acceleration from beta_{j-1} to beta_j
        for side in (0, 1):  # the corner at the interval's start (j = i) or end (j = i + 1)
            j = i + side
            interior = (j >= 1) & (j <= len(self.tau) - 2)
            jj = np.clip(j, 1, len(self.tau) - 2)
            h = np.where(interior, self.half[jj - 1], 0.0)
            inside = interior & (np.abs(tau - self.tau[jj]) < h)
            if not np.any(inside):
                continue
            k = np.flatnonzero(inside)
            jk = jj[k]
            b_in, b_out, hk = self.beta[jk - 1], self.beta[jk], h[k]
            u = (tau[k] - self.tau[jk] + hk)[:, None]
            pos[k] = self.position[jk] - b_in * hk[:, None] + b_in * u + (b_out - b_in) / (4 * hk[:, None]) * u**2
            beta[k] = b_in + (b_out - b_in) * u / (2 * hk[:, None])
        return pos, beta

    def _proper_time_at_knots(self):
        """Pivot proper time (c*tau units) at each sample, zero at world time tau = 0."""
        out = np.concatenate([[0.0], np.cumsum(self._proper_between(self.tau[:-1], self.tau[1:]))])
        return out - self._proper_from(out, np.array([0.0]))[0]

    def _proper_between(self, a, b):
        """Proper time elapsed between world times a and b (arrays), 8-point Gauss-Legendre."""
        nodes, weights = np.polynomial.legendre.leggauss(8)
        a, b = np.atleast_1d(a), np.atleast_1d(b)
        tau = (0.5 * (b - a))[:, None] * nodes + (0.5 * (a + b))[:, None]
        _, beta = self.state(tau.ravel())
        rate = np.sqrt(np.maximum(1.0 - np.einsum("ij,ij->i", beta, beta), 0.0)).reshape(tau.shape)
        return 0.5 * (b - a) * (rate @ weights)

    def _proper_from(self, knots, tau):
        tau = np.atleast_1d(np.asarray(tau, dtype=np.float64))
        i = self._locate(tau)
        return knots[i] + self._proper_between(self.tau[i], tau)

    def proper_time(self, tau):
        """The pivot's own clock (c*tau units) at world times tau: 0 at tau = 0."""
        return self._proper_from(self._proper, tau)

    def world_time(self, proper):
        """World times (c*tau units) at which the pivot's clock reads ``proper``: the inverse of
        :meth:`proper_time` (it rises strictly), by Newton steps from the interpolated knots."""
        proper = np.atleast_1d(np.asarray(proper, dtype=np.float64))
        i = np.clip(np.searchsorted(self._proper, proper, side="right") - 1, 0, len(self.tau) - 2)
        rate = np.sqrt(1.0 - np.einsum("ij,ij->i", self.beta, self.beta))  # d(proper)/d(tau) between corners
        tau = self.tau[i] + (proper - self._proper[i]) / rate[i]
        for _ in range(4):
            _, beta = self.state(tau)
            tau = tau - (self.proper_time(tau) - proper) / np.sqrt(1.0 - np.einsum("ij,ij->i", beta, beta))
        return tau

    # ------------------------------------------------------------------ light cone
    def light_cone_crossing(self, event_tau, event_x, iterations: int = 200):
        """World time of the pivot event on the past light cone of each event (n,), (n, 3).

        ``f(tau) = tau + |x - X(tau)| - tau_e`` rises strictly (slope >= 1 - |beta| > 0),
        so bisection on a bracket [tau_e - L, tau_e] with f < 0 at the left end converges
        and cannot diverge.
        """
        event_tau = np.atleast_1d(np.asarray(event_tau, dtype=np.float64))
        event_x = np.atleast_2d(np.asarray(event_x, dtype=np.float64))
        speed_max = float(np.max(np.linalg.norm(self.beta, axis=1)))
        here, _ = self.state(event_tau)
        reach = np.linalg.norm(event_x - here, axis=1) / (1.0 - speed_max) + 1.0
        lo, hi = event_tau - reach, event_tau.copy()
        for _ in range(iterations):
            mid = 0.5 * (lo + hi)
            pos, _ = self.state(mid)
            f = mid + np.linalg.norm(event_x - pos, axis=1) - event_tau
            lo, hi = np.where(f < 0, mid, lo), np.where(f < 0, hi, mid)
            if np.all(hi - lo <= 1e-15 * np.maximum(np.abs(hi), 1.0)):
                break
        return 0.5 * (lo + hi)


@dataclass
class Segment:
    """One inertial piece of a world line: valid for world times [start, end] of the pivot."""

    start: float
    end: float
    mid: float
    position: np.ndarray  # pivot at mid
    beta: np.ndarray  # velocity at mid
    error: float


def segment_error(trajectory: Trajectory, start: float, end: float, radius: float):
    """(mid position, mid velocity, bound) of replacing the world line on [start, end] by the
    inertial motion through its mid event.

    On the slice through the mid event every Born-rigid body point has the pivot's velocity,
    so body world lines leave their inertial replacements only at second order, like the
    pivot's, amplified by 1 / (1 - R a) where a is the proper acceleration (the front and back
    of an accelerating rigid body accelerate differently).  The pivot's deviation is measured
    at every sample and corner edge in the segment, where the piecewise motion bends.
    """
    mid = 0.5 * (start + end)
    knots = np.flatnonzero((trajectory.tau > start) & (trajectory.tau < end))
    corner = knots[(knots >= 1) & (knots <= len(trajectory.tau) - 2)]
    half = trajectory.half[corner - 1]
    probe = np.concatenate([np.linspace(start, end, 5), trajectory.tau[knots],
                            trajectory.tau[corner] - half, trajectory.tau[corner] + half])
    probe = np.sort(np.clip(probe, start, end))
    (x_mid,), (b_mid,) = trajectory.state(np.array([mid]))
    pos, beta = trajectory.state(probe)
    pivot = float(np.max(np.linalg.norm(pos - x_mid - b_mid * (probe - mid)[:, None], axis=1)))
    if pivot == 0.0:
        return x_mid, b_mid, 0.0
    gamma = 1.0 / np.sqrt(np.maximum(1.0 - np.einsum("ij,ij->i", beta, beta), 1e-300))
    u = gamma[:, None] * beta
    dt_proper = np.diff(probe) / np.maximum(gamma[1:], gamma[:-1])
    accel = np.linalg.norm(np.diff(u, axis=0), axis=1) / np.maximum(dt_proper, 1e-300)
    stiffness = radius * float(np.max(accel[dt_proper > 0], initial=0.0))
    return x_mid, b_mid, pivot / max(1.0 - stiffness, 1e-3)


def segment_world_line(trajectory: Trajectory, start: float, end: float, tolerance: float,
                       name: str = "an animated body") -> list[Segment]:
    """Inertial segments covering [start, end], each within ``tolerance`` of the true motion.
    Raises ValueError naming ``name`` once that needs more than SEGMENTS_PER_SAMPLE per sample of
    the world line (a tolerance far below what the samples carry, such as the property's floor of
    1e-9, would split a gentle motion into millions of segments, for hours)."""
    out: list[Segment] = []
    limit = max(SEGMENTS_PER_SAMPLE * len(trajectory.tau), MIN_SEGMENT_LIMIT)

    def split(a, b, depth):
        x_mid, b_mid, error = segment_error(trajectory, a, b, trajectory.body_radius)
        if error <= tolerance or depth >= _MAX_DEPTH:
            if len(out) == limit:
                raise ValueError(too_many_segments(name, tolerance, limit))
            out.append(Segment(a, b, 0.5 * (a + b), x_mid, b_mid, error))
            return
        m = 0.5 * (a + b)
        split(a, m, depth + 1)
        split(m, b, depth + 1)

    split(float(start), float(end), 0)
    return out


def rotation_matrix(axis_angle):
    """Rotation matrices (n, 3, 3) for rotation vectors (n, 3) (Rodrigues)."""
    v = np.atleast_2d(np.asarray(axis_angle, dtype=np.float64))
    angle = np.linalg.norm(v, axis=1)
    safe = np.where(angle > 0, angle, 1.0)
    k = v / safe[:, None]
    kx = np.zeros((len(v), 3, 3))
    kx[:, 0, 1], kx[:, 0, 2] = -k[:, 2], k[:, 1]
    kx[:, 1, 0], kx[:, 1, 2] = k[:, 2], -k[:, 0]
    kx[:, 2, 0], kx[:, 2, 1] = -k[:, 1], k[:, 0]
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    return np.eye(3) + s * kx + (1 - c) * (kx @ kx)



"""The true speed of a keyed location: F-curve derivatives per segment, not sample differences.

A world line sampled a few times per frame averages the speed over each sample interval, so
a spike shorter than one sample, or a CONSTANT-interpolation jump (a teleport), passes as
slow.  Here each F-curve's derivative is worked out per key segment: Bezier segments from
their control points (each handle clamped to its segment's time span, as Blender does; where
time stands still while the value moves, the vertical tangent is infinitely fast), linear ones
from their slope, CONSTANT ones jump at the next key (infinitely fast if the value changes);
easing modes, extrapolation and F-curve modifiers by differences of Blender's own evaluation.
Nothing here imports bpy: an F-curve is read through its ``keyframe_points``, ``modifiers``
and ``evaluate``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Callable

import numpy as np

BEZIER_SAMPLES = 64  # parameter samples per Bezier segment for the speed maximum (then refined)
_BISECTIONS = 60  # frame -> Bezier parameter (time is monotonic in the parameter)


@dataclass
class KeyedCurve:
    """One F-curve's key segments as arrays: segment i runs from key i to key i + 1."""

    key_frame: np.ndarray  # (K,)
    key_value: np.ndarray  # (K,)
    handle_left: np.ndarray  # (K, 2) of each key (frame, value), as stored
    handle_right: np.ndarray  # (K, 2)
    interpolation: np.ndarray  # (K,) per key: how the segment starting there is interpolated
    evaluate: Callable[[float], float]
    exact: bool  # False with F-curve modifiers: Blender's evaluation is differentiated numerically

    @classmethod
    def from_fcurve(cls, fc) -> "KeyedCurve":
        points = list(fc.keyframe_points)
        co = np.array([tuple(p.co) for p in points], dtype=np.float64).reshape(-1, 2)
        left = np.array([tuple(p.handle_left) for p in points], dtype=np.float64).reshape(-1, 2)
        right = np.array([tuple(p.handle_right) for p in points], dtype=np.float64).reshape(-1, 2)
        modes = np.array([p.interpolation for p in points], dtype=object)
        order = np.argsort(co[:, 0], kind="stable")
        return cls(co[order, 0], co[order, 1], left[order], right[order], modes[order],
                   fc.evaluate, exact=not any(not m.mute for m in fc.modifiers))

    @cached_property
    def control(self) -> np.ndarray:
        """(S, 4, 2) Bezier control points of every segment, each handle scaled down (about its key)
        to the segment's time span where it reaches further, as Blender does: time then never runs
        backwards along a segment (it may stand still, where both handles span the whole segment)."""
        keys = np.column_stack([self.key_frame, self.key_value])
        start, end = keys[:-1], keys[1:]
        out, into = self.handle_right[:-1] - start, self.handle_left[1:] - end
        span = (end[:, 0] - start[:, 0])[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            out_scale = np.where(np.abs(out[:, :1]) > span, span / np.abs(out[:, :1]), 1.0)
            into_scale = np.where(np.abs(into[:, :1]) > span, span / np.abs(into[:, :1]), 1.0)
        return np.stack([start, start + out_scale * out, end + into_scale * into, end], axis=1)

    def vertical(self) -> list[float]:
        """Frames where a Bezier segment's time stands still while its value moves (a vertical
        tangent: infinitely fast), e.g. handles as long as the segment, or without time extent."""
        bezier = np.flatnonzero((self.interpolation[:-1] == 'BEZIER') & (np.diff(self.key_frame) > 0.0))
        if len(bezier) == 0:
            return []
        control = self.control[bezier]
        x, y = control[:, :, 0], control[:, :, 1]
        a, b, c = x[:, 1] - x[:, 0], x[:, 2] - x[:, 1], x[:, 3] - x[:, 2]  # dx/dt / 3 = a s^2 + 2 b s t + c t^2
        curvature = a - 2 * b + c
        with np.errstate(divide="ignore", invalid="ignore"):
            inner = np.where(curvature > 0.0, (a - b) / curvature, 0.0)
        out = []
        for t in (np.zeros(len(bezier)), np.ones(len(bezier)), np.clip(inner, 0.0, 1.0)):
            still = _cubic_slope(x, t) <= 1e-6 * (x[:, 3] - x[:, 0])
            moving = np.abs(_cubic_slope(y, t)) > 0.0
            out.extend(float(f) for f in _cubic(x, t)[still & moving])
        return sorted(set(out))

    def jumps(self) -> list[float]:
        """Frames where the curve jumps (a CONSTANT segment into a different value, or two keys on one frame)."""
        step = (self.interpolation[:-1] == 'CONSTANT') | (np.diff(self.key_frame) <= 0.0)
        jump = step & (np.diff(self.key_value) != 0.0)
        return [float(f) for f in self.key_frame[1:][jump]]

    def probe_frames(self) -> np.ndarray:
        """Frames at which the derivative should be looked at: keys, and dense points on Bezier
        segments (uniform in their parameter, so dense where time runs slowly along them) and on
        easing segments."""
        t = np.linspace(0.0, 1.0, BEZIER_SAMPLES + 1)
        modes = self.interpolation[:-1]
        bezier = self.control[modes == 'BEZIER'][:, :, 0]  # (n, 4) time coordinates
        eased = ~np.isin(modes, ('BEZIER', 'LINEAR', 'CONSTANT'))
        a, b = self.key_frame[:-1][eased], self.key_frame[1:][eased]
        return np.concatenate([self.key_frame, _cubic(bezier[:, None, :], t[None, :]).ravel(),
                               (a[:, None] + (b - a)[:, None] * t[None, :]).ravel()])

    def derivative(self, frames: np.ndarray) -> np.ndarray:
        """d value / d frame at each frame (inside CONSTANT segments 0; jumps are in ``jumps``)."""
        frames = np.asarray(frames, dtype=np.float64)
        k = self.key_frame
        segment = np.searchsorted(k, frames, side="right") - 1
        inside = (segment >= 0) & (segment < len(k) - 1) & self.exact  # else extrapolation or modifiers
        seg = np.clip(segment, 0, max(len(k) - 2, 0))
        mode = self.interpolation[:-1][seg] if len(k) > 1 else np.full(len(frames), 'CONSTANT', dtype=object)
        span = np.diff(k)[seg] if len(k) > 1 else np.zeros(len(frames))
        out = np.zeros(len(frames))
        linear = inside & (mode == 'LINEAR') & (span > 0.0)
        out[linear] = np.diff(self.key_value)[seg[linear]] / span[linear]
        bezier = inside & (mode == 'BEZIER') & (span > 0.0)
        if np.any(bezier):
            out[bezier] = _bezier_slope(self.control[seg[bezier]], frames[bezier])
        numeric = ~inside | (inside & ~np.isin(mode, ('BEZIER', 'LINEAR', 'CONSTANT')))
        if np.any(numeric):
            out[numeric] = self._difference(frames[numeric], segment[numeric])
        return out

    def _difference(self, frames: np.ndarray, segment: np.ndarray) -> np.ndarray:
        """Differences of Blender's evaluation over a small step kept inside each frame's segment
        (one-sided at its keys, so a key's kink is not averaged), for easing modes,
        extrapolation and F-curve modifiers."""
        # Blender evaluates at single-precision frames: steps well above their resolution
        h = np.maximum(1e-3, 1e-5 * np.abs(frames))
        k = self.key_frame
        lo = np.where(segment >= 0, k[np.clip(segment, 0, len(k) - 1)], -np.inf)
        hi = np.where(segment < len(k) - 1, k[np.clip(segment + 1, 0, len(k) - 1)], np.inf)
        if not self.exact:  # modifiers change the curve everywhere: no kinks to respect
            lo, hi = np.full(len(frames), -np.inf), np.full(len(frames), np.inf)
        a, b = np.maximum(frames - h, lo), np.minimum(frames + h, hi)
        evaluate = self.evaluate
        ahead = np.fromiter((evaluate(f) for f in b), dtype=np.float64, count=len(frames))
        behind = np.fromiter((evaluate(f) for f in a), dtype=np.float64, count=len(frames))
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(b > a, (ahead - behind) / (b - a), 0.0)


def _cubic(points: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Cubic Bezier with control values ``points[..., 0:4]`` at parameters t (broadcast)."""
    s = 1.0 - t
    return (s**3 * points[..., 0] + 3 * s * s * t * points[..., 1] + 3 * s * t * t * points[..., 2]
            + t**3 * points[..., 3])


def _cubic_slope(points: np.ndarray, t: np.ndarray) -> np.ndarray:
    s = 1.0 - t
    return 3 * (s * s * (points[..., 1] - points[..., 0]) + 2 * s * t * (points[..., 2] - points[..., 1])
                + t * t * (points[..., 3] - points[..., 2]))


def _bezier_slope(control: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """dy/dx of Bezier segments (n, 4, 2) at given x (n,) (time rises monotonically in t)."""
    x, y = control[:, :, 0], control[:, :, 1]
    lo, hi = np.zeros(len(frames)), np.ones(len(frames))
    for _ in range(_BISECTIONS):
        mid = 0.5 * (lo + hi)
        below = _cubic(x, mid) < frames
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    t = 0.5 * (lo + hi)
    dx, dy = _cubic_slope(x, t), _cubic_slope(y, t)
    with np.errstate(divide="ignore", invalid="ignore"):
        slope = dy / dx
    # a handle without time extent: the tangent there is vertical unless the value also rests
    return np.where(dx > 0.0, slope, np.where(dy == 0.0, 0.0, np.inf))


# Blender stores an inf typed into a float property as the largest single-precision number
FLOAT_MAX = float(np.finfo(np.float32).max)


def is_finite(values) -> np.ndarray:
    """Finite and below Blender's stand-in for inf."""
    values = np.asarray(values, dtype=np.float64)
    return np.isfinite(values) & (np.abs(values) < FLOAT_MAX)


def non_finite_key(curve: KeyedCurve) -> float | None:
    """The frame of the first key whose time, value or handles are not finite numbers, or None."""
    values = np.column_stack([curve.key_frame, curve.key_value, curve.handle_left, curve.handle_right])
    bad = np.flatnonzero(~np.all(is_finite(values), axis=1))
    return float(curve.key_frame[bad[0]]) if len(bad) else None


def fastest(velocity: Callable[[np.ndarray], np.ndarray], frames: np.ndarray, refinements: int = 60):
    """(speed, frame) of the largest |velocity| over the sorted probe frames, refined by golden-section
    search between the neighbours of the fastest probe."""
    speed = np.linalg.norm(velocity(frames), axis=1)
    i = int(np.argmax(speed))
    if not np.isfinite(speed[i]):
        return float(speed[i]), float(frames[i])
    lo, hi = frames[max(i - 1, 0)], frames[min(i + 1, len(frames) - 1)]
    ratio = 0.5 * (np.sqrt(5.0) - 1.0)
    best, at = float(speed[i]), float(frames[i])
    a, b = hi - ratio * (hi - lo), lo + ratio * (hi - lo)
    for _ in range(refinements):
        fa, fb = np.linalg.norm(velocity(np.array([a, b])), axis=1)
        if fa > best:
            best, at = float(fa), float(a)
        if fb > best:
            best, at = float(fb), float(b)
        if fa >= fb:
            hi, b = b, a
            a = hi - ratio * (hi - lo)
        else:
            lo, a = a, b
            b = lo + ratio * (hi - lo)
    return best, at

"""The true speed of a keyed location: F-curve derivatives per segment, not sample differences.

A world line sampled a few times per frame averages the speed over each sample interval, so
a spike shorter than one sample, or a CONSTANT-interpolation jump (a teleport), passes as
slow.  Here each F-curve's derivative is worked out per key segment: Bezier segments from
their control points (with the handles shortened as Blender does when they overlap in
time), linear ones from their slope, CONSTANT ones jump at the next key (infinitely fast if
the value changes); easing modes, extrapolation and F-curve modifiers by central
differences of Blender's own evaluation.  Nothing here imports bpy: an F-curve is read
through its ``keyframe_points``, ``modifiers``, ``extrapolation`` and ``evaluate``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

BEZIER_SAMPLES = 64  # parameter samples per Bezier segment for the speed maximum (then refined)
_BISECTIONS = 60  # frame -> Bezier parameter (time is monotonic in the parameter)


@dataclass
class KeyedCurve:
    """One F-curve's key segments as arrays: segment i runs from key i to key i + 1."""

    key_frame: np.ndarray  # (K,)
    key_value: np.ndarray  # (K,)
    handle_right: np.ndarray  # (K, 2) of each key (frame, value), shortened as Blender does
    handle_left: np.ndarray  # (K, 2)
    interpolation: list  # per key: how the segment starting there is interpolated
    evaluate: Callable[[float], float]
    exact: bool  # False with F-curve modifiers: Blender's evaluation is differentiated numerically

    @classmethod
    def from_fcurve(cls, fc) -> "KeyedCurve":
        points = list(fc.keyframe_points)
        co = np.array([tuple(p.co) for p in points], dtype=np.float64).reshape(-1, 2)
        left = np.array([tuple(p.handle_left) for p in points], dtype=np.float64).reshape(-1, 2)
        right = np.array([tuple(p.handle_right) for p in points], dtype=np.float64).reshape(-1, 2)
        order = np.argsort(co[:, 0], kind="stable")
        co, left, right = co[order], left[order], right[order]
        curve = cls(co[:, 0], co[:, 1], right.copy(), left.copy(), [points[i].interpolation for i in order],
                    fc.evaluate, exact=not any(not m.mute for m in fc.modifiers))
        curve._shorten_overlapping_handles()
        return curve

    def _shorten_overlapping_handles(self) -> None:
        """Blender scales a segment's two handles down together when their time extents add up to
        more than the segment, so that time stays monotonic along it."""
        for i in range(len(self.key_frame) - 1):
            span = self.key_frame[i + 1] - self.key_frame[i]
            out = np.array([self.key_frame[i], self.key_value[i]]) - self.handle_right[i]
            into = np.array([self.key_frame[i + 1], self.key_value[i + 1]]) - self.handle_left[i + 1]
            reach = abs(out[0]) + abs(into[0])
            if reach > span > 0.0:
                scale = span / reach
                self.handle_right[i] = np.array([self.key_frame[i], self.key_value[i]]) - scale * out
                self.handle_left[i + 1] = np.array([self.key_frame[i + 1], self.key_value[i + 1]]) - scale * into

    def bezier(self, i: int) -> np.ndarray:
        """The four control points (4, 2) of segment i."""
        return np.array([(self.key_frame[i], self.key_value[i]), self.handle_right[i],
                         self.handle_left[i + 1], (self.key_frame[i + 1], self.key_value[i + 1])])

    def jumps(self) -> list[float]:
        """Frames where the curve jumps (a CONSTANT segment into a different value, or two keys on one frame)."""
        out = []
        for i in range(len(self.key_frame) - 1):
            same_frame = self.key_frame[i + 1] <= self.key_frame[i]
            if (self.interpolation[i] == 'CONSTANT' or same_frame) and self.key_value[i + 1] != self.key_value[i]:
                out.append(float(self.key_frame[i + 1]))
        return out

    def probe_frames(self) -> np.ndarray:
        """Frames at which the derivative should be looked at: keys, and dense points on Bezier segments."""
        frames = [self.key_frame]
        t = np.linspace(0.0, 1.0, BEZIER_SAMPLES + 1)
        for i in range(len(self.key_frame) - 1):
            if self.interpolation[i] == 'BEZIER':
                frames.append(_cubic(self.bezier(i)[:, 0], t))
            elif self.interpolation[i] != 'LINEAR':
                frames.append(np.linspace(self.key_frame[i], self.key_frame[i + 1], BEZIER_SAMPLES + 1))
        return np.concatenate(frames)

    def derivative(self, frames: np.ndarray) -> np.ndarray:
        """d value / d frame at each frame (inside CONSTANT segments 0; jumps are in ``jumps``)."""
        frames = np.asarray(frames, dtype=np.float64)
        out = np.empty(len(frames))
        k = self.key_frame
        segment = np.searchsorted(k, frames, side="right") - 1
        numeric = np.full(len(frames), not self.exact) | (segment < 0) | (segment >= len(k) - 1)  # extrapolation
        for i in np.unique(segment[~numeric]):
            sel = np.flatnonzero((segment == i) & ~numeric)
            mode = self.interpolation[i]
            if mode == 'CONSTANT' or k[i + 1] <= k[i]:
                out[sel] = 0.0
            elif mode == 'LINEAR':
                out[sel] = (self.key_value[i + 1] - self.key_value[i]) / (k[i + 1] - k[i])
            elif mode == 'BEZIER':
                out[sel] = _bezier_slope(self.bezier(i), frames[sel])
            else:
                numeric[sel] = True
        if np.any(numeric):
            out[numeric] = self._central_difference(frames[numeric])
        return out

    def _central_difference(self, frames: np.ndarray) -> np.ndarray:
        h = 1e-4 * max(1.0, float(np.ptp(self.key_frame)) / max(len(self.key_frame), 1))
        evaluate = self.evaluate
        ahead = np.fromiter((evaluate(f + h) for f in frames), dtype=np.float64, count=len(frames))
        behind = np.fromiter((evaluate(f - h) for f in frames), dtype=np.float64, count=len(frames))
        return (ahead - behind) / (2.0 * h)


def _cubic(points: np.ndarray, t: np.ndarray) -> np.ndarray:
    s = 1.0 - t
    return s**3 * points[0] + 3 * s * s * t * points[1] + 3 * s * t * t * points[2] + t**3 * points[3]


def _cubic_slope(points: np.ndarray, t: np.ndarray) -> np.ndarray:
    s = 1.0 - t
    return 3 * (s * s * (points[1] - points[0]) + 2 * s * t * (points[2] - points[1]) + t * t * (points[3] - points[2]))


def _bezier_slope(control: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """dy/dx of a Bezier segment at given x (its time coordinate rises monotonically in t)."""
    x = control[:, 0]
    lo, hi = np.zeros(len(frames)), np.ones(len(frames))
    for _ in range(_BISECTIONS):
        mid = 0.5 * (lo + hi)
        below = _cubic(x, mid) < frames
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    t = 0.5 * (lo + hi)
    dx, dy = _cubic_slope(x, t), _cubic_slope(control[:, 1], t)
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

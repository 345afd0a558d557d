"""The camera's lens and shutter as sampling functions (pure numpy, Cycles' conventions).

Depth of field: a thin lens whose aperture is a disc (or a regular polygon of ``blades``
corners, turned by ``rotation``, squeezed across by ``ratio``) of radius ``radius`` in the
camera's rest frame.  Every sample of one frame leaves its aperture point at the same
camera-frame time and aims at its pixel's point on the plane of focus (see
docs/physics-camera.md); :class:`~.camera.CameraRays` builds those rays.

The random numbers of a camera sample come from :mod:`.sampling` keyed by (pixel, sample) in
dimensions of their own, so a pixel's lens points do not depend on the tiling.
"""

from __future__ import annotations

import numpy as np

from . import sampling

# sampling dimensions of a camera sample: 0-2 are the pixel jitter (sampling.stratified_offsets),
# 1000 and above the lights (shading); the lens takes 10-12, the shutter 13-14
LENS_DIMENSION = 10
SHUTTER_DIMENSION = 13


def stratified_single(pixel, sample, count: int, dimension: int):
    """One number in [0, 1) per camera sample: sample k of a pixel's ``count`` in its own of
    ``count`` equal intervals, jittered inside it."""
    interval = sampling.shuffled_strata(pixel, sample, count, dimension)
    return (interval + sampling.uniform(pixel, sample, dimension + 1)) / count


def concentric_disc(u1, u2):
    """Points of the unit disc, uniform in area, from two uniforms in [0, 1) (Shirley and
    Chiu's concentric map: neighbouring numbers stay neighbouring points)."""
    a = 2.0 * np.asarray(u1, dtype=np.float64) - 1.0
    b = 2.0 * np.asarray(u2, dtype=np.float64) - 1.0
    wide = np.abs(a) > np.abs(b)
    radius = np.where(wide, a, b)
    with np.errstate(divide="ignore", invalid="ignore"):
        angle = np.where(wide, (np.pi / 4) * (b / a), np.pi / 2 - (np.pi / 4) * (a / b))
    angle = np.where(radius == 0.0, 0.0, angle)
    return radius * np.cos(angle), radius * np.sin(angle)


def regular_polygon(u1, u2, corners: int, rotation: float):
    """Points uniform in area over the regular polygon inscribed in the unit circle whose
    corners sit at angles ``rotation + (2 j + 1) pi / corners`` (Cycles' blade layout).

    ``u1`` picks one of the polygon's triangles (centre and one side) and, rescaled, the
    distance from the centre; ``u2`` the place along the side.
    """
    u1 = np.asarray(u1, dtype=np.float64) * corners
    side = np.floor(u1)
    depth = np.sqrt(u1 - side)  # distance toward the side: density grows linearly, uniform in area
    along = np.asarray(u2, dtype=np.float64) * depth
    half = np.pi / corners
    # in the triangle of side 0 (corners at angles +-half) ...
    x = depth * np.cos(half)
    y = (2.0 * along - depth) * np.sin(half)
    # ... then turned to the chosen side
    turn = rotation + 2.0 * half * side
    c, s = np.cos(turn), np.sin(turn)
    return c * x - s * y, s * x + c * y


def aperture_offsets(camera, pixel, sample, count: int):
    """Aperture points (x across, y up the camera; scene units, camera rest frame) of camera
    samples keyed by (pixel, sample), ``count`` per pixel: the disc or polygon of the camera's
    aperture, stratified over each pixel's samples."""
    u1, u2 = sampling.stratified_pair(pixel, sample, count, LENS_DIMENSION)
    if camera.aperture_blades >= 3:
        x, y = regular_polygon(u1, u2, int(camera.aperture_blades), camera.aperture_rotation)
    else:
        x, y = concentric_disc(u1, u2)
    return x * (camera.aperture_radius / camera.aperture_ratio), y * camera.aperture_radius


def aperture_radius(fstop: float, focal_length: float | None) -> float:
    """Cycles' aperture radius for an F-stop: half the focal length (``focal_length`` in mm, read
    as 1 mm = 1e-3 scene units) over the F-stop; an orthographic camera (``focal_length`` None)
    gets 1 / (2 F-stop)."""
    fstop = max(float(fstop), 1e-5)
    return (1.0 if focal_length is None else focal_length * 1e-3) / (2.0 * fstop)


# ---------------------------------------------------------------------- shutter
def shutter_fractions(xi, density):
    """Where in the shutter interval (0 = open, 1 = closed) samples fall, from uniforms ``xi``, with
    the density of the shutter curve: ``density`` holds its values at evenly spaced points of the
    interval, linear in between (Blender's curve as Cycles tabulates it; None = flat).

    The exact inverse of the piecewise-quadratic distribution function, not a table: on the
    chosen segment the density is b + 2 a t, so the share r of the segment's light is reached at
    a t^2 + b t = r, solved without cancellation as t = 2 r / (b + sqrt(b^2 + 4 a r)).
    """
    xi = np.asarray(xi, dtype=np.float64)
    if density is None:
        return xi
    density = np.abs(np.asarray(density, dtype=np.float64))
    step = 1.0 / (len(density) - 1)
    cumulative = np.concatenate([[0.0], np.cumsum(0.5 * step * (density[1:] + density[:-1]))])
    target = xi * cumulative[-1]
    segment = np.clip(np.searchsorted(cumulative, target, side="right") - 1, 0, len(density) - 2)
    remaining = np.maximum(target - cumulative[segment], 0.0)
    b = density[segment]
    a = (density[segment + 1] - b) / (2.0 * step)
    root = b + np.sqrt(np.maximum(b * b + 4.0 * a * remaining, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        within = np.where(root > 0.0, 2.0 * remaining / root, 0.0)
    return np.minimum((segment + np.clip(within / step, 0.0, 1.0)) * step, 1.0)


def rolling_shutter_fractions(fractions, rows, height: int, duration: float):
    """Cycles' rolling shutter ("TOP"): the rows are read from the top (row ``height - 1``, as
    image rows count from the bottom) down; each row sees the share ``duration`` of the shutter
    interval, its window starting ``1 - row / height`` of the way through the rest (duration 0:
    every row at one instant, 1: no roll)."""
    row_time = 1.0 - np.asarray(rows, dtype=np.float64) / height
    return (np.asarray(fractions) - 0.5) * duration + (row_time - 0.5) * (1.0 - duration) + 0.5


def shutter_times(camera, pixel, sample, count: int, resolution):
    """Observation times (seconds on the camera's own clock, from the frame's observation event)
    of camera samples keyed by (pixel, sample), ``count`` per pixel (stratified over them), over
    the camera's shutter interval."""
    width, height = resolution
    xi = stratified_single(pixel, sample, count, SHUTTER_DIMENSION)
    fractions = shutter_fractions(xi, camera.shutter_curve)
    if camera.rolling_shutter_type == "TOP":
        fractions = rolling_shutter_fractions(fractions, np.asarray(pixel) // width, height,
                                              camera.rolling_shutter_duration)
    opens, closes = camera.shutter_interval
    return opens + fractions * (closes - opens)

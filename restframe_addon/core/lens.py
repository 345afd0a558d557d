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
# 1000 and above the lights (shading); the lens takes two of its own
LENS_DIMENSIONS = (10, 11)


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


def aperture_offsets(camera, pixel, sample):
    """Aperture points (x across, y up the camera; scene units, camera rest frame) of camera
    samples keyed by (pixel, sample): the disc or polygon of the camera's aperture."""
    u1 = sampling.uniform(pixel, sample, LENS_DIMENSIONS[0])
    u2 = sampling.uniform(pixel, sample, LENS_DIMENSIONS[1])
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

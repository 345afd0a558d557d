"""Primary rays in the observer's (camera's) rest frame, matching Blender's cameras.

Image coordinates: ``px`` from the left edge, ``py`` from the bottom edge, in
pixels of the full image (pixel centres at +0.5).  Perspective and orthographic
rays interpolate Blender's ``view_frame`` corners, so sensor fit, shift and
ortho scale are exactly Blender's.  Panoramic mappings follow Cycles' (its
camera-space convention: forward -Z, left -X, up +Y).
"""

from __future__ import annotations

import math

import numpy as np

from . import lens, rows
from .scene import Camera


def _camera_local(camera: Camera, u, v):
    """Points on the image plane (camera space) for normalised coordinates u, v in [0, 1]."""
    top_right, bottom_right, bottom_left, top_left = np.asarray(camera.frame, dtype=np.float64)
    return (
        bottom_left
        + u[:, None] * (bottom_right - bottom_left)
        + v[:, None] * (top_left - bottom_left)
    )


def _panorama_local(camera: Camera, u, v, aspect):
    """Unit directions (camera space) and a validity mask for panoramic cameras."""
    forward = np.array([0.0, 0.0, -1.0])
    left = np.array([-1.0, 0.0, 0.0])
    up = np.array([0.0, 1.0, 0.0])
    ptype = camera.panorama_type
    if ptype == "EQUIRECTANGULAR":
        lon_min, lon_max = camera.longitude_range
        lat_min, lat_max = camera.latitude_range
        lon = lon_max - u * (lon_max - lon_min)
        lat = lat_min + v * (lat_max - lat_min)
        x, y, z = np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)
        valid = np.ones(len(u), dtype=bool)
    elif ptype in ("FISHEYE_EQUIDISTANT", "FISHEYE_EQUISOLID"):
        if ptype == "FISHEYE_EQUIDISTANT":
            a = (u - 0.5) * 2.0
            b = (v - 0.5) * 2.0 / aspect
            r = np.hypot(a, b)
            theta = r * camera.fisheye_fov * 0.5
            valid = r <= 1.0
        else:
            width, height = camera.sensor_size
            a = (u - 0.5) * width
            b = (v - 0.5) * height
            r = np.hypot(a, b)
            theta = 2.0 * np.arcsin(np.clip(r / (2.0 * camera.fisheye_lens), -1.0, 1.0))
            valid = (r <= 2.0 * camera.fisheye_lens) & (theta <= camera.fisheye_fov * 0.5)
        with np.errstate(invalid="ignore", divide="ignore"):
            phi = np.where(r > 0, np.arccos(np.clip(a / r, -1.0, 1.0)), 0.0)
        phi = np.where(b < 0, -phi, phi)
        x, y, z = np.cos(theta), -np.cos(phi) * np.sin(theta), np.sin(phi) * np.sin(theta)
    else:
        raise ValueError(f"{camera.name}: panorama type {ptype} is not supported by RESTframe")
    d = x[:, None] * forward + y[:, None] * left + z[:, None] * up
    return d, valid


_RUN_MARGIN = 1e-9  # of a unit direction: the rays' rounding (a few ulp) and the bounds' own


class CameraRays:
    """Primary rays of one camera at one resolution, its constants worked out once (a tile's
    rays then cost only per-ray arithmetic).

    Image coordinates as in :func:`primary_rays`; ``offset`` moves the origins (the camera's
    placement in its rest frame).
    """

    def __init__(self, camera: Camera, resolution, offset=(0.0, 0.0, 0.0)):
        if camera.kind not in ("PERSP", "ORTHO", "PANO"):
            raise ValueError(f"{camera.name}: camera type {camera.kind} is not supported by RESTframe")
        self.camera = camera
        self.width, self.height = resolution
        matrix = np.asarray(camera.matrix, dtype=np.float64)
        self.rotation = matrix[:3, :3]
        self.position = matrix[:3, 3] + np.asarray(offset, dtype=np.float64)
        top_right, bottom_right, bottom_left, top_left = np.asarray(camera.frame, dtype=np.float64)
        # image-plane points are corner + u across + v up (camera space); rotated once, not per ray
        self.plane = (bottom_left, bottom_right - bottom_left, top_left - bottom_left)
        self.world_plane = list(zip(*(self.rotation @ p for p in self.plane)))  # per axis: (corner, across, up)

    @property
    def has_lens(self) -> bool:
        """Whether samples go through a finite aperture (depth of field)."""
        return self.camera.has_depth_of_field

    def __call__(self, px, py, grid: bool = False, keys=None):
        """Rays for image positions px, py; with ``keys`` = (pixel ids, sample numbers, samples
        per pixel), one id and number per ray, and a camera with depth of field, each ray leaves
        its own aperture point."""
        rays = self._pinhole(px, py, grid)
        if keys is None or not self.has_lens:
            return rays
        return self._through_lens(*rays, *keys)

    def _pinhole(self, px, py, grid):
        u = np.asarray(px, dtype=np.float64) / self.width
        v = np.asarray(py, dtype=np.float64) / self.height
        camera = self.camera
        if camera.kind == "PERSP":
            return self._perspective(u, v, grid)
        if grid:
            u, v = np.tile(u, len(v)), np.repeat(v, len(u))
        n = len(u)
        if camera.kind == "ORTHO":
            local = _camera_local(camera, u, v)
            offsets = np.column_stack([local[:, 0], local[:, 1], np.zeros(n)])
            axis = self.rotation[:, 2]
            directions = np.broadcast_to(-axis / np.linalg.norm(axis), (n, 3))
            origins = self.position + offsets @ self.rotation.T
            valid = np.ones(n, dtype=bool)
        else:
            d_local, valid = _panorama_local(camera, u, v, self.width / self.height)
            directions = rows.normalized(d_local @ self.rotation.T)
            origins = np.broadcast_to(self.position, (n, 3))
        return origins, directions, np.full(n, camera.clip_start), np.full(n, camera.clip_end), valid

    def _perspective(self, u, v, grid):
        n = len(u) * len(v) if grid else len(u)

        def on_plane(corner, across, up):  # (corner + v up) + u across at every ray
            if grid:
                return np.add.outer(corner + up * v, across * u).ravel()
            # a zero term left out gives the same bits (u, v finite): corner + (+-0) is the corner
            # when that is not 0, and a sum that is not -0 plus +-0 is itself; so does a factor of
            # 1 (1 u is u: a camera whose image's width lies along a world axis)
            if up == 0.0 and corner != 0.0:
                if across == 1.0:
                    return np.add(u, corner)
                point = np.multiply(across, u)
            else:
                point = np.multiply(up, v)
                if across != 0.0 or (corner == 0.0 and math.copysign(1.0, corner) < 0.0):
                    point += corner
                    point += np.multiply(across, u, out=np.empty(len(u)))
                    return point
            point += corner
            return point

        # the image-plane points by axis (contiguous rows), scaled to unit length as they are
        # written into the directions' columns (one strided pass per axis)
        points = [on_plane(corner, across, up) for corner, across, up in self.world_plane]
        inverse = np.multiply(points[0], points[0])  # the squared length summed in rows.norm's order
        for axis in (1, 2):
            inverse += np.square(points[axis])
        np.sqrt(inverse, out=inverse)
        np.divide(1.0, inverse, out=inverse)  # the rotation keeps lengths
        directions = np.empty((n, 3))
        for axis, point in enumerate(points):
            np.multiply(point, inverse, out=directions[:, axis])
        corner, across, up = self.plane
        # path length per unit of depth along the view axis: 1 / cosine to the axis (the plane is at z < 0)
        if corner[2] != 0.0 and across[2] == 0.0 and up[2] == 0.0:
            # the image plane at one depth (Blender's camera frame): on_plane would add zeros to the corner
            per_depth = np.multiply(inverse, corner[2])
        else:
            per_depth = on_plane(corner[2], across[2], up[2])
            per_depth *= inverse
        np.divide(-1.0, per_depth, out=per_depth)
        camera = self.camera
        return (np.broadcast_to(self.position, (n, 3)), directions, camera.clip_start * per_depth,
                camera.clip_end * per_depth, np.ones(n, dtype=bool))

    def cones(self, rects) -> list:
        """Per rectangle of ``rects`` ((x0, y0, x1, y1) each, their whole area): (axis, half-angle)
        of a cone holding the direction of every pinhole ray through its pixels, None for a cone
        of a right angle or more; all None for other cameras.  The rays through a rectangle of
        the image plane are positive sums of its corners' rays, which a cone under a right angle
        (a convex set) holding those holds too; widened for the rays' own rounding.  Every
        rectangle's corners at once (a render's tiles: one pass, not one per tile)."""
        if self.camera.kind != "PERSP":
            return [None] * len(rects)
        x0, y0, x1, y1 = np.asarray(rects, dtype=np.float64).reshape(-1, 4).T
        corners = self._perspective((np.stack([x0, x1, x1, x0], axis=1) / self.width).ravel(),
                                    (np.stack([y0, y0, y1, y1], axis=1) / self.height).ravel(),
                                    False)[1].reshape(-1, 4, 3)
        axes = corners.sum(axis=1)
        axes /= np.sqrt(np.einsum("ij,ij->i", axes, axes))[:, None]
        cosines = np.einsum("ikj,ij->ik", corners, axes)
        angles = np.arccos(np.clip(cosines, -1.0, 1.0).min(axis=1)) * (1.0 + 1e-6) + 1e-9
        return [(axis, float(angle)) if angle < 0.5 * np.pi else None for axis, angle in zip(axes, angles)]

    def run_bounds(self, rect, pixels: slice, run: int):
        """(low, high), each (3, b): bounds of the direction of every pinhole ray through each run
        of ``run`` consecutive pixels of ``rect``'s ``pixels`` (row-major, as the tile's rays; the
        pixels past the last whole run left out), wherever in its pixel the ray is: a tile's
        camera rays are culled by these once for all its samples (``tracer.trace_nearest``); None
        for other cameras, and where runs would span two rows.  The image-plane point p is affine
        in the image position, so over a run's pixels (a rectangle) each axis of p lies between
        the rectangle's corners'; then ``p / |p|`` lies between the box's ends over the box's
        nearest and farthest |p|, widened for the rays' own rounding."""
        x0, y0, x1, y1 = rect
        width = x1 - x0
        if self.camera.kind != "PERSP" or width % run or pixels.start % run:
            return None
        first, last = pixels.start // width, -(-pixels.stop // width)  # the rows the pixels are in
        u = np.arange(x0, x1 + 1, run, dtype=np.float64) / self.width  # the runs' ends
        v = np.arange(y0 + first, y0 + last + 1, dtype=np.float64) / self.height
        start = pixels.start // run - first * (width // run)
        kept = slice(start, start + (pixels.stop - pixels.start) // run)
        low, high = np.empty((3, kept.stop - kept.start)), np.empty((3, kept.stop - kept.start))
        for axis, (corner, across, up) in enumerate(self.world_plane):
            at = np.add.outer(corner + up * v, across * u)  # (rows + 1, runs + 1): the runs' corners
            rows_low, rows_high = np.minimum(at[:-1], at[1:]), np.maximum(at[:-1], at[1:])
            low[axis] = np.minimum(rows_low[:, :-1], rows_low[:, 1:]).ravel()[kept]
            high[axis] = np.maximum(rows_high[:, :-1], rows_high[:, 1:]).ravel()[kept]
        nearest = np.sqrt(np.sum(np.clip(0.0, low, high) ** 2, axis=0))
        farthest = np.sqrt(np.sum(np.maximum(low * low, high * high), axis=0))
        with np.errstate(divide="ignore", invalid="ignore"):
            low = np.minimum(low / nearest, low / farthest)
            high = np.maximum(high / nearest, high / farthest)
        spread_out = ~(nearest > 0.0)  # a run's box about the eye: any direction
        low[:, spread_out], high[:, spread_out] = -1.0, 1.0
        return low - _RUN_MARGIN, high + _RUN_MARGIN

    def _through_lens(self, origins, directions, s_lo, s_hi, valid, pixel, sample, count):
        """The pinhole rays moved to their aperture points and aimed at the points where they
        meet the plane of focus (panoramas: the sphere of focus), as Cycles' thin lens.

        All in the camera's rest frame: the aperture lies across the view axis (across each
        ray for panoramas) and every ray still starts at the frame's one camera time.
        """
        camera = self.camera
        across, up, forward = self.rotation[:, 0], self.rotation[:, 1], -self.rotation[:, 2]
        lens_x, lens_y = lens.aperture_offsets(camera, pixel, sample, count)
        focus = camera.focus_distance
        if camera.kind == "PANO":
            # Cycles' aperture basis for a panoramic ray: the view axis made perpendicular to the ray
            across = forward - rows.scale(directions, directions @ forward)
            length = rows.norm(across)
            on_axis = length < 1e-9  # the ray along the view axis: any perpendicular will do
            across[on_axis] = self.rotation[:, 0]
            length[on_axis] = 1.0
            across = rows.scale(across, 1.0 / length)
            offset = rows.add_scaled(rows.scale(rows.cross(directions, across), lens_y), lens_x, across)
            to_focus = directions * focus
        else:
            offset = rows.add_scaled(np.multiply.outer(lens_y, up), lens_x, across)
            if camera.kind == "PERSP":
                to_focus = rows.scale(directions, focus / (directions @ forward))
            else:
                to_focus = forward * focus
        aimed = rows.normalized(to_focus - offset)
        if camera.kind == "ORTHO":  # Cycles starts the ray at the near clip depth and keeps its length
            s_lo = camera.clip_start / (aimed @ forward)
            s_hi = s_lo + (camera.clip_end - camera.clip_start)
        return origins + offset, aimed, s_lo, s_hi, valid


def primary_rays(camera: Camera, px, py, resolution, offset=(0.0, 0.0, 0.0), grid: bool = False):
    """Rays for image positions px, py (pixels): origins and unit directions in the camera's
    rest frame (world axes, camera-local origin at the camera, moved by ``offset``), the clip
    range of path lengths, and a mask of positions that see anything at all (fisheye circle).

    With ``grid``, px (w,) and py (h,) are the columns and rows of a rectangle of positions
    (rays in row-major order: a tile's pixel centres).  A perspective camera's origins are
    one point, returned as a read-only broadcast view."""
    return CameraRays(camera, resolution, offset)(px, py, grid)

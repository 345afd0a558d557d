"""Primary rays in the observer's (camera's) rest frame, matching Blender's cameras.

Image coordinates: ``px`` from the left edge, ``py`` from the bottom edge, in
pixels of the full image (pixel centres at +0.5).  Perspective and orthographic
rays interpolate Blender's ``view_frame`` corners, so sensor fit, shift and
ortho scale are exactly Blender's.  Panoramic mappings follow Cycles' (its
camera-space convention: forward -Z, left -X, up +Y).
"""

from __future__ import annotations

import numpy as np

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


def primary_rays(camera: Camera, px, py, resolution):
    """Rays for image positions px, py (pixels): origins and unit directions in the camera's
    rest frame (world axes, camera-local origin at the camera), the clip range of
    path lengths, and a mask of positions that see anything at all (fisheye circle)."""
    width, height = resolution
    u = np.asarray(px, dtype=np.float64) / width
    v = np.asarray(py, dtype=np.float64) / height
    matrix = np.asarray(camera.matrix, dtype=np.float64)
    rotation, position = matrix[:3, :3], matrix[:3, 3]
    n = len(u)
    if camera.kind == "PERSP":
        local = _camera_local(camera, u, v)
        length = np.sqrt(np.einsum("ij,ij->i", local, local))
        directions = (local @ rotation.T) / length[:, None]  # the rotation keeps lengths
        cos_axis = -local[:, 2] / length
        origins = np.broadcast_to(position, (n, 3))
        return origins, directions, camera.clip_start / cos_axis, camera.clip_end / cos_axis, np.ones(n, dtype=bool)
    if camera.kind == "ORTHO":
        local = _camera_local(camera, u, v)
        offsets = np.column_stack([local[:, 0], local[:, 1], np.zeros(n)])
        directions = np.broadcast_to(-rotation[:, 2] / np.linalg.norm(rotation[:, 2]), (n, 3))
        origins = position + offsets @ rotation.T
        valid = np.ones(n, dtype=bool)
    elif camera.kind == "PANO":
        d_local, valid = _panorama_local(camera, u, v, width / height)
        directions = d_local @ rotation.T
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        origins = np.broadcast_to(position, (n, 3))
    else:
        raise ValueError(f"{camera.name}: camera type {camera.kind} is not supported by RESTframe")
    return origins, directions, np.full(n, camera.clip_start), np.full(n, camera.clip_end), valid

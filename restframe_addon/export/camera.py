"""The camera: Blender's camera object -> the core Camera, with its image plane and velocity."""

from __future__ import annotations

import numpy as np

from ..core.scene import Camera
from .errors import ExportError
from .motion import object_velocity


_PANORAMAS = {"EQUIRECTANGULAR", "FISHEYE_EQUIDISTANT", "FISHEYE_EQUISOLID"}


def _fitted_sensor(cam, aspect: float) -> tuple[float, float]:
    """Sensor (width, height) in mm after Blender's sensor fit for this image aspect."""
    fit = cam.sensor_fit
    if fit == 'AUTO':
        fit = 'HORIZONTAL' if aspect >= 1.0 else 'VERTICAL'
        size = cam.sensor_width
    else:
        size = cam.sensor_width if fit == 'HORIZONTAL' else cam.sensor_height
    return (size, size / aspect) if fit == 'HORIZONTAL' else (size * aspect, size)


def export_camera(camera_object, scene) -> Camera:
    """Blender's camera as the core sees it; ``view_frame`` gives the exact image plane."""
    if camera_object is None:
        raise ExportError("the scene has no camera: add one and set it as the scene camera")
    if camera_object.type != 'CAMERA':
        raise ExportError(f"{camera_object.name}: the scene camera is a {camera_object.type.lower()} object, not a camera")
    cam = camera_object.data
    matrix = np.array(camera_object.matrix_world, dtype=np.float64)
    matrix[:3, :3] /= np.linalg.norm(matrix[:3, :3], axis=0)
    render = scene.render
    aspect = (render.resolution_x * render.pixel_aspect_x) / (render.resolution_y * render.pixel_aspect_y)
    out = Camera(
        matrix=matrix,
        kind=cam.type,
        frame=np.array([tuple(v) for v in cam.view_frame(scene=scene)], dtype=np.float64),
        clip_start=float(cam.clip_start),
        clip_end=float(cam.clip_end),
        sensor_size=_fitted_sensor(cam, aspect),
        velocity=object_velocity(camera_object),
        name=camera_object.name,
    )
    if cam.type == 'PANO':
        ptype = getattr(cam, "panorama_type", None) or getattr(getattr(cam, "cycles", None), "panorama_type", None)
        if ptype not in _PANORAMAS:
            raise ExportError(f"{camera_object.name}: panorama type {ptype} is not supported "
                              f"(use one of {', '.join(sorted(_PANORAMAS))})")
        out.panorama_type = ptype
        out.latitude_range = (float(cam.latitude_min), float(cam.latitude_max))
        out.longitude_range = (float(cam.longitude_min), float(cam.longitude_max))
        out.fisheye_fov = float(cam.fisheye_fov)
        out.fisheye_lens = float(cam.fisheye_lens)
    return out


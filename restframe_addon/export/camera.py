"""The camera: Blender's camera object -> the core Camera, with its image plane, velocity, lens
(Depth of Field) and shutter (Motion Blur), as Cycles reads them."""

from __future__ import annotations

import dataclasses

import numpy as np

from ..core import lens, validation
from ..core.lorentz import Boost
from ..core.scene import Camera, Velocity
from ..motion_query import assembly_root, location_curves, motion_source
from .errors import ExportError
from .motion import object_velocity, point_trajectory, shutter_frames


_PANORAMAS = {"EQUIRECTANGULAR", "FISHEYE_EQUIDISTANT", "FISHEYE_EQUISOLID"}


def without_scale(matrix) -> tuple[np.ndarray, np.ndarray]:
    """A world matrix (4x4) with its axes made unit length, as Cycles takes a camera's or lamp's,
    and the axes' lengths (the scale); an axis scaled to zero comes out NaN: the caller decides."""
    matrix = np.array(matrix, dtype=np.float64)
    scale = np.linalg.norm(matrix[:3, :3], axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        matrix[:3, :3] /= scale
    return matrix, scale


def _fitted_sensor(cam, aspect: float) -> tuple[float, float]:
    """Sensor (width, height) in mm after Blender's sensor fit for this image aspect."""
    fit = cam.sensor_fit
    if fit == 'AUTO':
        fit = 'HORIZONTAL' if aspect >= 1.0 else 'VERTICAL'
        size = cam.sensor_width
    else:
        size = cam.sensor_width if fit == 'HORIZONTAL' else cam.sensor_height
    return (size, size / aspect) if fit == 'HORIZONTAL' else (size * aspect, size)


def depth_of_field(camera_object) -> dict:
    """The core Camera's lens fields from Blender's Depth of Field panel, as Cycles reads them:
    aperture radius from the F-stop (half the focal length, in mm read as 1e-3 scene units,
    over the F-stop; 1 / (2 F-stop) for an orthographic camera), the focus object's distance
    along the view axis (its bone's, with a subtarget).  Nothing (a pinhole) without Depth of Field."""
    cam = camera_object.data
    dof = cam.dof
    if not dof.use_dof:
        return {}
    focus = float(dof.focus_distance)
    if dof.focus_object is not None:
        target = dof.focus_object.matrix_world
        bone = getattr(dof, "focus_subtarget", "")
        if bone and dof.focus_object.pose is not None and bone in dof.focus_object.pose.bones:
            target = target @ dof.focus_object.pose.bones[bone].matrix
        view_axis = np.array(camera_object.matrix_world.col[2][:3])
        offset = np.array(camera_object.matrix_world.translation) - np.array(target.translation)
        focus = abs(float(offset @ view_axis)) / float(np.linalg.norm(view_axis))
    return dict(
        aperture_radius=lens.aperture_radius(dof.aperture_fstop, None if cam.type == 'ORTHO' else cam.lens),
        focus_distance=max(focus, 1e-5),
        aperture_blades=int(dof.aperture_blades),  # Blender's 0 (or the core's < 3): round
        aperture_rotation=float(dof.aperture_rotation),
        aperture_ratio=float(dof.aperture_ratio),
    )


SHUTTER_CURVE_POINTS = 256  # the shutter curve tabulated as Cycles does (RAMP_TABLE_SIZE)


def motion_blur(scene) -> dict:
    """The core Camera's shutter fields: the interval in seconds of the camera's own clock, the
    shutter curve's openness (None when flat) and the rolling shutter; nothing without motion blur."""
    frames = shutter_frames(scene)
    if frames is None:
        return {}
    seconds_per_frame = scene.render.fps_base / scene.render.fps
    mapping = scene.render.motion_blur_shutter_curve
    curve = np.array([mapping.evaluate(mapping.curves[0], x) for x in np.linspace(0.0, 1.0, SHUTTER_CURVE_POINTS)])
    try:
        validation.check_shutter_curve(curve)
    except ValueError as error:
        raise ExportError(str(error)) from None
    rf = scene.restframe
    return dict(
        shutter_interval=(frames[0] * seconds_per_frame, frames[1] * seconds_per_frame),
        shutter_curve=None if np.all(curve == curve[0]) else curve,
        rolling_shutter_type=rf.rolling_shutter_type,
        rolling_shutter_duration=float(rf.rolling_shutter_duration),
    )


def _assembly_place(position, camera_object, velocity: Velocity) -> np.ndarray:
    """Where a point of the camera's assembly is in S at world time 0 (its world line then runs on
    with the velocity): the assembly pivot plus its Blender offset from it, Lorentz-contracted, so
    that in the assembly's frame it keeps that offset (``docs/physics.md#observer``)."""
    pivot = np.asarray(assembly_root(motion_source(camera_object)).matrix_world.translation, dtype=np.float64)
    boost = Boost.from_velocity(velocity.beta, velocity.lorentz_factor)
    return pivot + boost.contracted(np.asarray(position, dtype=np.float64) - pivot)


def _world_line(camera_object, scene, position, warn):
    """The world line of the point ``position`` (its Blender place at the rendered frame) of the
    camera's animated assembly (``point_trajectory``): the camera's, or a stereo eye's."""
    root = assembly_root(motion_source(camera_object))
    return point_trajectory(root, scene, position, position, camera_object.name, warn=warn)


_OBJECT_KINDS = {"FONT": "text", "GPENCIL": "grease pencil", "GREASEPENCIL": "grease pencil"}  # as the UI says


def export_camera(camera_object, scene, warn=print) -> Camera:
    """Blender's camera as the core sees it; ``view_frame`` gives the exact image plane.

    It moves as a point of its assembly (``docs/physics.md#observer``): with the motion settings of
    its own, or, with none (Constant, zero velocity), of its parent, so a cockpit camera rides with
    its ship.  With Motion = Animation the assembly's keyframed location gives its world line (an
    accelerating observer)."""
    if camera_object is None:
        raise ExportError("the scene has no camera: add one and set it as the scene camera")
    if camera_object.type != 'CAMERA':
        kind = _OBJECT_KINDS.get(camera_object.type, camera_object.type.lower().replace("_", " "))
        article = "an" if kind[0] in "aeiou" else "a"
        raise ExportError(f"{camera_object.name}: the scene camera is {article} {kind} object, not a camera")
    cam = camera_object.data
    matrix, _ = without_scale(camera_object.matrix_world)  # a zero scale: NaN, refused by the core's check
    render = scene.render
    aspect = (render.resolution_x * render.pixel_aspect_x) / (render.resolution_y * render.pixel_aspect_y)
    source = motion_source(camera_object)
    root = assembly_root(source)
    if any(source.restframe.angular_velocity):
        warn(f"{camera_object.name}: the camera does not spin with '{source.name}' (it takes its velocity only)")
    animated = source.restframe.is_animated
    velocity = Velocity() if animated else object_velocity(source)
    trajectory = None
    if animated:
        if root != camera_object and location_curves(camera_object)[0]:
            warn(f"{camera_object.name}: it rides on the world line of '{root.name}' (the same motion settings): "
                 "its own location keys only place it at the rendered frame")
        trajectory = _world_line(camera_object, scene, matrix[:3, 3], warn)
    else:
        matrix[:3, 3] = _assembly_place(matrix[:3, 3], camera_object, velocity)
    out = Camera(
        matrix=matrix,
        kind=cam.type,
        frame=np.array([tuple(v) for v in cam.view_frame(scene=scene)], dtype=np.float64),
        clip_start=float(cam.clip_start),
        clip_end=float(cam.clip_end),
        sensor_size=_fitted_sensor(cam, aspect),
        velocity=velocity,
        trajectory=trajectory,
        name=camera_object.name,
        **depth_of_field(camera_object),
        **motion_blur(scene),
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



def render_views(scene) -> list[str]:
    """The views a render produces: none without Stereoscopy, else Blender's stereo pair or
    the enabled multi-views."""
    render = scene.render
    if not render.use_multiview:
        return []
    if render.views_format == 'STEREO_3D':
        return [name for name in ('left', 'right') if name in render.views]
    return [view.name for view in render.views if view.use]


def view_camera(camera: Camera, camera_object, scene, model_matrix, shift_x: float) -> Camera:
    """The camera of one view (an eye): Blender's own model matrix and lens shift for it
    (``RenderEngine.camera_model_matrix`` / ``camera_shift_x`` after ``active_view_set``, the
    stereo convention of Cycles).  Its position is its own observation event, a point of the
    camera's assembly placed as the camera is: on a world line of its own when the assembly is
    animated (an accelerating eye observes from its own place, in its own momentary rest frame)."""
    matrix, _ = without_scale(model_matrix)
    trajectory = None
    if camera.trajectory is None:
        matrix[:3, 3] = _assembly_place(matrix[:3, 3], camera_object, camera.velocity)
    else:  # the assembly's warnings were said when the camera was exported
        trajectory = _world_line(camera_object, scene, matrix[:3, 3], warn=lambda message: None)
    frame = np.array(camera.frame)
    width, height = np.ptp(frame[:, 0]), np.ptp(frame[:, 1])
    fit = camera_object.data.sensor_fit
    horizontal = fit == 'HORIZONTAL' or (fit == 'AUTO' and width >= height)
    # the lens shift is measured in the fitted sensor side; view_frame already holds the camera's own
    frame[:, 0] += (shift_x - camera_object.data.shift_x) * (width if horizontal else height)
    return dataclasses.replace(camera, matrix=matrix, frame=frame, trajectory=trajectory)

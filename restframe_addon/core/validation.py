"""The checks of user input, and the one wording of each error message about it.

Every layer (the core, the Blender export, the UI, the command line) calls these, so
a user sees the same message for the same mistake wherever it is caught.  Checks
raise ValueError (the core's :class:`RenderError` for whole-render settings) with a
message that names the object and says what to change.
"""

from __future__ import annotations

import dataclasses
import math
from fractions import Fraction

import numpy as np


class RenderError(ValueError):
    """The scene or settings cannot be rendered; the message says what to change."""


DOPPLER_MODES = ("OFF", "FACTOR", "SPECTRAL")
PARALLELISM = ("PROCESSES", "THREADS")  # RenderSettings.parallelism: where tiles render (see core.workers)
INTEGRATORS = ("PATH", "DIRECT")
_BOUNCE_LIMITS = ("max_bounces", "diffuse_bounces", "glossy_bounces", "transmission_bounces")
_CLAMPS = ("clamp_direct", "clamp_indirect")
MAX_CAMERA_SAMPLES = 1 << 16  # camera samples per pixel: the Samples property's limit (and the CLI's)


def one_minus_speed_squared(beta) -> float:
    """1 - |beta|^2 from the exact squares of the float inputs, correctly rounded: it carries
    the whole information about a speed near c.  At rest (every scene's static objects) it is
    exactly 1 without the fractions, which cost about 40 us a call."""
    if not any(beta):
        return 1.0
    return float(1 - sum(Fraction(c) ** 2 for c in beta))


def check_velocity(beta, lorentz_factor: float = 0.0, name: str = "velocity") -> tuple[tuple[float, ...], float]:
    """The velocity ``beta`` (units of c) and Lorentz factor (0: unused; > 1: the speed, beta
    only the direction) as floats; raises ValueError naming ``name`` unless they are finite
    and give a speed below c."""
    beta = tuple(float(c) for c in beta)
    lorentz_factor = float(lorentz_factor)
    if not all(math.isfinite(c) for c in beta):
        raise ValueError(f"{name}: the velocity {beta} is not a finite number")
    if not math.isfinite(lorentz_factor):
        raise ValueError(f"{name}: the Lorentz factor {lorentz_factor} is not a finite number")
    if lorentz_factor != 0.0:
        if lorentz_factor < 1.0:
            raise ValueError(f"{name}: a Lorentz factor must be at least 1 (got {lorentz_factor:g}); 0 means unused")
        if lorentz_factor > 1.0 and math.fsum(c * c for c in beta) == 0.0:
            raise ValueError(f"{name}: a Lorentz factor above 1 needs a velocity to give the direction")
    elif one_minus_speed_squared(beta) <= 0.0:
        raise ValueError(f"{name}: speed {math.sqrt(math.fsum(c * c for c in beta)):.7g} c is not below the speed "
                         "of light; use the Lorentz factor for speeds very close to c")
    return beta, lorentz_factor


def check_angular_velocity(omega, name: str) -> None:
    """Raises ValueError naming ``name`` unless every component of the angular velocity is finite."""
    if not all(math.isfinite(float(w)) for w in omega):
        raise ValueError(f"{name}: the angular velocity {tuple(float(w) for w in omega)} is not a finite number")


def check_rim_speed(rim: float, name: str) -> None:
    """Raises ValueError naming ``name`` unless a spinning body's rim moves below c."""
    if not rim < 1.0:
        raise ValueError(f"{name}: spinning this fast its rim would move at {rim:.6g} c; "
                         "slow the spin or raise the scene's speed of light")


def check_light_speed(light_speed: float) -> None:
    """Raises ValueError unless the scene's speed of light is a positive number."""
    if not (math.isfinite(light_speed) and light_speed > 0.0):
        raise ValueError(f"the speed of light must be a positive number of scene units per second "
                         f"(got {light_speed:g})")


def non_finite_motion(name: str) -> str:
    """The message for an animated world line with a sample that is not a finite number."""
    return f"{name}: the animated location is not a finite number"


def too_many_segments(name: str, tolerance: float, limit: int) -> str:
    """The message for an animated body whose world line the motion tolerance would split too finely."""
    return (f"{name}: following its motion within the Motion Tolerance of {tolerance:g} scene units needs more "
            f"than {limit} inertial segments: raise the tolerance (Render Properties > Relativity)")


def check_finite_motion(values, name: str) -> None:
    """Raises ValueError (naming the object) unless an animated world line's samples are all finite."""
    if not np.all(np.isfinite(values)):
        raise ValueError(non_finite_motion(name))


def check_region(region, resolution) -> None:
    """Raises RenderError unless the region (x0, y0, x1, y1), x1 and y1 exclusive, holds pixels of the image."""
    width, height = resolution
    x0, y0, x1, y1 = region
    if not (0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height):
        raise RenderError(f"the render region {region} is empty or outside the {width}x{height} image")


ROLLING_SHUTTER_TYPES = ("NONE", "TOP")


def check_shutter_curve(curve) -> None:
    """Raises ValueError unless the motion-blur shutter curve (its values over the shutter) opens somewhere."""
    curve = np.asarray(curve, dtype=np.float64)
    if curve.ndim != 1 or len(curve) < 2 or not np.all(np.isfinite(curve)) or not np.any(curve != 0.0):
        raise ValueError("the motion blur shutter curve is zero everywhere (the shutter never opens): "
                         "raise it in Motion Blur > Shutter Curve")


def check_camera_optics(camera) -> None:
    """Raises ValueError naming the camera unless its lens (depth of field) and shutter (motion
    blur) settings can be rendered."""
    if not (math.isfinite(camera.aperture_radius) and camera.aperture_radius >= 0.0):
        raise ValueError(f"{camera.name}: the aperture radius must be a length of 0 or more (got {camera.aperture_radius})")
    if camera.aperture_radius > 0.0 and not (math.isfinite(camera.focus_distance) and camera.focus_distance > 0.0
                                             and math.isfinite(camera.aperture_ratio) and camera.aperture_ratio > 0.0):
        raise ValueError(f"{camera.name}: depth of field needs a focus distance and an aperture ratio above 0")
    if camera.shutter_interval is None:
        return
    opens, closes = camera.shutter_interval
    if not (math.isfinite(opens) and math.isfinite(closes) and opens <= closes):
        raise ValueError(f"{camera.name}: the shutter interval {camera.shutter_interval} is not an interval of time")
    if camera.rolling_shutter_type not in ROLLING_SHUTTER_TYPES:
        raise ValueError(f"{camera.name}: rolling shutter type {camera.rolling_shutter_type!r} is not one of "
                         f"{ROLLING_SHUTTER_TYPES}")
    if not 0.0 <= camera.rolling_shutter_duration <= 1.0:
        raise ValueError(f"{camera.name}: the rolling shutter duration must be between 0 and 1 "
                         f"(got {camera.rolling_shutter_duration})")
    if camera.shutter_curve is not None:
        check_shutter_curve(camera.shutter_curve)


def doppler_levels_error(levels: int) -> str | None:
    """Why the Factor display cannot use this many grey levels (None: it can).  0 is continuous;
    one level would paint every hit the same grey, whatever its D."""
    if int(levels) == 0 or int(levels) >= 2:
        return None
    return (f"Factor display Levels must be 0 (continuous) or at least 2, not {int(levels)} "
            "(a single level would paint every hit the same grey)")


def check_doppler_levels(levels: int) -> None:
    """Raises RenderError for a grey-level count the Factor display cannot use."""
    error = doppler_levels_error(levels)
    if error is not None:
        raise RenderError(error)


# what a non-finite field is called in the message (default: its name with spaces)
_FIELD_WORDS = {"matrix": "world transform (location, rotation, or a scale of zero)", "frame": "view frame (lens, sensor)",
                "power": "power (strength)", "power_curve": "keyed power", "color_curve": "keyed colour",
                "emission_curve": "keyed emission strength"}
# image pixels (a texture's NaN stays in its pixels, as in Cycles) and settings that are not numbers
_NOT_CHECKED_FINITE = ("base_color_texture", "alpha_texture", "normal_texture", "velocity", "trajectory",
                       "shutter_curve", "image")


def _non_finite_fields(item):
    """The (field, value) of a light, camera, material or world texture whose numbers are not all finite."""
    for f in dataclasses.fields(item):
        value = getattr(item, f.name)
        if f.name in _NOT_CHECKED_FINITE or value is None or isinstance(value, (str, bool)):
            continue
        parts = value if isinstance(value, tuple) and value and isinstance(value[0], np.ndarray) else (value,)
        if not all(np.all(np.isfinite(np.asarray(part, dtype=np.float64))) for part in parts):
            yield f.name, value


def check_finite_inputs(scene) -> None:
    """Raises RenderError naming the object unless the camera, every light, material and the world
    hold finite numbers: a NaN or infinite power, colour, location or lens (a driver dividing by zero,
    a script) would otherwise render as black or NaN pixels without a word."""
    named = [(scene.camera.name, scene.camera), *((light.name, light) for light in scene.lights),
             *((f"material {m.name}", m) for m in scene.materials)]
    if scene.world_texture is not None:
        named.append((f"world {scene.world_texture.name}", scene.world_texture))
    for name, item in named:
        for field, value in _non_finite_fields(item):
            shown = value if not isinstance(value, np.ndarray) else np.round(value, 6).tolist()
            raise RenderError(f"{name}: its {_FIELD_WORDS.get(field, field.replace('_', ' '))} is not a finite "
                              f"number ({shown})")
    if not np.all(np.isfinite(scene.world_color)):
        raise RenderError(f"the world colour {tuple(scene.world_color)} is not a finite number")


def check_render(scene, settings, known_passes) -> None:
    """Raises RenderError for a scene and settings that cannot be rendered (``known_passes``:
    the pass names settings.passes may ask for)."""
    if scene.camera is None:
        raise RenderError("the scene has no camera: add one and make it the scene camera")
    width, height = settings.resolution
    if width < 1 or height < 1:
        raise RenderError(f"the resolution {width}x{height} has no pixels")
    if settings.region is not None:
        check_region(settings.region, settings.resolution)
    try:
        check_light_speed(scene.light_speed)
    except ValueError as error:
        raise RenderError(str(error)) from None
    if not math.isfinite(scene.tau_obs):
        raise RenderError("the observation time is not finite: check the reference frame and the speed of light")
    unknown = set(settings.passes or ()) - set(known_passes)
    if unknown:
        raise RenderError(f"unknown passes {sorted(unknown)}: RESTframe fills {list(known_passes)} besides Combined")
    if settings.doppler_mode not in DOPPLER_MODES:
        raise RenderError(f"Doppler display mode {settings.doppler_mode!r} is not one of {DOPPLER_MODES}")
    if settings.doppler_mode == "FACTOR":
        check_doppler_levels(settings.doppler_levels)
    if settings.parallelism not in PARALLELISM:
        raise RenderError(f"parallelism {settings.parallelism!r} is not one of {PARALLELISM}")
    if settings.integrator not in INTEGRATORS:
        raise RenderError(f"integrator {settings.integrator!r} is not one of {INTEGRATORS}")
    for name in _BOUNCE_LIMITS:
        if int(getattr(settings, name)) < 0:
            raise RenderError(f"the light-path limit {name} must be 0 or more (got {getattr(settings, name)})")
    if not (math.isfinite(settings.motion_tolerance) and settings.motion_tolerance > 0.0):
        raise RenderError(f"the motion tolerance must be a positive number of scene units (got {settings.motion_tolerance:g})")
    for name in _CLAMPS:
        value = float(getattr(settings, name))
        if not (math.isfinite(value) and value >= 0.0):
            raise RenderError(f"the light-path clamp {name} must be 0 (off) or a positive number (got {value:g})")
    try:
        check_camera_optics(scene.camera)
    except ValueError as error:
        raise RenderError(str(error)) from None
    check_finite_inputs(scene)

"""RESTframe's settings on objects and scenes (``Object.restframe``, ``Scene.restframe``).

The property names are public: scripts, pipelines and the README rely on them.
Every value is animatable like any Blender property; the physics they feed is
defined in ``docs/physics.md``.
"""

import math

import bpy
from bpy.props import (
    BoolProperty,
    EnumProperty,
    FloatProperty,
    FloatVectorProperty,
    IntProperty,
    PointerProperty,
)
from bpy.types import PropertyGroup

from . import motion_query
from .core import validation
from .core.lorentz import Boost

# Explicit numbers keep saved files stable as modes are added.
DOPPLER_MODES = (
    ('OFF', "Off", "Geometry only: aberration, light-travel time and the searchlight effect; "
     "colours are not shifted", 0),
    ('FACTOR', "Factor", "Show the Doppler factor D of each pixel as a grey level "
     "(D > 1: approaching, D < 1: receding)", 1),
    ('SPECTRAL', "Spectral", "Shift colours as seen: surfaces and lights as spectra, every wavelength "
     "scaled by D (blue shift when approaching, red shift when receding)", 2),
)

PARALLELISM = (
    ('PROCESSES', "Processes", "Render tiles in worker processes: every core busy (each worker rebuilds "
     "the scene once per render, and they stay running between renders)", 0),
    ('THREADS', "Threads", "Render tiles in threads of Blender's own process: no extra processes, but "
     "Python's global lock keeps them from using every core fully", 1),
)

INTEGRATORS = (
    ('PATH', "Path Tracing", "Full light transport across rest frames: lamps, the world and emissive "
     "surfaces light everything, light bounces between surfaces (Light Paths limits)", 0),
    ('DIRECT', "Direct Light", "Lamps only, with traced mirrors and glass: fast and noise-free "
     "(the renderer before path tracing)", 1),
)

MOTION_MODES = (
    ('CONSTANT', "Constant Velocity", "Move at the constant Velocity (or Lorentz Factor) below; "
     "the location is where the object is at the reference frame", 0),
    ('ANIMATION', "Animation", "Follow the object's keyframed location as its world line (accelerated "
     "motion): the object's own location keys, evaluated over the light-travel time; parents stay static. "
     "A camera observes in its momentary rest frame, a lamp shines from its retarded positions", 1),
)


def speed_of(beta, lorentz_factor: float) -> tuple[float, float, float]:
    """Speed as (beta, gamma, rapidity) from the two user inputs, by the core's own boost.

    With ``lorentz_factor`` > 0 the speed comes from gamma, which stays exact for
    speeds too close to c to write as a float beta.  Values are ``nan`` when the
    input is not physical (speed >= c, gamma < 1, no direction for gamma > 1).
    """
    try:
        boost = Boost.from_velocity(beta, lorentz_factor)
    except ValueError:
        return math.nan, math.nan, math.nan
    return boost.b, boost.gamma, boost.rapidity


class RestframeObjectSettings(PropertyGroup):
    """Constant velocity of an object, light or camera (``Object.restframe``)."""

    velocity: FloatVectorProperty(
        name="Velocity",
        description="Velocity in units of the speed of light c, along the world axes and "
        "measured in the world frame (|velocity| < 1). On a camera it makes a moving observer",
        subtype='VELOCITY',
        size=3,
        default=(0.0, 0.0, 0.0),
        soft_min=-1.0,
        soft_max=1.0,
        step=1,
        precision=6,
    )
    lorentz_factor: FloatProperty(
        name="Lorentz Factor",
        description="0: unused. Above 0 it sets the speed through gamma (at least 1) and Velocity "
        "gives only the direction: the way to enter speeds too close to c for a decimal fraction",
        default=0.0,
        min=0.0,
        soft_max=1e6,
        step=10,
        precision=6,
    )

    motion: EnumProperty(
        name="Motion",
        description="Where the object's world line comes from: a constant velocity, or its animated location",
        items=MOTION_MODES,
        default='CONSTANT',
    )
    angular_velocity: FloatVectorProperty(
        name="Angular Velocity",
        description="Constant spin in radians per second about the object's origin (its pivot), along "
        "the world axes, in the frame of its velocity. The rim must stay slower than light",
        subtype='XYZ',
        size=3,
        default=(0.0, 0.0, 0.0),
        step=10,
        precision=4,
    )

    def _speed(self):
        return speed_of(self.velocity, self.lorentz_factor)

    beta: FloatProperty(
        name="Speed",
        description="Speed in units of c (computed)",
        get=lambda self: self._speed()[0],
        precision=9,
    )
    gamma: FloatProperty(
        name="Gamma",
        description="Lorentz factor 1/sqrt(1 - beta^2) (computed)",
        get=lambda self: self._speed()[1],
        precision=6,
    )
    rapidity: FloatProperty(
        name="Rapidity",
        description="Rapidity atanh(beta): adds up along a line, unlike speeds (computed)",
        get=lambda self: self._speed()[2],
        precision=6,
    )

    proper_time: FloatProperty(
        name="Proper Time",
        description="The object's own clock at the rendered frame, in seconds from the reference time "
        "(its proper time along its world line; computed)",
        get=lambda self: motion_query.clock(self.id_data, bpy.context.scene)[0],
        precision=6,
    )

    @property
    def is_moving(self) -> bool:
        return any(self.velocity) or self.lorentz_factor > 1.0

    @property
    def is_animated(self) -> bool:
        """The world line comes from the animated location (Motion = Animation)."""
        return self.motion == 'ANIMATION'

    @classmethod
    def register(cls):
        bpy.types.Object.restframe = PointerProperty(
            name="RESTframe", description="RESTframe relativistic motion", type=cls)

    @classmethod
    def unregister(cls):
        del bpy.types.Object.restframe


class RestframeSceneSettings(PropertyGroup):
    """Scene-wide clock, quality and display settings (``Scene.restframe``)."""

    light_speed: FloatProperty(
        name="Speed of Light",
        description="The speed of light c in scene units per second: converts the frame clock "
        "into light travel distance. Smaller values make motion across frames visible",
        default=10.0,
        min=1e-9,
        soft_min=0.01,
        soft_max=1000.0,
        precision=4,
    )
    reference_frame: IntProperty(
        name="Reference Frame",
        description="The frame at which every moving object (its assembly pivot) sits where it "
        "was placed; at other frames it has moved by velocity x elapsed time",
        default=1,
    )
    motion_tolerance: FloatProperty(
        name="Motion Tolerance",
        description="How far (scene units) accelerated or spinning bodies may stray from their true "
        "motion: smaller is more exact and slower (more inertial segments)",
        default=1e-3,
        min=1e-9,
        soft_min=1e-6,
        soft_max=1.0,
        precision=6,
        subtype='DISTANCE',
    )
    show_velocity: BoolProperty(
        name="Velocity Arrows",
        description="Draw each moving object's velocity in the 3D viewport, as long as the "
        "distance it covers in one second",
        default=True,
    )
    samples: IntProperty(
        name="Samples",
        description="Camera samples per pixel (stratified), for anti-aliasing and soft effects",
        default=4,
        min=1,
        soft_max=256,
        max=validation.MAX_CAMERA_SAMPLES,
    )
    integrator: EnumProperty(
        name="Integrator",
        description="How light reaches the surfaces seen",
        items=INTEGRATORS,
        default='PATH',
    )
    max_bounces: IntProperty(
        name="Max Bounces",
        description="Path Tracing: total number of bounces of a light path (as Cycles' Total). "
        "Direct Light: maximum number of mirror and glass bounces",
        default=4,
        min=0,
        max=128,
    )
    diffuse_bounces: IntProperty(
        name="Diffuse Bounces",
        description="Path Tracing: maximum number of diffuse reflection bounces, bounded by Max Bounces",
        default=4,
        min=0,
        max=128,
    )
    glossy_bounces: IntProperty(
        name="Glossy Bounces",
        description="Path Tracing: maximum number of glossy (and mirror) reflection bounces, bounded by Max Bounces",
        default=4,
        min=0,
        max=128,
    )
    transmission_bounces: IntProperty(
        name="Transmission Bounces",
        description="Path Tracing: maximum number of transmission (refraction) bounces, bounded by Max Bounces",
        default=12,
        min=0,
        max=128,
    )
    clamp_direct: FloatProperty(
        name="Clamp Direct",
        description="Path Tracing: largest contribution of a sample's light after one bounce "
        "(sum of RGB), against fireflies at the cost of accuracy; 0 = off",
        default=0.0,
        min=0.0,
        soft_max=100.0,
    )
    clamp_indirect: FloatProperty(
        name="Clamp Indirect",
        description="Path Tracing: largest contribution of a sample's light after two or more bounces "
        "(sum of RGB), against fireflies at the cost of accuracy; 0 = off",
        default=10.0,
        min=0.0,
        soft_max=100.0,
    )
    tile_size: IntProperty(
        name="Tile Size",
        description="Pixels per side of the chunks the image fills in with (smaller: quicker Esc and "
                    "progress, larger: less per-chunk overhead)",
        default=256,
        min=8,
        max=4096,
        subtype='PIXEL',
    )
    parallelism: EnumProperty(
        name="Parallelism",
        description="How tiles are rendered on several cores",
        items=PARALLELISM,
        default='PROCESSES',
    )
    doppler_mode: EnumProperty(
        name="Doppler",
        description="How the Doppler shift of received light is shown",
        items=DOPPLER_MODES,
        default='OFF',
    )
    searchlight: BoolProperty(
        name="Searchlight",
        description="Apply the relativistic intensity change (D^4 for radiance, the headlight "
        "effect): approaching objects brighten, receding ones dim",
        default=True,
    )
    spectral_samples: IntProperty(
        name="Wavelengths",
        description="Wavelengths per camera ray between 360 and 830 nm (Spectral mode)",
        default=32,
        min=4,
        soft_max=128,
        max=1024,
    )
    normalize_exposure: BoolProperty(
        name="Normalize Exposure",
        description="Scale the image to the mean brightness the same view has without Doppler "
        "intensity and colour changes, so strongly shifted scenes stay visible",
        default=False,
    )
    doppler_range_auto: BoolProperty(
        name="Auto Range",
        description="Map the frame's own lowest and highest Doppler factor to black and white",
        default=True,
    )
    doppler_range: FloatVectorProperty(
        name="Range",
        description="Doppler factors shown as black and white (Factor display)",
        size=2,
        default=(0.25, 4.0),
        min=0.0,
        soft_max=100.0,
        precision=4,
    )
    rolling_shutter_type: EnumProperty(
        name="Rolling Shutter",
        description="Type of rolling shutter effect matching CMOS-based cameras (as Cycles)",
        items=(
            ('NONE', "None", "No rolling shutter effect used"),
            ('TOP', "Top-Bottom", "Sensor is being scanned from top to bottom"),
        ),
        default='NONE',
    )
    rolling_shutter_duration: FloatProperty(
        name="Rolling Shutter Duration",
        description="The share of the shutter time each scanline is exposed (0: every row at one "
        "instant, rolling down over the shutter time; 1: no rolling)",
        default=0.1,
        min=0.0,
        max=1.0,
    )
    doppler_levels: IntProperty(
        name="Levels",
        description="Quantise the Factor display to this many grey levels, evenly spaced from black to "
        "white (0: continuous; 1 is refused, it would paint every hit the same grey)",
        default=0,
        min=0,
        max=1024,
    )

    @classmethod
    def register(cls):
        bpy.types.Scene.restframe = PointerProperty(
            name="RESTframe", description="RESTframe render settings", type=cls)

    @classmethod
    def unregister(cls):
        del bpy.types.Scene.restframe


class RestframeViewLayerSettings(PropertyGroup):
    """Per view layer render data (``ViewLayer.restframe``)."""

    denoising_store_passes: BoolProperty(
        name="Denoising Data",
        description="Store the Denoising Albedo and Denoising Normal passes (sample averages of the "
        "first surface seen), for the compositor's Denoise node as with Cycles",
        default=False,
    )

    @classmethod
    def register(cls):
        bpy.types.ViewLayer.restframe = PointerProperty(
            name="RESTframe", description="RESTframe view layer settings", type=cls)

    @classmethod
    def unregister(cls):
        del bpy.types.ViewLayer.restframe


classes = (
    RestframeObjectSettings,
    RestframeSceneSettings,
    RestframeViewLayerSettings,
)


register, unregister = bpy.utils.register_classes_factory(classes)

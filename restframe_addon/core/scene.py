"""What the tracer needs to know about a scene, independent of Blender.

The Blender layer (``restframe_addon.export``) fills these from the evaluated
depsgraph; tests and scripts can build them directly.  All positions are Blender
world coordinates at the rendered frame, i.e. the shape each object has *in its
own rest frame* (see ``docs/physics.md#rest-shapes``: the artist models rest shapes).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from .world import from_texel_state, texel_state

if TYPE_CHECKING:
    from .motion import Trajectory


@dataclass(frozen=True)
class Velocity:
    """A constant velocity in units of c, world axes, measured in the world frame S.

    ``lorentz_factor`` > 0 sets the speed through gamma and uses ``beta`` only
    for its direction: the way to enter speeds too close to c for float input.
    """

    beta: tuple[float, float, float] = (0.0, 0.0, 0.0)
    lorentz_factor: float = 0.0

    @property
    def key(self) -> tuple:
        """Objects whose velocities have equal keys share one rest frame."""
        return (tuple(float(c) for c in self.beta), float(self.lorentz_factor))

    @property
    def is_zero(self) -> bool:
        return self.lorentz_factor in (0.0, 1.0) and not any(self.beta)


REST = Velocity()

# Ray types: the bits of ``Mesh.visibility`` (Blender's Object > Visibility > Ray Visibility).  A
# surface a ray type does not see is passed through by those rays, as if absent for them.
RAY_CAMERA = 1  # camera rays (and their continuations through cut-outs)
RAY_DIFFUSE = 2  # diffuse bounces (the path tracer's)
RAY_GLOSSY = 4  # mirror and glossy reflections
RAY_TRANSMISSION = 8  # refraction through glass
RAY_SHADOW = 16  # shadow rays toward lights
RAY_ALL = RAY_CAMERA | RAY_DIFFUSE | RAY_GLOSSY | RAY_TRANSMISSION | RAY_SHADOW


class _PicklesTexels:
    """A Material's or WorldTexture's pickling: images held as a world.texel_image pickle as their
    lookup layout, so that a worker process gets one copy of each, not a second."""

    def __getstate__(self):
        return {name: texel_state(value) if isinstance(value, np.ndarray) else value
                for name, value in self.__dict__.items()}

    def __setstate__(self, state):
        self.__dict__.update({name: from_texel_state(value) for name, value in state.items()})


@dataclass
class Material(_PicklesTexels):
    """A Principled-BSDF-like surface, evaluated in the surface's rest frame."""

    name: str = "Default"
    base_color: tuple[float, float, float] = (0.8, 0.8, 0.8)
    metallic: float = 0.0
    roughness: float = 0.5
    ior: float = 1.5
    specular_ior_level: float = 0.5  # Principled "Specular IOR Level": 0.5 = Fresnel of the IOR, 0 = none
    transmission: float = 0.0
    # the Principled coat (Path Tracing): a clear dielectric GGX layer over everything else (Cycles'
    # Coat Weight, Roughness and IOR; untinted)
    coat_weight: float = 0.0
    coat_roughness: float = 0.03
    coat_ior: float = 1.5
    emission: tuple[float, float, float] = (0.0, 0.0, 0.0)  # colour * strength, rest-frame radiance
    # animated emission: (times in seconds of the body's own clock, multipliers), evaluated at the
    # clock reading of each seen event (optical clocks); linear between keys, constant beyond
    emission_curve: tuple[np.ndarray, np.ndarray] | None = None
    base_color_texture: np.ndarray | None = None  # (H, W, 3) scene-linear, row 0 = bottom (Blender order)
    base_color_interpolation: str = "Linear"  # "Linear" (bilinear) or "Closest" (nearest pixel), as Blender's
    # Principled Alpha (cut-outs): the chance a ray stops at the surface; 1 = opaque
    alpha: float = 1.0
    alpha_texture: np.ndarray | None = None  # (H, W, 1) alpha from an image (times ``alpha``), row 0 = bottom
    # a tangent-space normal map (Normal Map node): the image's colour (H, W, 3), Non-Color, row 0 = bottom
    normal_texture: np.ndarray | None = None
    normal_strength: float = 1.0
    holdout: bool = False  # a Holdout shader: a hole in the image, as a holdout object


@dataclass
class Mesh:
    """One evaluated object (or instance) as triangles in world coordinates.

    ``pivot`` is the world position of the object's assembly pivot (the topmost
    parent with the same velocity): the body contracts about it, and its world
    line passes through ``(tau=0, pivot)``.
    """

    name: str
    vertices: np.ndarray  # (N, 3) float64
    triangles: np.ndarray  # (M, 3) int
    velocity: Velocity = REST
    pivot: tuple[float, float, float] = (0.0, 0.0, 0.0)
    material_indices: np.ndarray | None = None  # (M,) index into Scene.materials; None = all 0
    corner_normals: np.ndarray | None = None  # (M, 3, 3) smooth-shading normals; None = flat
    corner_uvs: np.ndarray | None = None  # (M, 3, 2)
    object_index: int = 0  # Blender's pass_index, for the IndexOB pass
    trajectory: "Trajectory | None" = None  # animated pivot world line (replaces velocity); see core.motion
    angular_velocity: tuple[float, float, float] | None = None  # rad/s about the pivot, world axes, in the velocity frame
    visibility: int = RAY_ALL  # the ray types that see it (RAY_* bits)
    holdout: bool = False  # seen by the camera as a hole in the image (colour and alpha 0), still occluding


@dataclass
class Light:
    """A Blender light, at rest in its own frame.

    ``power`` is Blender's: watts for point, spot and area lights, W/m^2
    ("strength") for sun lights.  ``matrix`` holds the light's world rotation
    (columns = local X, Y, Z axes; it emits along local -Z).
    """

    name: str
    kind: str  # "POINT", "SPOT", "SUN", "AREA"
    position: tuple[float, float, float]
    matrix: np.ndarray = field(default_factory=lambda: np.eye(3))
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    power: float = 1000.0
    radius: float = 0.0  # point/spot soft radius
    spot_size: float = np.pi / 4  # full cone angle
    spot_blend: float = 0.15
    sun_angle: float = 0.0  # angular diameter of the sun disc
    area_shape: str = "SQUARE"  # SQUARE, RECTANGLE, DISK, ELLIPSE
    area_size: tuple[float, float] = (1.0, 1.0)
    temperature: float = 0.0  # K; > 0: a black body at this temperature, tinted by ``color``
    velocity: Velocity = REST
    pivot: tuple[float, float, float] | None = None  # None = its own position
    trajectory: "Trajectory | None" = None  # an animated lamp's world line (replaces velocity and position)
    # keyed output, read on the lamp's own clock at emission: (seconds, watts) and (seconds, (N, 3) colours);
    # linear between samples, constant beyond; None = ``power`` / ``color`` at every time
    power_curve: tuple[np.ndarray, np.ndarray] | None = None
    color_curve: tuple[np.ndarray, np.ndarray] | None = None
    # Path Tracing, as Cycles: the ray types that see a lamp with an extent (its Ray Visibility;
    # Blender makes new lamps invisible to the camera), and whether bounce rays find it at all,
    # weighed against its samples (Multiple Importance)
    visibility: int = RAY_ALL & ~RAY_CAMERA
    use_mis: bool = True

    @property
    def is_keyed(self) -> bool:
        """Whether its strength or colour changes with its clock."""
        return self.power_curve is not None or self.color_curve is not None

    @property
    def pivot_or_position(self):
        return self.position if self.pivot is None else self.pivot


@dataclass
class Camera:
    """The observer.  ``matrix`` is the camera's world transform without scale.

    ``frame`` holds Blender's ``Camera.view_frame`` corners in camera space,
    ordered top-right, bottom-right, bottom-left, top-left.  For a moving
    camera (``velocity`` not zero) these describe its optics in its own rest frame, lens included.
    """

    matrix: np.ndarray  # (4, 4)
    kind: str = "PERSP"  # PERSP, ORTHO, PANO
    frame: np.ndarray = field(
        default_factory=lambda: np.array(
            [[0.5, 0.5, -1.0], [0.5, -0.5, -1.0], [-0.5, -0.5, -1.0], [-0.5, 0.5, -1.0]]
        )
    )
    clip_start: float = 0.1
    clip_end: float = 1000.0
    panorama_type: str = "EQUIRECTANGULAR"  # EQUIRECTANGULAR, FISHEYE_EQUIDISTANT, FISHEYE_EQUISOLID
    latitude_range: tuple[float, float] = (-np.pi / 2, np.pi / 2)
    longitude_range: tuple[float, float] = (-np.pi, np.pi)
    fisheye_fov: float = np.pi
    fisheye_lens: float = 10.5  # mm, equisolid
    sensor_size: tuple[float, float] = (36.0, 24.0)  # mm (width, height) as fitted to the image
    velocity: Velocity = REST
    name: str = "Camera"
    # an animated (accelerating) observer's world line: replaces velocity; the image forms in its momentary
    # rest frame at the observation event, shutter samples at their own proper times on it (core.observer)
    trajectory: "Trajectory | None" = None
    # depth of field (Cycles' thin lens, in the camera's rest frame; core.lens): radius 0 = a pinhole
    aperture_radius: float = 0.0  # scene units (the polygon's corners lie on this circle)
    focus_distance: float = 10.0  # scene units along the view axis (the plane of focus)
    aperture_blades: int = 0  # < 3: a round aperture
    aperture_rotation: float = 0.0  # radians
    aperture_ratio: float = 1.0  # anamorphic: the aperture is narrower across by this factor
    # motion blur (core.lens): each sample observes at its own time of the camera's own clock
    shutter_interval: tuple[float, float] | None = None  # seconds from the frame's observation event; None = an instant
    shutter_curve: np.ndarray | None = None  # the shutter's openness at evenly spaced times of the interval; None = flat
    rolling_shutter_type: str = "NONE"  # NONE, TOP (rows read out from the top down over the interval)
    rolling_shutter_duration: float = 0.1  # the share of the interval each row is exposed (Cycles)

    @property
    def has_depth_of_field(self) -> bool:
        return self.aperture_radius > 0.0

    @property
    def has_motion_blur(self) -> bool:
        return self.shutter_interval is not None


@dataclass
class WorldTexture(_PicklesTexels):
    """An Environment Texture on the world's Background (equirectangular), at rest in the world frame.

    ``image`` (H, W, 3 or 4) scene-linear radiance, row 0 = bottom (Blender order); ``rotation``:
    the Euler XYZ rotation of a Mapping node before it (``vector_type`` as the node's), see
    :mod:`.world`.  Lights the scene with the Path Tracing integrator (Direct Light shows
    ``Scene.world_color`` behind the scene, as before).
    """

    image: np.ndarray
    strength: float = 1.0
    rotation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    vector_type: str = "POINT"
    interpolation: str = "Linear"
    name: str = "World"


@dataclass
class Scene:
    """Everything one rendered frame needs.

    ``tau_obs`` = c * t_obs: the world time (as a length) of the observation
    event; ``light_speed`` (scene units per second) only converts it back.
    """

    camera: Camera
    meshes: list[Mesh] = field(default_factory=list)
    materials: list[Material] = field(default_factory=lambda: [Material()])
    lights: list[Light] = field(default_factory=list)
    world_color: tuple[float, float, float] = (0.05, 0.05, 0.05)  # the Background colour x strength
    world_texture: WorldTexture | None = None  # an environment image instead of the plain colour
    tau_obs: float = 0.0
    light_speed: float = 299792458.0


@dataclass
class RenderSettings:
    """How to render: resolution, region, quality and display knobs."""

    resolution: tuple[int, int] = (64, 64)  # (x, y) pixels of the full image
    region: tuple[int, int, int, int] | None = None  # (x0, y0, x1, y1) pixels, x1/y1 exclusive
    samples: int = 1  # stratified camera samples per pixel
    # DIRECT: lamps light surfaces, mirrors and glass are traced (the core's default, unchanged);
    # PATH: full light transport, world and emissive surfaces lighting others (core/integrator.py)
    integrator: str = "DIRECT"
    max_bounces: int = 4  # DIRECT: mirror / glass recursion depth; PATH: total scattering events (Cycles' Total)
    diffuse_bounces: int = 4  # PATH: limits by the kind of scattering (Cycles' Light Paths)
    glossy_bounces: int = 4
    transmission_bounces: int = 12
    clamp_direct: float = 0.0  # PATH: largest RGB sum of one sample's light after one scattering (0 = off)
    clamp_indirect: float = 0.0  # PATH: the same after two or more (0 = off)
    doppler_mode: str = "OFF"  # OFF (geometry only), FACTOR (D as grey), SPECTRAL (colour shift)
    searchlight: bool = True  # apply the D^4 intensity transforms (headlamp effect)
    spectral_samples: int = 32  # SPECTRAL: wavelengths per camera ray over 360-830 nm
    motion_tolerance: float = 1e-3  # scene units: how far accelerated/rotating bodies may stray from their true motion
    normalize_exposure: bool = False  # scale the image to the mean brightness it would have without Doppler intensity changes
    film_transparent: bool = False
    tile_size: int = 256
    threads: int = 0  # 0 = all cores
    parallelism: str = "THREADS"  # THREADS, or PROCESSES: tiles in worker processes (core.workers), free of the GIL
    doppler_range: tuple[float, float] | None = None  # FACTOR display: None = the frame's own range
    doppler_levels: int = 0  # FACTOR display: quantise to N >= 2 grey levels (0 = continuous; 1 is refused)
    passes: tuple[str, ...] | None = None  # passes to fill besides Combined (passes.EXTRA_PASSES names); None = passes.DEFAULT_PASSES


def render_workers(threads: int) -> int:
    """The render threads (or worker processes) a ``RenderSettings.threads`` asks for: 0 = one per core."""
    return threads if threads > 0 else (os.cpu_count() or 1)

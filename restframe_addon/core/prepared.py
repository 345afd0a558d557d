"""A scene prepared for rendering, once: rest frames with their embree geometry, lights,
shader, the camera's observation event and rays, the pre-passes over the whole image
(the Doppler-factor display range, the exposure) and the passes to fill.

A :class:`PreparedScene` is read-only: any number of threads render tiles of it at once
(:func:`~.render.render_tile`).  Embree scenes cannot be pickled, so a prepared scene
pickles as its plain :class:`~.scene.Scene` and settings plus the values its pre-passes
measured; unpickling rebuilds the frames and geometry without measuring again, so
another process renders the very same pixels.  A worker process builds from the scene and
settings alone (:func:`build_unmeasured`, while this process prepares the same) and takes
the measured values when they come (:func:`measured_as`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from . import lens, observer
from .camera import CameraRays
from .colour import RGBColour, SpectralColour
from .frames import FrameSet, MotionSettings, build_frames, shift_into_frame
from .integrator import PathTracer, scene_world
from .passes import DEFAULT_PASSES, EXTRA_PASSES, ray_doppler
from .persistent import GeometryCache
from .sampling import Samples
from .scene import RAY_CAMERA, Camera, RenderSettings, Scene, render_workers
from .shading import MaterialTable, PreparedLight, Shader, prepare_lights
from .tracer import TraceCache, misses_everything
from .validation import RenderError, check_render

_SMALLEST_SPLIT_TILE = 8  # pixels: tiles are not split below this (the Tile Size setting's own minimum)
_EXPOSURE_PREVIEW = 48  # pixels on the longer side of the exposure-normalisation preview
_LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


@dataclass(frozen=True, eq=False)
class PreparedScene:
    """Everything a tile needs, built by :func:`prepare` (not by hand)."""

    scene: Scene
    settings: RenderSettings
    frames: FrameSet
    lights: tuple[PreparedLight, ...]
    materials: MaterialTable
    colour: RGBColour | SpectralColour
    shader: Shader
    path_tracer: PathTracer | None  # the Path Tracing integrator (None: Direct Light, the shader alone)
    camera_tau: float  # camera-frame time of the observation event: primary rays start then (motion blur: about it)
    camera_rays: CameraRays
    passes: tuple[str, ...]  # the passes to fill besides Combined
    doppler_range: tuple[float, float] | None  # FACTOR display: D shown as black .. white
    exposure: float  # multiplies Combined (1 unless the exposure is normalised)

    def __reduce__(self):
        return _rebuild, (self.scene, self.settings, self.measurements)

    @property
    def measurements(self) -> tuple[tuple[float, float] | None, float]:
        """What the pre-passes measured (Doppler range, exposure): all that a build from the
        scene and settings lacks."""
        return self.doppler_range, self.exposure

    @property
    def warnings(self) -> tuple[str, ...]:
        return self.frames.warnings

    # ------------------------------------------------------------------ layout
    @property
    def region(self) -> tuple[int, int, int, int]:
        """(x0, y0, x1, y1) of the pixels to render (x1, y1 exclusive): the render region or the whole image."""
        width, height = self.settings.resolution
        return self.settings.region or (0, 0, width, height)

    @property
    def full_image(self) -> tuple[int, int, int, int]:
        width, height = self.settings.resolution
        return (0, 0, width, height)

    def tiles(self, area=None) -> list[tuple[int, int, int, int]]:
        """The tiles of ``area`` (default: the region to render), row by row from the bottom:
        squares of the tile size, their height then their width halved in turn (down to 8
        pixels) while there are fewer of them than the render's workers, since each worker
        renders whole tiles: a 255x255 image in one 256-pixel tile left all cores but one idle.
        One side at a time, so a split gives the workers no more tiles than they need: each
        costs a render_tile call's fixed time (a 32x32 Cornell box at 4 samples: 4 squares cost
        two workers two calls each, 2 bands one).  The pixels are the same for any tiling."""
        x0, y0, x1, y1 = area or self.region
        width = height = max(int(self.settings.tile_size), 1)
        workers = render_workers(self.settings.threads)
        while math.ceil((x1 - x0) / width) * math.ceil((y1 - y0) / height) < workers:
            if height >= width and height >= 2 * _SMALLEST_SPLIT_TILE:
                height = (height + 1) // 2
            elif width >= 2 * _SMALLEST_SPLIT_TILE:
                width = (width + 1) // 2
            else:
                break
        return [
            (tx, ty, min(tx + width, x1), min(ty + height, y1))
            for ty in range(y0, y1, height)
            for tx in range(x0, x1, width)
        ]

    def pixel_grid(self, rect):
        """Pixel coordinates and flat image indices of a rectangle of pixels, in row-major order (the
        coordinates as floats: every batch's jitter adds them, 5x faster than from integers)."""
        x0, y0, x1, y1 = rect
        xs = np.tile(np.arange(x0, x1, dtype=np.float64), y1 - y0)
        ys = np.repeat(np.arange(y0, y1, dtype=np.float64), x1 - x0)
        return xs, ys, self.pixel_ids(rect)

    def pixel_ids(self, rect):
        """Flat image indices of a rectangle of pixels, in row-major order (row starts plus columns: one pass)."""
        x0, y0, x1, y1 = rect
        return np.add.outer(np.arange(y0, y1, dtype=np.int64) * self.settings.resolution[0],
                            np.arange(x0, x1, dtype=np.int64)).ravel()

    # ------------------------------------------------------------------ rays
    @property
    def samples_vary(self) -> bool:
        """Whether a pixel's camera samples differ by more than their place in the pixel (a lens, a shutter)."""
        return self.camera_rays.has_lens or self.scene.camera.has_motion_blur

    def rays(self, px, py, grid: bool = False, keys=None):
        """Camera rays (tau, x, d, s_lo, s_hi) through image points (px, py) (pixels; ``grid``:
        every px with every py); rays outside a panorama get s_hi = -inf (they hit nothing).
        With ``keys`` = (pixel ids, sample numbers, samples per pixel) they are camera samples:
        through the lens, and with motion blur each at its own time of the camera's clock."""
        return self.sample_rays(px, py, grid, keys)[0]

    def sample_rays(self, px, py, grid: bool = False, keys=None):
        """:meth:`rays` and the Doppler factor (n,) of the camera frame as each ray's observer
        sees it, None where that is the camera frame itself (all but the shutter samples of an
        accelerating camera, each observing in its momentary rest frame: core.observer)."""
        origins, d, s_lo, s_hi, valid = self.camera_rays(px, py, grid, keys)
        camera = self.scene.camera
        doppler = None
        if keys is not None and camera.has_motion_blur:
            proper = self.scene.light_speed * lens.shutter_times(camera, *keys, self.settings.resolution)
            if camera.trajectory is None:
                # an inertial camera's rest-frame time runs with its own clock (tau = c t)
                tau = self.camera_tau + proper
            else:
                tau, origins, d, w = observer.shutter_samples(
                    camera, self.frames.frames[self.frames.camera].boost, self.scene.tau_obs,
                    self.camera_rays.position, proper, origins, d)
                s_lo, s_hi, doppler = s_lo * w, s_hi * w, 1.0 / w
        else:
            tau = np.broadcast_to(self.camera_tau, (len(d),))  # read-only views: every ray starts at this time
        return (tau, origins, d, s_lo, s_hi if valid.all() else np.where(valid, s_hi, -np.inf)), doppler

    def misses_everything(self, rect, cache: TraceCache | None = None) -> bool:
        """Whether every camera ray through the pixels ``rect`` provably misses every surface
        while a missing ray's colour and passes do not depend on its direction (a pinhole camera
        at rest with the world, Direct Light), so that a tile need not make or trace its rays
        (:meth:`missing_rays` stand in for them)."""
        return self.each_misses_everything([rect], cache)[0]

    def each_misses_everything(self, rects, cache: TraceCache | None = None) -> list[bool]:
        """:meth:`misses_everything` of each rectangle of ``rects``, all at once (a render's tiles)."""
        frames = self.frames
        if self.samples_vary or self.path_tracer is not None or not frames.map(frames.camera, frames.world).is_identity:
            return [False] * len(rects)
        return misses_everything(frames, frames.camera, (float(self.camera_tau), self.camera_rays.position),
                                 self.camera_rays.cones(rects), cache)

    def missing_rays(self, n: int):
        """``n`` camera rays that :meth:`misses_everything` found to miss: their shared
        observation event, the view axis for a direction (what is drawn for a miss, and its
        passes, do not depend on it) and the clip range of that axis (read-only views)."""
        camera = self.scene.camera
        axis = -self.camera_rays.rotation[:, 2]
        return (np.broadcast_to(self.camera_tau, (n,)), np.broadcast_to(self.camera_rays.position, (n, 3)),
                np.broadcast_to(axis / np.linalg.norm(axis), (n, 3)), np.broadcast_to(camera.clip_start, (n,)),
                np.broadcast_to(camera.clip_end, (n,)))

    def centre_rays(self, rect):
        """The pixel-centre camera rays of a rectangle of pixels, in row-major order."""
        x0, y0, x1, y1 = rect
        return self.rays(np.arange(x0, x1) + 0.5, np.arange(y0, y1) + 0.5, grid=True)


def prepare(scene: Scene, settings: RenderSettings, should_stop: Callable[[], bool] = lambda: False,
            geometry_cache: GeometryCache | None = None) -> PreparedScene:
    """Check, build and measure a scene for rendering.

    Raises RenderError (naming the object) for scenes and settings that cannot be rendered.
    Once ``should_stop()`` is true the build stops early; the result is then incomplete
    and must not be rendered.  ``geometry_cache``: the rest-frame geometry of earlier frames,
    reused where unchanged (:mod:`.persistent`; the same pixels as a fresh build).
    """
    settings = dataclasses.replace(settings)  # its own copy: a caller changing theirs later changes no render
    return _measured(_build(scene, settings, should_stop, geometry_cache), should_stop)


def prepare_view(prepared: PreparedScene, camera: Camera, should_stop: Callable[[], bool] = lambda: False
                 ) -> PreparedScene:
    """The prepared scene seen by another camera (a stereo eye, another view): with the same
    velocity its rest frames, lights and shader are shared (built once), and only the camera's
    observation event, rays and the pre-passes are its own; else (another velocity, or an eye of
    an accelerating assembly, in a momentary rest frame of its own) prepared afresh."""
    scene = dataclasses.replace(prepared.scene, camera=camera)
    tau_obs = scene.tau_obs
    if observer.camera_velocity(camera, tau_obs) != observer.camera_velocity(prepared.scene.camera, tau_obs):
        return prepare(scene, prepared.settings, should_stop)
    check_render(scene, prepared.settings, EXTRA_PASSES)
    camera_tau, camera_rays = _camera(scene, prepared.settings, prepared.frames)
    view = dataclasses.replace(prepared, scene=scene, camera_tau=camera_tau, camera_rays=camera_rays,
                               doppler_range=prepared.settings.doppler_range, exposure=1.0)
    return _measured(view, should_stop)


def _measured(prepared: PreparedScene, should_stop) -> PreparedScene:
    """The prepared scene with its pre-passes' values (Doppler range, exposure) measured."""
    settings = prepared.settings
    doppler_range = settings.doppler_range
    if settings.doppler_mode == "FACTOR" and doppler_range is None:
        doppler_range = _measure_doppler_range(prepared, should_stop)
    exposure = 1.0
    if settings.normalize_exposure and settings.doppler_mode != "FACTOR":
        exposure = _measure_exposure(prepared, should_stop)
    return measured_as(prepared, (doppler_range, exposure))


def build_unmeasured(scene: Scene, settings: RenderSettings, geometry_cache: GeometryCache | None = None
                     ) -> PreparedScene:
    """The scene built for rendering as :func:`prepare` builds it, but not measured: for a
    worker process, which renders once :func:`measured_as` gives it the values the preparing
    process measured.  Nor checked (:func:`~.validation.check_render`): the preparing process
    checks it meanwhile, and a scene it refuses is never rendered (the check was a fifth of a
    worker's build of moving_sphere, which an F12 waits for).  ``geometry_cache``: the
    worker's own, across the frames it renders."""
    return _build(scene, settings, geometry_cache=geometry_cache, checked=True)


def measured_as(built: PreparedScene, measurements) -> PreparedScene:
    """A built scene with the pre-passes' values ``measurements`` (:attr:`PreparedScene.measurements`)."""
    doppler_range, exposure = measurements
    return dataclasses.replace(built, doppler_range=doppler_range, exposure=exposure)


def _rebuild(scene: Scene, settings: RenderSettings, measurements) -> PreparedScene:
    """A prepared scene from its pickled parts: built again, the pre-passes' values kept."""
    return measured_as(_build(scene, settings), measurements)


def _build(scene: Scene, settings: RenderSettings, should_stop: Callable[[], bool] = lambda: False,
           geometry_cache: GeometryCache | None = None, checked: bool = False) -> PreparedScene:
    """Everything but the pre-passes (Doppler range as given, exposure 1); ``checked``: the scene
    and settings are known to pass :func:`~.validation.check_render`."""
    if not checked:
        check_render(scene, settings, EXTRA_PASSES)
    try:
        frames = build_frames(scene, should_stop, MotionSettings(settings.motion_tolerance), geometry_cache)
        lights = tuple(prepare_lights(scene, frames))
    except ValueError as error:
        raise RenderError(str(error)) from error
    materials = MaterialTable(scene.materials, scene.light_speed)
    if settings.doppler_mode == "SPECTRAL":
        colour = SpectralColour(materials, lights, scene.world_color, settings.spectral_samples)
    else:
        colour = RGBColour(materials, lights, scene.world_color)
    shader = Shader(frames, materials, lights, colour, settings.max_bounces, settings.searchlight,
                    layered=settings.integrator == "PATH")
    path_tracer = None
    if settings.integrator == "PATH":
        try:
            path_tracer = PathTracer(shader, scene_world(scene), settings)
        except ValueError as error:
            raise RenderError(str(error)) from error
    camera_tau, camera_rays = _camera(scene, settings, frames)
    return PreparedScene(
        scene=scene, settings=settings, frames=frames, lights=lights, materials=materials, colour=colour,
        shader=shader, path_tracer=path_tracer,
        camera_tau=camera_tau, camera_rays=camera_rays,
        passes=tuple(DEFAULT_PASSES) if settings.passes is None else tuple(settings.passes),
        doppler_range=settings.doppler_range, exposure=1.0)


def _camera(scene: Scene, settings: RenderSettings, frames: FrameSet) -> tuple[float, CameraRays]:
    """The camera-frame time of the observation event (the camera's position at world time
    tau_obs) and the camera's rays."""
    camera_boost = frames.frames[frames.camera].boost
    position = np.asarray(scene.camera.matrix, dtype=np.float64)[:3, 3]
    if scene.camera.trajectory is None:
        world_event = position + camera_boost.b * camera_boost.n * scene.tau_obs
        tau, _ = camera_boost.events(np.array(scene.tau_obs), world_event)
        offset = shift_into_frame(camera_boost, position)
    else:  # on its world line, in its momentary rest frame
        tau, place = observer.observation_event(scene.camera, camera_boost, scene.tau_obs)
        offset = place - position
    return float(tau), CameraRays(scene.camera, settings.resolution, offset)


def _measure_doppler_range(prepared: PreparedScene, should_stop) -> tuple[float, float]:
    """Range of D over the whole image's pixel-centre rays (for the normalised FACTOR
    display; the whole image, so that regions rendered apart agree with a full render)."""
    frames = prepared.frames
    cache = TraceCache()
    lo, hi = math.inf, -math.inf
    for rect in prepared.tiles(prepared.full_image):
        if should_stop():
            break
        rays = prepared.centre_rays(rect)
        pixel = prepared.pixel_ids(rect)
        hits = prepared.shader.trace(frames.camera, *rays, RAY_CAMERA, pixel, np.zeros_like(pixel), 0, cache,
                                     for_passes=True)
        doppler = ray_doppler(frames, hits)[hits.frame >= 0]
        if len(doppler):
            lo, hi = min(lo, doppler.min()), max(hi, doppler.max())
    return (lo, hi) if lo <= hi else (0.0, 1.0)


def _measure_exposure(prepared: PreparedScene, should_stop) -> float:
    """Exposure that gives the image the mean luminance of the same view without Doppler
    intensity or colour changes (the paper's dynamic-range re-normalisation, section 4.2).

    Both are estimated on a small preview of the whole image (one ray per preview pixel),
    so that regions rendered apart agree with a full render.
    """
    x0, y0, x1, y1 = prepared.full_image
    scale = _EXPOSURE_PREVIEW / max(x1 - x0, y1 - y0, 1)
    nx, ny = max(int((x1 - x0) * scale), 1), max(int((y1 - y0) * scale), 1)
    gx, gy = np.meshgrid(x0 + (np.arange(nx) + 0.5) * (x1 - x0) / nx, y0 + (np.arange(ny) + 0.5) * (y1 - y0) / ny)
    px, py = gx.ravel(), gy.ravel()
    pixel = np.arange(len(px), dtype=np.int64)
    materials, lights = prepared.materials, prepared.lights
    plain = Shader(prepared.frames, materials, lights, RGBColour(materials, lights, prepared.scene.world_color),
                   prepared.settings.max_bounces, searchlight=False, layered=prepared.shader.layered)
    tracers = (prepared.shader, plain)
    if prepared.path_tracer is not None:  # the same integrator, with and without the Doppler changes
        tracers = (prepared.path_tracer, PathTracer(plain, prepared.path_tracer.world, prepared.settings))
    cache = TraceCache()
    means = []
    for tracer in tracers:
        if should_stop():
            return 1.0
        colour = tracer.colour
        lam = colour.camera_wavelengths(pixel, pixel * 0)
        rays = prepared.rays(px, py)
        if isinstance(tracer, PathTracer):
            values, _ = tracer.radiance(prepared.frames.camera, *rays, pixel, pixel * 0, lam, cache=cache)
        else:
            values, _ = tracer.radiance(prepared.frames.camera, *rays, 0, Samples(pixel, pixel * 0), lam, cache=cache)
        means.append(float(np.mean(colour.to_rgb(values, lam) @ _LUMINANCE)))
    rendered, reference = means
    return reference / rendered if rendered > 0 and reference > 0 else 1.0

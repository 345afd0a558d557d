"""Render a :class:`~.scene.Scene`: tiles of camera rays through every rest frame, in threads.

The observer is the camera's rest frame (S itself for a camera at rest).  Its
observation event is the camera's position at world time ``tau_obs``; every
primary ray starts there (orthographic rays start on the image plane, all at the
same camera-frame time; with depth of field each sample starts at its aperture point,
with motion blur at its own time of the camera's clock: docs/physics-camera.md).  The
passes other than Combined are those of the pixel-centre ray at the observation event.  Tiles are independent and every random number is keyed
by (pixel, sample), so any split into tiles, regions or machines gives the same
image.  Memory is bounded by the tile size (and samples are batched).

Pass arrays are float32 ``(h, w, C)`` with row 0 at the bottom (Blender's order).
"""

from __future__ import annotations

import math
import os
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np

from . import blas, lens, rows, sampling
from .camera import CameraRays
from .frames import FrameSet, MotionSettings, build_frames, shift_into_frame
from .colour import RGBColour, SpectralColour
from .scene import RenderSettings, Scene
from .shading import MaterialTable, Shader, prepare_lights
from .tracer import frames_hit, trace_nearest

PASSES = {"Doppler": 1, "Emission Time": 1, "Object Time": 1}  # RESTframe's own (Depth, Normal, IndexOB are Blender's)
EXTRA_PASSES = {**PASSES, "Depth": 1, "Normal": 3, "IndexOB": 1}  # what RenderSettings.passes may ask for
ALL_PASSES = {"Combined": 4, **EXTRA_PASSES}
DOPPLER_MODES = ("OFF", "FACTOR", "SPECTRAL")
_MAX_VALUES = 3 << 16  # ray colour values per batch: bounds memory whatever the tile size, samples and wavelengths
_EXPOSURE_PREVIEW = 48  # pixels on the longer side of the exposure-normalisation preview


class RenderError(ValueError):
    """The scene or settings cannot be rendered; the message says what to change."""


@dataclass
class Tile:
    x0: int
    y0: int
    x1: int
    y1: int
    passes: dict


class Renderer:
    """A scene prepared for rendering: frames built, lights placed, camera event known."""

    def __init__(self, scene: Scene, settings: RenderSettings, should_stop: Callable[[], bool] = lambda: False):
        _validate(scene, settings)
        self.scene = scene
        self.settings = settings
        self.should_stop = should_stop
        try:
            self.frames: FrameSet = build_frames(scene, should_stop, MotionSettings(settings.motion_tolerance))
            lights = prepare_lights(scene, self.frames)
        except ValueError as error:
            raise RenderError(str(error)) from error
        self.warnings = self.frames.warnings
        self.materials = MaterialTable(scene.materials, scene.light_speed)
        if settings.doppler_mode == "SPECTRAL":
            colour = SpectralColour(self.materials, lights, scene.world_color, settings.spectral_samples)
        else:
            colour = RGBColour(self.materials, lights, scene.world_color)
        self.colour = colour
        self.shader = Shader(self.frames, self.materials, lights, colour, settings.max_bounces, settings.searchlight)
        camera_boost = self.frames.frames[self.frames.camera].boost
        position = np.asarray(scene.camera.matrix, dtype=np.float64)[:3, 3]
        world_event = position + camera_boost.b * camera_boost.n * scene.tau_obs
        tau, _ = camera_boost.events(np.array(scene.tau_obs), world_event)
        self.camera_tau = float(tau)
        self.camera_rays = CameraRays(scene.camera, settings.resolution, shift_into_frame(camera_boost, position))
        self.camera_samples_vary = self.camera_rays.has_lens or scene.camera.has_motion_blur
        self.passes = tuple(EXTRA_PASSES) if settings.passes is None else tuple(settings.passes)
        self.doppler_range = settings.doppler_range
        if settings.doppler_mode == "FACTOR" and self.doppler_range is None:
            self.doppler_range = self._measure_doppler_range(should_stop)
        self.exposure = 1.0
        if settings.normalize_exposure and settings.doppler_mode != "FACTOR":
            self.exposure = self._measure_exposure(scene, settings, lights, should_stop)

    # ------------------------------------------------------------------ layout
    @property
    def region(self) -> tuple[int, int, int, int]:
        width, height = self.settings.resolution
        return self.settings.region or (0, 0, width, height)

    @property
    def full_image(self) -> tuple[int, int, int, int]:
        width, height = self.settings.resolution
        return (0, 0, width, height)

    def tiles(self, area=None) -> list[tuple[int, int, int, int]]:
        """The tiles of ``area`` (default: the region to render)."""
        x0, y0, x1, y1 = area or self.region
        size = max(int(self.settings.tile_size), 1)
        return [
            (tx, ty, min(tx + size, x1), min(ty + size, y1))
            for ty in range(y0, y1, size)
            for tx in range(x0, x1, size)
        ]

    # ------------------------------------------------------------------ rays
    def _camera_rays(self, px, py, grid: bool = False, keys=None):
        """Camera rays at image positions; with ``keys`` = (pixel ids, sample numbers, samples per
        pixel) they are camera samples: through the lens, and at their own shutter times with
        motion blur."""
        origins, d, s_lo, s_hi, valid = self.camera_rays(px, py, grid, keys)
        camera = self.scene.camera
        if keys is not None and camera.has_motion_blur:
            # an inertial camera's rest-frame time runs with its own clock (tau = c t)
            tau = self.camera_tau + self.scene.light_speed * lens.shutter_times(camera, *keys, self.settings.resolution)
        else:
            tau = np.broadcast_to(self.camera_tau, (len(d),))  # read-only views: every ray starts at this time
        return tau, origins, d, s_lo, s_hi if valid.all() else np.where(valid, s_hi, -np.inf)

    def centre_rays(self, rect):
        """The pixel-centre camera rays of a rectangle of pixels, in row-major order."""
        x0, y0, x1, y1 = rect
        return self._camera_rays(np.arange(x0, x1) + 0.5, np.arange(y0, y1) + 0.5, grid=True)

    def _pixel_grid(self, rect):
        """Pixel coordinates and flat image indices of a rectangle of pixels, in row-major order."""
        x0, y0, x1, y1 = rect
        xs = np.tile(np.arange(x0, x1, dtype=np.int64), y1 - y0)
        ys = np.repeat(np.arange(y0, y1, dtype=np.int64), x1 - x0)
        return xs, ys, ys * self.settings.resolution[0] + xs

    def _measure_doppler_range(self, should_stop):
        """Range of D over the whole image's pixel-centre rays (for the normalised FACTOR
        display; the whole image, so that regions rendered apart agree with a full render)."""
        lo, hi = math.inf, -math.inf
        for rect in self.tiles(self.full_image):
            if should_stop():
                break
            tau, x, d, s_lo, s_hi = self.centre_rays(rect)
            hits = trace_nearest(self.frames, self.frames.camera, tau, x, d, s_lo, s_hi)
            doppler = self._hit_doppler(hits, tau, x, d)[hits.frame >= 0]
            if len(doppler):
                lo, hi = min(lo, doppler.min()), max(hi, doppler.max())
        return (lo, hi) if lo <= hi else (0.0, 1.0)

    def _measure_exposure(self, scene, settings, lights, should_stop) -> float:
        """Exposure that gives the image the mean luminance of the same view without Doppler
        intensity or colour changes (the paper's dynamic-range re-normalisation, section 4.2).

        Both are estimated on a small preview of the whole image (one ray per preview pixel),
        so that regions rendered apart agree with a full render.
        """
        x0, y0, x1, y1 = self.full_image
        scale = _EXPOSURE_PREVIEW / max(x1 - x0, y1 - y0, 1)
        nx, ny = max(int((x1 - x0) * scale), 1), max(int((y1 - y0) * scale), 1)
        gx, gy = np.meshgrid(x0 + (np.arange(nx) + 0.5) * (x1 - x0) / nx, y0 + (np.arange(ny) + 0.5) * (y1 - y0) / ny)
        px, py = gx.ravel(), gy.ravel()
        pixel = np.arange(len(px), dtype=np.int64)
        plain = Shader(self.frames, self.materials, lights, RGBColour(self.materials, lights, scene.world_color),
                       settings.max_bounces, searchlight=False)
        luminance = np.array([0.2126, 0.7152, 0.0722])
        means = []
        for shader in (self.shader, plain):
            if should_stop():
                return 1.0
            lam = shader.colour.camera_wavelengths(pixel, pixel * 0)
            tau, x, d, s_lo, s_hi = self._camera_rays(px, py)
            values, _ = shader.radiance(self.frames.camera, tau, x, d, s_lo, s_hi, 0, pixel, pixel * 0, lam)
            means.append(float(np.mean(shader.colour.to_rgb(values, lam) @ luminance)))
        rendered, reference = means
        return reference / rendered if rendered > 0 and reference > 0 else 1.0

    # ------------------------------------------------------------------ one tile
    def render_tile(self, rect) -> Tile:
        x0, y0, x1, y1 = rect
        h, w = y1 - y0, x1 - x0
        xs, ys, pixel = self._pixel_grid(rect)
        n = len(pixel)
        centre = self.centre_rays(rect)
        centre_hits = trace_nearest(self.frames, self.frames.camera, *centre)
        passes = self._centre_passes(centre, centre_hits)
        samples = max(int(self.settings.samples), 1)
        rgb = np.zeros((n, 3))
        coverage = np.zeros(n)
        for index, (part, first, count) in enumerate(_batches(n, samples, self.colour.channels)):
            if index and self.should_stop():  # Esc between sample batches of a long tile
                break
            m = part.stop - part.start
            pix = np.repeat(pixel[part], count)
            smp = np.tile(np.arange(first, first + count), m)
            if samples == 1 and not self.camera_samples_vary:  # the one sample is the pixel-centre ray, already traced
                color, hit = self._sample(tuple(a[part] for a in centre), pix, smp, centre_hits.take(part))
            else:
                ox, oy = sampling.stratified_offsets(pix, smp, samples)
                rays = self._camera_rays(np.repeat(xs[part], count) + ox, np.repeat(ys[part], count) + oy,
                                         keys=(pix, smp, samples))
                color, hit = self._sample(rays, pix, smp)
            rgb[part] += color.reshape(m, count, 3).sum(axis=1)
            coverage[part] += hit.reshape(m, count).sum(axis=1)
        rgb *= self.exposure / samples
        coverage /= samples
        alpha = coverage if self.settings.film_transparent else np.ones(n)
        passes["Combined"] = np.concatenate([rgb, alpha[:, None]], axis=1)
        return Tile(x0, y0, x1, y1, {k: v.reshape(h, w, -1).astype(np.float32) for k, v in passes.items()})

    def _sample(self, rays, pixel, sample, hits=None):
        """Colour of camera samples and whether they hit anything (``hits``: already traced)."""
        tau, x, d, s_lo, s_hi = rays
        camera = self.frames.camera
        if self.settings.doppler_mode == "FACTOR":
            if hits is None:
                hits = trace_nearest(self.frames, camera, tau, x, d, s_lo, s_hi)
            hit = hits.frame >= 0
            rgb = np.repeat(self._doppler_grey(self._hit_doppler(hits, tau, x, d))[:, None], 3, axis=1)
        else:
            lam = self.colour.camera_wavelengths(pixel, sample)
            values, hits = self.shader.radiance(camera, tau, x, d, s_lo, s_hi, 0, pixel, sample, lam, hits)
            rgb = self.colour.to_rgb(values, lam)
            hit = hits.frame >= 0
        if self.settings.film_transparent:
            rgb[~hit] = 0.0
        elif self.settings.doppler_mode == "FACTOR":
            rgb[~hit] = self.scene.world_color
        return rgb, hit

    def _hit_doppler(self, hits, tau, x, d):
        """Doppler factor of camera-ray hits (the frame's, times a spinning surface's own)."""
        doppler = 1.0 / hits.w
        for k in frames_hit(hits):
            frame = self.frames.frames[int(k)]
            if frame.spin is None:
                continue
            sel = np.flatnonzero(hits.frame == k)
            tau_k, d_k = hits.tau_frame[sel], hits.d_frame[sel]
            doppler[sel] *= self.shader.surface_doppler(int(k), hits.prim[sel], hits.u[sel], hits.v[sel],
                                                        tau_k - hits.s_frame[sel], d_k)
        return doppler

    def _doppler_grey(self, doppler):
        lo, hi = self.doppler_range
        t = np.clip((doppler - lo) / (hi - lo), 0.0, 1.0) if hi > lo else np.ones_like(doppler)
        levels = int(self.settings.doppler_levels)
        if levels > 1:
            t = np.minimum(np.floor(t * levels), levels - 1) / (levels - 1)
        return t

    def _centre_passes(self, rays, hits):
        """The requested passes of the pixel-centre ray: exact, quotable values (no sample averaging)."""
        tau, x, d, _, _ = rays
        camera = self.frames.camera
        wanted = set(self.passes)
        n = len(d)
        hit = hits.frame >= 0
        passes = {}
        if "Depth" in wanted:
            passes["Depth"] = np.where(hit, hits.s, 1e10)
        if "Emission Time" in wanted:
            # world time of the hit event: back along the ray in the camera frame, then into S
            world_tau, _ = self.frames.map(camera, self.frames.world).events(
                tau[hit] - hits.s[hit], rows.add_scaled(x[hit], hits.s[hit], d[hit]))
            passes["Emission Time"] = np.zeros(n)
            passes["Emission Time"][hit] = world_tau / self.scene.light_speed
        per_frame = {"Doppler": (1,), "Normal": (3,), "IndexOB": (1,), "Object Time": (1,)}
        for name in wanted & per_frame.keys():
            passes[name] = np.zeros((n, *per_frame[name]))
        if not wanted & per_frame.keys():
            return passes
        for k in frames_hit(hits):
            sel = np.flatnonzero(hits.frame == k)
            frame = self.frames.frames[int(k)]
            d_k, w = hits.d_frame[sel], hits.w[sel]
            tau_hit = hits.tau_frame[sel] - hits.s_frame[sel]
            prim, u, v = hits.prim[sel], hits.u[sel], hits.v[sel]
            if "Doppler" in wanted:
                passes["Doppler"][sel, 0] = self.shader.surface_doppler(int(k), prim, u, v, tau_hit, d_k) / w
            if "Normal" in wanted:
                passes["Normal"][sel] = self.shader.surface_info(int(k), prim, u, v, d_k, tau_hit)[2]
            if "IndexOB" in wanted:
                passes["IndexOB"][sel, 0] = frame.geometry.tri_object_index[prim]
            if "Object Time" in wanted:
                passes["Object Time"][sel, 0] = frame.object_clock(tau_hit, prim) / self.scene.light_speed
        return passes


def _batches(n: int, samples: int, channels: int):
    """(pixels, first sample, sample count) of a tile's batches: at most ``_MAX_VALUES`` colour
    values each, whatever the tile size, samples and wavelengths (pixels split when one sample
    of the whole tile is already more)."""
    part_size = n if n * channels <= _MAX_VALUES else max(_MAX_VALUES // channels, 1)
    for start in range(0, n, part_size):
        part = slice(start, min(start + part_size, n))
        per_batch = max(_MAX_VALUES // ((part.stop - part.start) * channels), 1)
        for first in range(0, samples, per_batch):
            yield part, first, min(per_batch, samples - first)


def _validate(scene: Scene, settings: RenderSettings) -> None:
    if scene.camera is None:
        raise RenderError("the scene has no camera: add one and make it the scene camera")
    width, height = settings.resolution
    if width < 1 or height < 1:
        raise RenderError(f"the resolution {width}x{height} has no pixels")
    if settings.region is not None:
        x0, y0, x1, y1 = settings.region
        if not (0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height):
            raise RenderError(f"the render region {settings.region} is empty or outside the {width}x{height} image")
    if not (math.isfinite(scene.light_speed) and scene.light_speed > 0):
        raise RenderError(f"the speed of light must be a positive number (got {scene.light_speed})")
    if not math.isfinite(scene.tau_obs):
        raise RenderError("the observation time is not finite: check the reference frame and the speed of light")
    unknown = set(settings.passes or ()) - set(EXTRA_PASSES)
    if unknown:
        raise RenderError(f"unknown passes {sorted(unknown)}: RESTframe fills {list(EXTRA_PASSES)} besides Combined")
    problem = lens.settings_problem(scene.camera)
    if problem:
        raise RenderError(problem)
    if settings.doppler_mode not in DOPPLER_MODES:
        raise RenderError(f"Doppler display mode {settings.doppler_mode!r} is not one of {DOPPLER_MODES}")


def _worker_count(settings: RenderSettings) -> int:
    return settings.threads if settings.threads > 0 else (os.cpu_count() or 1)


def render_tiles(scene: Scene, settings: RenderSettings, should_stop: Callable[[], bool] = lambda: False,
                 renderer: Renderer | None = None) -> Iterator[Tile]:
    """Yield rendered tiles as they complete; return early once ``should_stop()`` is true."""
    renderer = renderer or Renderer(scene, settings, should_stop)
    with blas.single_threaded():  # the render threads use the cores (see blas)
        yield from _tiles_in_threads(renderer, _worker_count(settings), should_stop)


def _tiles_in_threads(renderer: Renderer, workers: int, should_stop) -> Iterator[Tile]:
    rects = renderer.tiles()
    if workers == 1:
        for rect in rects:
            if should_stop():
                return
            yield renderer.render_tile(rect)
        return
    pool = ThreadPoolExecutor(max_workers=workers)
    pending = set()
    queue = iter(rects)
    try:
        while True:
            while len(pending) < 2 * workers and not should_stop():
                rect = next(queue, None)
                if rect is None:
                    break
                pending.add(pool.submit(renderer.render_tile, rect))
            if not pending or should_stop():
                return
            done, pending = wait(pending, timeout=0.1, return_when=FIRST_COMPLETED)
            for future in done:
                yield future.result()
    finally:
        # on Esc, return at once: tiles still running stop at their next sample batch
        pool.shutdown(wait=False, cancel_futures=True)


def render_image(scene: Scene, settings: RenderSettings, should_stop: Callable[[], bool] = lambda: False,
                 progress: Callable[[int, int], None] | None = None) -> dict[str, np.ndarray]:
    """Render the whole image (or region) into full-size pass arrays, row 0 at the bottom."""
    renderer = Renderer(scene, settings, should_stop)
    width, height = settings.resolution
    passes = {name: np.zeros((height, width, ALL_PASSES[name]), dtype=np.float32)
              for name in ("Combined", *renderer.passes)}
    total = len(renderer.tiles())
    for done, tile in enumerate(render_tiles(scene, settings, should_stop, renderer), start=1):
        for name, data in tile.passes.items():
            passes[name][tile.y0:tile.y1, tile.x0:tile.x1] = data
        if progress is not None:
            progress(done, total)
    return passes

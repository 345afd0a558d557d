"""Settings: the render panels -> core RenderSettings (resolution, border, samples, passes)."""

from __future__ import annotations

import numpy as np

from ..core.passes import DENOISING_PASSES, PASSES
from ..core.scene import RenderSettings
from .errors import ExportError


def full_resolution(scene) -> tuple[int, int]:
    render = scene.render
    return (render.resolution_x * render.resolution_percentage // 100,
            render.resolution_y * render.resolution_percentage // 100)


def _border_pixels(edge: float, size: int) -> int:
    """One border edge in pixels as Blender computes it: the single-precision edge times the
    resolution, in single precision, truncated (``render_init_from_main``).  In double precision
    an edge like 0.7 (stored as 0.69999999) lands one pixel short at 1920."""
    return int(np.float32(edge) * np.float32(size))


def border_region(scene, resolution) -> tuple[int, int, int, int] | None:
    """Blender's render border in pixels (x1/y1 exclusive), rounded as Blender does."""
    render = scene.render
    if not render.use_border:
        return None
    width, height = resolution
    x0, x1 = _border_pixels(render.border_min_x, width), _border_pixels(render.border_max_x, width)
    y0, y1 = _border_pixels(render.border_min_y, height), _border_pixels(render.border_max_y, height)
    if x1 <= x0 or y1 <= y0:
        raise ExportError("the render region (border) is empty: draw a larger one or turn it off")
    return (x0, y0, x1, y1)


def core_passes(view_layer) -> tuple[str, ...]:
    """The core passes a render of this view layer fills besides Combined: Blender's where the
    view layer enables them, RESTframe's own always."""
    denoising = view_layer.restframe.denoising_store_passes
    blender = (("Depth", view_layer.use_pass_z), ("Normal", view_layer.use_pass_normal),
               ("IndexOB", view_layer.use_pass_object_index)) + tuple((name, denoising) for name in DENOISING_PASSES)
    return tuple(name for name, used in blender if used) + tuple(PASSES)


def render_settings(scene, resolution=None, view_layer=None) -> RenderSettings:
    """The render settings of the scene's RESTframe and Render panels (all passes without a view layer)."""
    rf = scene.restframe
    render = scene.render
    resolution = tuple(resolution) if resolution is not None else full_resolution(scene)
    return RenderSettings(
        resolution=resolution,
        region=border_region(scene, resolution),
        samples=rf.samples,
        integrator=rf.integrator,
        max_bounces=rf.max_bounces,
        diffuse_bounces=rf.diffuse_bounces,
        glossy_bounces=rf.glossy_bounces,
        transmission_bounces=rf.transmission_bounces,
        clamp_direct=rf.clamp_direct,
        clamp_indirect=rf.clamp_indirect,
        doppler_mode=rf.doppler_mode,
        searchlight=rf.searchlight,
        spectral_samples=rf.spectral_samples,
        normalize_exposure=rf.normalize_exposure,
        film_transparent=render.film_transparent,
        tile_size=rf.tile_size,
        threads=render.threads if render.threads_mode == 'FIXED' else 0,
        doppler_range=None if rf.doppler_range_auto else tuple(rf.doppler_range),
        doppler_levels=rf.doppler_levels,
        motion_tolerance=rf.motion_tolerance,
        passes=None if view_layer is None else core_passes(view_layer),
    )


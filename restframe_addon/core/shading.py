"""Shading in each surface's rest frame, with light and colour carried between frames.

A surface is shaded where it is at rest (its frame k): the law of reflection,
Snell's law, Fresnel and the BSDF hold there.  What crosses frames is light:

* from a light (at rest in frame j) to the surface: the backward ray from the hit
  event aims at the light's retarded position -- in frame j the light is static,
  so it is the light's own position -- and is mapped back to frame k.  Its
  path-length ratio is the Doppler factor D = r / r' of the light seen from the
  surface; irradiance is ``I' D^4 cos / r^2`` (point-like) or ``E' D^2 cos`` (sun).
* from a surface to whoever looks at it (camera or another surface): radiance
  scales by ``D^4`` (frequency-integrated, the searchlight effect).

With ``searchlight`` off these D powers are dropped (geometry only).  Colour
values are ``(n, C)`` arrays handled by a colour model (:mod:`.colour`): RGB, or
spectra whose wavelengths are multiplied by D at every frame change (one more
power of D for spectral densities).  Values are in the frame they are evaluated in.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from types import MappingProxyType

import numpy as np

from . import rows, sampling, spectral
from .bsdf import (dielectric_f0, fresnel_average_f82_tint, fresnel_average_principled_dielectric, fresnel_dielectric,
                   fresnel_f82_tint, ggx_dielectric_albedo, ggx_energy_compensation, ggx_reflection,
                   ggx_single_scattering)
from .frames import FrameSet, clock_shift, shift_into_frame
from .lorentz import RowBoosts
from .passes import facing_normals, frame_batches, hit_doppler, hit_times, joined_frames
from .scene import RAY_CAMERA, RAY_GLOSSY, RAY_TRANSMISSION, Light, Material, Scene
from .tracer import Hits, TraceCache, frames_hit, occluded, trace_nearest
from .world import Texels, image_lookup

MIRROR_ROUGHNESS = 0.05  # smoother surfaces reflect by traced mirror rays, rougher ones by GGX highlights
_MIN_ALPHA = 1e-3

# Blender's light units: a point light of power P watts has radiant intensity P / (4 pi) W/sr
# (irradiance P / (4 pi r^2) head-on); an area light of power P emits radiance P / (pi A);
# a sun of strength S gives irradiance S on a surface facing it.
_POINT_INTENSITY_PER_WATT = 1.0 / (4.0 * np.pi)

# Cycles' default view-layer Alpha Threshold: the passes (depth, normal, index) see surfaces
# at least this opaque, the colour sees every surface with the chance of its alpha
PASS_ALPHA_THRESHOLD = 0.5
# sampler dimensions of the cut-out decisions: from here, 1000 per (bounce depth, ray type) and
# (bounce depth, light), one more per surface passed (at most tracer._MAX_PASS_THROUGH < 1000)
_CUTOUT_DIMENSION = 1_000_000
# Direct Light shades the hits in a lamp's shadow too (with no light), rather than gathering the
# others, unless more than 1 in this many are in shadow (a gather costs about 1/8 of the shading)
_SHADE_IN_SHADOW = 8


class MaterialTable:
    """The scene's materials as arrays indexed by material number."""

    def __init__(self, materials: list[Material], light_speed: float = 1.0):
        if not materials:
            materials = [Material()]
        # emission keys converted to the tracer's clock (c*t)
        self.emission_curves = {
            i: (np.asarray(m.emission_curve[0], dtype=np.float64) * light_speed,
                np.asarray(m.emission_curve[1], dtype=np.float64))
            for i, m in enumerate(materials) if m.emission_curve is not None
        }
        self.materials = materials
        self.base = np.array([m.base_color for m in materials], dtype=np.float64).reshape(-1, 3)
        self.metallic = np.clip([m.metallic for m in materials], 0.0, 1.0)
        self.roughness = np.clip([m.roughness for m in materials], 0.0, 1.0)
        self.ior = np.maximum([m.ior for m in materials], 1e-3)
        self.specular_scale = 2.0 * np.clip([m.specular_ior_level for m in materials], 0.0, None)
        self.transmission = np.clip([m.transmission for m in materials], 0.0, 1.0)
        self.coat_weight = np.clip([m.coat_weight for m in materials], 0.0, 1.0)
        self.coat_roughness = np.clip([m.coat_roughness for m in materials], 0.0, 1.0)
        self.coat_ior = np.maximum([m.coat_ior for m in materials], 1.0 + 1e-6)
        self.emission = np.array([m.emission for m in materials], dtype=np.float64).reshape(-1, 3)
        self.emits = np.any(self.emission != 0.0, axis=1)
        # images laid out for world.image_lookup once
        self.textures = [_texels(m.base_color_texture, colour=True) for m in materials]
        self.closest = [m.base_color_interpolation == "Closest" for m in materials]
        self.principled_alpha = np.clip([m.alpha for m in materials], 0.0, 1.0)  # cut-outs (not the GGX alpha)
        self.alpha_textures = [_texels(m.alpha_texture) for m in materials]
        self.cuts_out = bool(np.any(self.principled_alpha < 1.0)) or any(t is not None for t in self.alpha_textures)
        self.normal_textures = [_texels(m.normal_texture) for m in materials]
        self.normal_strength = np.maximum([m.normal_strength for m in materials], 0.0)
        self.normal_mapped = any(t is not None for t in self.normal_textures)
        self.holdout = np.array([m.holdout for m in materials], dtype=bool)
        self.holdouts = bool(self.holdout.any())
        self.mirror = self.roughness < MIRROR_ROUGHNESS
        self.glass = self.transmission > 0.0
        self.traces_secondary = bool(np.any(self.mirror | self.glass))
        # the direct-light lobes, per material (worked out once, gathered per hit)
        self.diffuse_weight = (1.0 - self.metallic) * (1.0 - self.transmission) / np.pi
        # Specular IOR Level scales the whole dielectric lobe (0 = none), grazing reflection included
        self.f0_dielectric = np.minimum(dielectric_f0(self.ior) * self.specular_scale, 1.0) * (1.0 - self.metallic)
        self.f90 = np.minimum(self.specular_scale, 1.0) * (1.0 - self.metallic) + self.metallic
        self.alpha = np.maximum(self.roughness**2, _MIN_ALPHA)
        # the Principled BSDF as Cycles adjusts it: Specular IOR Level scales F0, which sets the IOR
        f0_adjusted = np.minimum(dielectric_f0(self.ior) * self.specular_scale, 1.0 - 1e-9)
        self.f0_adjusted = f0_adjusted
        self.ior_adjusted = (1.0 + np.sqrt(f0_adjusted)) / (1.0 - np.sqrt(f0_adjusted))
        # its hemispherical Fresnel average (for the multiscatter compensation), once per material
        self.fresnel_average_dielectric = fresnel_average_principled_dielectric(
            self.ior_adjusted, f0_adjusted[:, None], np.ones(len(materials)))[:, 0]
        # rough surfaces with a specular lobe get GGX highlights (Specular IOR Level 0, not metallic: none)
        self.glossy = ~self.mirror & ((self.f90 > 0.0) | (self.f0_dielectric > 0.0) | (self.metallic > 0.0))

    def emission_factor(self, index, clock):
        """Multiplier of animated emissions at the emitting body's own clock (c*t units)."""
        factor = np.ones(len(index))
        for m, (times, values) in self.emission_curves.items():
            sel = index == m
            if np.any(sel):
                factor[sel] = np.interp(clock[sel], times, values)
        return factor

    def clamp(self, index):
        """Material numbers as rows of the table (out of range: the nearest end; in range, as
        they always are from the export, the array itself: see rows.clipped)."""
        return rows.clipped(index, 0, len(self.materials) - 1)

    def base_color(self, index, uv, columns: bool = False):
        """Base colour per hit, with image textures looked up (bilinear or closest, repeat) where present
        (``columns``: one textured material's into contiguous columns, see world.image_lookup)."""
        one = _only_material(index) if uv is not None else None
        if one is not None and self.textures[one] is not None:  # one textured material: no gathers
            return self._texture_color(one, uv[:, 0], uv[:, 1], columns)
        color = np.take(self.base, index, axis=0)
        if uv is None:
            return color
        for m, texture in enumerate(self.textures):
            if texture is None:
                continue
            sel = np.flatnonzero(index == m)
            if len(sel):
                color[sel] = self._texture_color(m, uv[sel, 0], uv[sel, 1])
        return color

    def _texture_color(self, m, u, v, columns: bool = False):
        return image_lookup(self.textures[m], u, v, "Closest" if self.closest[m] else "Linear", channels=3,
                            columns=columns)

    def opacity(self, index, uv):
        """Principled Alpha per hit (the alpha image looked up where there is one, UVs or not)."""
        alpha = self.principled_alpha[index]
        for m, texture in enumerate(self.alpha_textures):
            if texture is None:
                continue
            sel = np.flatnonzero(index == m)
            if len(sel):
                alpha[sel] = alpha[sel] * (image_lookup(texture, uv[sel, 0], uv[sel, 1], channels=1)[:, 0]
                                             if uv is not None else 1.0)
        return alpha

    def tangent_normals(self, index, uv):
        """The normal map's tangent-space normal per hit (Blender's colour * 2 - 1), NaN where the
        material has none."""
        normal = np.full((len(index), 3), np.nan)
        for m, texture in enumerate(self.normal_textures):
            if texture is None:
                continue
            sel = np.flatnonzero(index == m)
            if len(sel):
                normal[sel] = 2.0 * image_lookup(texture, uv[sel, 0], uv[sel, 1]) - 1.0
        return normal


@dataclass
class PreparedLight:
    """A light placed in its rest frame (the frame index into the FrameSet)."""

    light: Light
    frame: int
    position: np.ndarray  # in its frame
    axes: np.ndarray  # 3x3, columns = local X, Y, Z (emits along -Z)
    radiant: np.ndarray  # colour * power in Blender units
    power: float  # the lamp's power as shaded: Blender's, a soft sun's scaled to its disc (:func:`prepare_lights`)
    clock_offset: float = 0.0  # the lamp's own clock = its frame's time + this (constant velocity)
    keyed: tuple | None = None  # keyed output: (lamp-clock times c*t (N,), colours (N, 3), powers (N,)); None: radiant

    @property
    def sampled(self) -> bool:
        """Whether shadow rays aim at random points of it (soft and area lights, a sun with an angle)."""
        light = self.light
        if light.kind == "SUN":
            return light.sun_angle > 0.0
        return light.kind == "AREA" or light.radius > 0.0


def prepare_lights(scene: Scene, frames: FrameSet) -> list[PreparedLight]:
    prepared = []
    for light, frame in zip(scene.lights, frames.light_frames):
        boost = frames.frames[frame].boost
        axes = np.asarray(light.matrix, dtype=np.float64)
        axes = axes / np.maximum(np.linalg.norm(axes, axis=0, keepdims=True), 1e-300)
        position = np.asarray(light.position, dtype=np.float64) + shift_into_frame(boost, light.pivot_or_position)
        power, keyed = float(light.power), _keyed_output(light, scene.light_speed) if light.is_keyed else None
        if light.kind == "SUN" and light.sun_angle > 0.0:  # its disc's radiance, as Cycles': S / (pi sin^2 half),
            disc = 2.0 / (1.0 + np.cos(0.5 * light.sun_angle))  # over the S / solid angle its samples carry
            power *= disc
            keyed = None if keyed is None else (keyed[0], keyed[1], keyed[2] * disc)
        radiant = np.asarray(light.color, dtype=np.float64) * power
        if light.temperature > 0.0:
            radiant = radiant * spectral.blackbody_rgb(light.temperature)
        if light.kind not in ("POINT", "SPOT", "SUN", "AREA"):
            raise ValueError(f"{light.name}: light type {light.kind} is not supported by RESTframe")
        if light.kind == "SUN" and light.trajectory is not None:
            raise ValueError(f"{light.name}: a sun lamp is infinitely far and has no world line: "
                             "give it a constant velocity (Motion = Constant Velocity)")
        if np.any(radiant > 0) if keyed is None else np.any(keyed[1] * keyed[2][:, None] > 0):
            prepared.append(PreparedLight(light, frame, position, axes, radiant, power,
                                          clock_offset=-clock_shift(boost, light.pivot_or_position), keyed=keyed))
    return prepared


def _keyed_output(light: Light, light_speed: float):
    """A keyed lamp's (lamp-clock times c*t, colours, powers) on the union of its curves' samples
    (linear between them, as each curve)."""
    curves = [c for c in (light.power_curve, light.color_curve) if c is not None]
    seconds = np.unique(np.concatenate([np.asarray(c[0], dtype=np.float64) for c in curves]))
    if light.power_curve is None:
        power = np.full(len(seconds), float(light.power))
    else:
        power = np.interp(seconds, *(np.asarray(a, dtype=np.float64) for a in light.power_curve))
    if light.color_curve is None:
        color = np.broadcast_to(np.asarray(light.color, dtype=np.float64), (len(seconds), 3)).copy()
    else:
        times, values = (np.asarray(a, dtype=np.float64) for a in light.color_curve)
        color = np.column_stack([np.interp(seconds, times, values.reshape(-1, 3)[:, i]) for i in range(3)])
    if not (np.all(np.isfinite(power)) and np.all(np.isfinite(color))):
        raise ValueError(f"{light.name}: its keyed strength or colour is not a finite number")
    return seconds * light_speed, color, power


class LayeredLobes:
    """The Principled BSDF's lobes at some surface points, layered as Cycles does (the Path
    Tracing integrator's BSDF; Direct Light keeps :meth:`Shader.brdf`'s plain sum).

    Metallic m mixes a metal (F82-Tint Fresnel from the base colour) with a dielectric whose
    specular layer (real Fresnel of the IOR as Specular IOR Level adjusts it) lies over glass
    (Transmission) or over the diffuse base, which it dims by its directional albedo; rough
    specular lobes are multiscatter GGX (energy-compensated), smooth ones (roughness below
    ``MIRROR_ROUGHNESS``) delta reflections.  All in the surfaces' rest frame; ``view`` toward
    the viewer, ``back``: the back of the surface was hit (for a transmissive one: from inside).
    """

    def __init__(self, mats: MaterialTable, base, mat, ns, view, back=None):
        self.ns, self.view, self.base, self.mat = ns, view, base, mat
        n, channels = base.shape
        self.metallic = mats.metallic[mat]
        self.alpha = mats.alpha[mat]
        self.glossy = mats.glossy[mat]
        self.mirror = mats.mirror[mat]
        ior = mats.ior_adjusted[mat]
        # n_view / n_other: light inside a transmissive body sees the interface from within
        inside = (back if back is not None else np.zeros(n, dtype=bool)) & (mats.transmission[mat] > 0.0)
        self.eta = np.where(inside, ior, 1.0 / ior)
        cos_v = np.clip(rows.dot(ns, view), 1e-6, 1.0)
        self.cos_v = cos_v
        self.white = np.broadcast_to(1.0, (n, channels))  # (read-only views of one number: no arrays of ones)
        # each lobe worked out where a material has it (elsewhere it is 0, or its factor 1)
        self.diffuse = rows.scale(base, mats.diffuse_weight[mat])  # f, not albedo
        layer = np.flatnonzero(mats.f0_adjusted[mat] > 0.0)  # a specular layer dims it (none where F0 = 0)
        if len(layer):
            f0 = np.broadcast_to(mats.f0_adjusted[mat[layer]][:, None], (len(layer), channels))
            self.diffuse[layer] *= 1.0 - ggx_dielectric_albedo(cos_v[layer], self.alpha[layer], ior[layer], f0,
                                                               np.ones(len(layer)))
        self.compensation_dielectric = self.compensation_metal = self.white
        glossy = np.flatnonzero(self.glossy)
        if len(glossy):
            self.compensation_dielectric, self.compensation_metal = np.ones((n, channels)), np.ones((n, channels))
            average = np.broadcast_to(mats.fresnel_average_dielectric[mat[glossy]][:, None], (len(glossy), channels))
            self.compensation_dielectric[glossy] = ggx_energy_compensation(cos_v[glossy], self.alpha[glossy], average)
            metal = glossy[self.metallic[glossy] > 0.0]
            if len(metal):
                average = fresnel_average_f82_tint(rows.take(base, metal), self.white[metal])
                self.compensation_metal[metal] = ggx_energy_compensation(cos_v[metal], self.alpha[metal], average)
        # the delta lobes
        self.reflect_weight = np.zeros((n, channels))
        mirror = np.flatnonzero(self.mirror)
        if len(mirror):
            self.reflect_weight[mirror] = self.fresnel(cos_v[mirror], compensated=False, index=mirror)
        transmission = mats.transmission[mat] * (1.0 - self.metallic)
        through = np.zeros(n)
        glass = np.flatnonzero(transmission > 0.0)
        if len(glass):
            through[glass] = (1.0 - fresnel_dielectric(cos_v[glass], self.eta[glass])) * transmission[glass]
        self.transmit_weight = np.broadcast_to(through[:, None], (n, channels))

    def fresnel(self, cos_h, compensated: bool = True, index=None):
        """The specular reflectance (n, C) at microfacet angle cos_h: dielectric and metal mixed by
        Metallic; at the points ``index`` (default: all), one cos_h each."""
        pick = (lambda a: a) if index is None else (lambda a: rows.take(a, index))  # noqa: E731
        metallic = pick(self.metallic)
        dielectric = fresnel_dielectric(cos_h, pick(self.eta)) * (1.0 - metallic)
        if compensated:
            value = pick(self.compensation_dielectric) * dielectric[:, None]
        else:
            value = np.repeat(dielectric[:, None], self.base.shape[1], axis=1)
        metal = np.flatnonzero(metallic > 0.0)
        if len(metal):
            at = metal if index is None else index[metal]
            reflectance = rows.scale(fresnel_f82_tint(cos_h[metal], rows.take(self.base, at), self.white[at]),
                                     metallic[metal])
            value[metal] += self.compensation_metal[at] * reflectance if compensated else reflectance
        return value

    def value(self, light, index=None):
        """f (n, C), without the cosine: the diffuse and the rough specular lobes; at the points
        ``index`` (default: all), one light direction each."""
        value = self.diffuse.copy() if index is None else rows.take(self.diffuse, index)
        glossy = np.flatnonzero(self.glossy if index is None else self.glossy[index])
        if len(glossy):
            r = glossy if index is None else index[glossy]
            single, above, cos_vh = ggx_single_scattering(self.ns[r], self.view[r], light[glossy], self.alpha[r])
            value[glossy] += rows.scale(self.fresnel(cos_vh, index=r), np.where(above, single, 0.0))
        return value

    def take(self, index) -> "LayeredLobes":
        """The lobes of some of the points (an index array)."""
        part = object.__new__(type(self))
        for name, value in vars(self).items():
            setattr(part, name, value[index] if isinstance(value, np.ndarray) else value)
        return part


class Shader:
    """Traces and shades backward rays for one prepared scene (thread-safe: read-only state).

    ``layered``: evaluate surfaces with :class:`LayeredLobes` (Path Tracing) instead of the
    direct-light integrator's plain sum of lobes.
    """

    def __init__(self, frames: FrameSet, materials: MaterialTable, lights: list[PreparedLight],
                 colour, max_bounces: int, searchlight: bool, layered: bool = False):
        self.layered = layered
        self.frames = frames
        self.materials = materials
        self.lights = tuple(lights)
        self.colour = colour
        self.max_bounces = max_bounces
        self.searchlight = searchlight
        # how far secondary and shadow rays start off a surface (RestFrame.surface_offset)
        self.epsilon = MappingProxyType({k: float(frames.surface_offsets[k]) for k in frames.geometry})
        # the material of every triangle of a frame whose triangles have one (a body of one
        # material, the common case): its hits' material numbers are that number broadcast, not gathered
        single = {}
        for k in frames.geometry:
            geometry = frames.frames[k].geometry
            if id(geometry) not in single:
                one = _only_material(materials.clamp(geometry.tri_material))
                if one is not None:  # (one element, viewed n times by hit_materials)
                    one = np.array([one], geometry.tri_material.dtype)
                    one.flags.writeable = False
                single[id(geometry)] = one
        self._one_material = MappingProxyType({k: single[id(frames.frames[k].geometry)] for k in frames.geometry})
        # a sharp sun's light in every frame with geometry that moves against it (_sharp_sun), made once here
        self._sharp_suns = MappingProxyType({
            (pl.frame, k, tuple(pl.axes[:, 2])): self._sunlight_row(pl.frame, k, pl.axes[:, 2])
            for pl in self.lights if pl.light.kind == "SUN" and not pl.sampled for k in frames.geometry
            if not frames.map(pl.frame, k).is_identity})

    # ------------------------------------------------------------------ helpers
    def searchlight_power(self, doppler, exponent: int):
        """D^(exponent + the colour model's extra power), or 1 with the searchlight off."""
        if not self.searchlight:
            return np.ones_like(doppler)
        return doppler ** (exponent + self.colour.extra_power)

    # ------------------------------------------------------------------ denoising data
    def denoising_data(self, hits):
        """Cycles' denoising passes of camera rays: the first surface's albedo (RGB, diffuse plus
        specular reflectance plus transmission as its BSDF weighs them, at most 1) and its
        shading normal (the surface's frame, as the Normal pass); 0 where nothing is hit."""
        n = len(hits.frame)
        albedo, normal = np.zeros((n, 3)), np.zeros((n, 3))
        for k in frames_hit(hits):
            sel = np.flatnonzero(hits.frame == k)
            frame = self.frames.frames[int(k)]
            prim, u, v, d_k = hits.prim[sel], hits.u[sel], hits.v[sel], hits.d_frame[sel]
            _, _, ns, mat, back = self.surface_info(int(k), prim, u, v, d_k, hit_times(hits, sel))
            uv = hit_uv(frame, prim, u, v)
            lobes = LayeredLobes(self.materials, self.materials.base_color(mat, uv), mat, ns, -d_k, back)
            specular = np.where(lobes.glossy[:, None], lobes.fresnel(lobes.cos_v), lobes.reflect_weight)
            albedo[sel] = np.minimum(lobes.diffuse * np.pi + specular + lobes.transmit_weight, 1.0)
            normal[sel] = ns
        return {"Denoising Albedo": albedo, "Denoising Normal": normal}

    # ------------------------------------------------------------------ rays
    def radiance(self, src: int, tau0, x0, d, s_lo, s_hi, depth: int, ids: sampling.Samples, lam, hits=None,
                 cache: TraceCache | None = None, ray: int = RAY_CAMERA):
        """Radiance arriving at events (tau0, x0) of frame src from backward directions d, of the
        samples ``ids``, at the wavelengths ``lam`` of frame src (None in RGB mode); ``hits`` if already traced;
        ``cache``: the calling thread's :class:`~.tracer.TraceCache` (None: keep nothing);
        ``ray``: the rays' type (``RAY_*``).  Holdout surfaces give 0 (they end the path).

        Returns (values (n, C), hits) -- the hits of this ray bundle, for the passes.
        """
        n = len(d)
        if hits is None:
            hits = self.trace(src, tau0, x0, d, s_lo, s_hi, ray, ids.pixel, ids.sample, depth, cache)
        values = np.empty((n, self.colour.channels))
        missed = hits.frame < 0
        miss = np.flatnonzero(missed)
        if len(miss):
            to_world = self.frames.map(src, self.frames.world)
            if to_world.is_identity:  # the background is at rest with the viewer: D = 1
                _put_rows(values, missed, miss, self.colour.world(_rows(lam, miss), len(miss)))
            else:
                doppler = 1.0 / to_world.rays(d[miss])[1]
                world = self.colour.world(self.colour.shift(_rows(lam, miss), doppler), len(miss))
                values[miss] = rows.scale(world, self.searchlight_power(doppler, 4))
        held = self.held_out(hits) if self.has_holdouts else None
        if held is not None:
            values[held] = 0.0
        for order, segments in self._frame_batches(hits, held, depth, values):
            self._shade_batch(src, hits, order, segments, depth, ids, lam, cache, values)
        return values, hits

    def _frame_batches(self, hits: Hits, held, depth: int, values) -> list:
        """:func:`~.passes.frame_batches` of the hits to shade: holdouts (``held``) left out, and
        with emission alone the frames whose surfaces are dark (their values set to 0)."""
        keep = None if held is None else ~held
        batches = frame_batches(hits, keep)
        if not self._emission_only(depth):
            return batches
        dark = [k for order, segments in batches for k, s in segments
                if self._dark(self.frames.frames[k], rows.take(hits.prim, s if isinstance(order, slice) else order[s]))]
        if not dark:
            return batches
        black = np.isin(hits.frame, dark)
        values[black] = 0.0  # black whatever its Doppler factor (it is finite)
        return frame_batches(hits, ~black if keep is None else keep & ~black)

    def _shade_batch(self, src: int, hits: Hits, order, segments, depth: int, ids, lam, cache, values):
        """Shade the hits ``order`` of the frames ``segments`` ((k, rows of order) each) together into
        ``values``: :meth:`radiance` of one of :meth:`_frame_batches`' batches."""
        emission_only = self._emission_only(depth)
        prim = rows.take(hits.prim, order)
        # the directions only where they matter: shading beyond emission, a spinning surface's Doppler factor
        spins = any(self.frames.frames[k].spin is not None for k, _ in segments)
        d_k = None if emission_only and not spins else rows.take(hits.d_frame, order)
        tau_hit = hit_times(hits, order)
        u, v = rows.take(hits.u, order), rows.take(hits.v, order)
        ids, lam = ids.take(order), _rows(lam, order)
        if not spins and all(self.frames.map(src, k).is_identity for k, _ in segments):  # at rest: D = 1
            rows.put_selection(values, order, self._shade_surfaces(segments, tau_hit, d_k, prim, u, v, depth, ids,
                                                                   lam, cache))
            return
        w = rows.take(hits.w, order)
        # (a frame at rest with the viewer has w = 1: D = 1, and its hits are scaled by 1)
        doppler = joined_frames([hit_doppler(self.frames.frames[k], prim[s], u[s], v[s], tau_hit[s],
                                             None if d_k is None else d_k[s], w[s]) for k, s in segments])
        local = self._shade_surfaces(segments, tau_hit, d_k, prim, u, v, depth, ids, self.colour.shift(lam, doppler),
                                     cache)
        rows.put_selection(values, order, rows.scale(local, self.searchlight_power(doppler, 4)))

    # ------------------------------------------------------------------ tracing
    def trace(self, src: int, tau0, x0, d, s_lo, s_hi, ray: int, pixel, sample, depth: int,
              cache: TraceCache | None = None, for_passes: bool = False, runs=None) -> Hits:
        """The surfaces rays of type ``ray`` stop at: hidden ones passed, cut-outs passed with the
        chance 1 - alpha (keyed by pixel, sample and depth), or, ``for_passes``, where alpha is
        below :data:`PASS_ALPHA_THRESHOLD`; ``runs``: as for :func:`~.tracer.trace_nearest`."""
        if not self.materials.cuts_out:
            see_through = None
        elif for_passes:
            see_through = lambda hits, rays, layer: self.hit_opacity(hits) < PASS_ALPHA_THRESHOLD
        else:
            see_through = self.cutouts(sampling.Samples(pixel, sample), _cutout_dimension(depth, ray.bit_length()))
        return trace_nearest(self.frames, src, tau0, x0, d, s_lo, s_hi, cache, ray, see_through, runs)

    def cutouts(self, ids: sampling.Samples, dimension: int):
        """A ``see_through`` test for the tracer: the rays of the samples ``ids`` pass a
        surface where its alpha is at most a uniform number (sampler ``dimension`` + the
        surfaces passed so far); None without cut-outs."""
        if not self.materials.cuts_out:
            return None

        def see_through(hits, rays, layer):
            return self.hit_opacity(hits) <= ids.take(rays).uniforms((dimension + layer,))[0]
        return see_through

    def hit_materials(self, k: int, prim) -> np.ndarray:
        """Material numbers (rows of the MaterialTable) of triangles ``prim`` of frame k (read-only:
        one number broadcast where all the frame's triangles have it)."""
        one = self._one_material.get(k)
        if one is not None:
            return rows.broadcast(one, len(prim))
        return self.materials.clamp(np.take(self.frames.frames[k].geometry.tri_material, prim))

    def _frames_materials(self, segments, prim) -> np.ndarray:
        """:meth:`hit_materials` at hits of several frames (``segments``: (frame k, its rows)), joined."""
        return joined_frames([self.hit_materials(k, prim[s]) for k, s in segments])

    def hit_opacity(self, hits: Hits) -> np.ndarray:
        """Principled Alpha at hits (every ray hit something)."""
        alpha = np.ones(len(hits.frame))
        for k in frames_hit(hits):
            sel = np.flatnonzero(hits.frame == k)
            frame = self.frames.frames[k]
            prim = hits.prim[sel]
            uv = hit_uv(frame, prim, hits.u[sel], hits.v[sel])
            alpha[sel] = self.materials.opacity(self.hit_materials(k, prim), uv)
        return alpha

    @property
    def has_holdouts(self) -> bool:
        """Whether any surface is a holdout (an object's or a Holdout shader)."""
        return self.frames.has_holdout or self.materials.holdouts

    def held_out(self, hits: Hits) -> np.ndarray:
        """Whether each hit is on a holdout surface (a hole in the image)."""
        held = np.zeros(len(hits.frame), dtype=bool)
        if not self.has_holdouts:
            return held
        for k in frames_hit(hits):
            geometry = self.frames.frames[k].geometry
            sel = np.flatnonzero(hits.frame == k)
            prim = hits.prim[sel]
            held[sel] = self.materials.holdout[self.hit_materials(k, prim)]
            if geometry.tri_holdout is not None:
                held[sel] |= geometry.tri_holdout[prim]
        return held

    def surface_info(self, k: int, prim, u, v, d_k, tau_hit=None, cache: TraceCache | None = None):
        """Position, facing geometric and shading normals (normal maps applied), and material
        index at hits of frame k (``cache``: the calling thread's)."""
        return self.frames_surface_info([(k, slice(0, len(prim)))], prim, u, v, d_k, tau_hit, cache)

    def frames_surface_info(self, segments, prim, u, v, d_k, tau_hit=None, cache: TraceCache | None = None):
        """:meth:`surface_info` at hits of several frames (``segments``: (frame k, its rows))."""
        return self._surfaces(segments, prim, u, v, d_k, tau_hit, cache)[:5]

    def _surfaces(self, segments, prim, u, v, d_k, tau_hit, cache):
        """:meth:`frames_surface_info`, the cosines ns . (-d_k) where facing_normals has them
        (None with a normal map applied, or where it has not), and each frame's UVs (:func:`hit_uv`)
        where the normal maps needed them (else None: not worked out)."""
        position, ng, ns, back, cos_view = facing_normals(self.frames, segments, prim, u, v, d_k, tau_hit, cache)
        material = self._frames_materials(segments, prim)
        uvs = None
        if self.materials.normal_mapped:
            own = False  # (ns may be ng, or the geometry's: copied before a normal map writes into it)
            uvs = [hit_uv(self.frames.frames[k], prim[s], u[s], v[s], cache) for k, s in segments]
            for (k, s), uv in zip(segments, uvs):
                frame = self.frames.frames[k]
                if uv is None:
                    continue
                plain = ns[s]
                mapped = self._normal_mapped(frame, prim[s], material[s], uv, ng[s], plain, back[s], d_k[s],
                                             np.zeros(len(plain)) if tau_hit is None else tau_hit[s])
                if mapped is not plain and len(segments) == 1:  # (one frame: _normal_mapped's copy is every row)
                    ns = mapped
                elif mapped is not plain:
                    if not own:
                        ns, own = ns.copy(), True
                    ns[s] = mapped
                if mapped is not plain:
                    cos_view = None
        return position, ng, ns, material, back, cos_view, uvs

    def _shade_surfaces(self, segments, tau, d_k, prim, u, v, depth, ids, lam, cache):
        """The values leaving hits toward their rays, in each hit's frame: the hits of several
        frames in one array, ``segments`` = (frame k, its rows) in order; what depends on the frame
        (the geometry, the lamps' light) worked out frame by frame, the rest once for all."""
        mats = self.materials
        if self._emission_only(depth):  # no normals, texture or base colour needed
            mat = self._frames_materials(segments, prim)
            return self._emission(segments, tau, prim, mat, lam)
        position, ng, ns, mat, back, cos_view, uvs = self._surfaces(segments, prim, u, v, d_k, tau, cache)
        if uvs is None:  # (not already worked out for the normal maps)
            uvs = [hit_uv(self.frames.frames[k], prim[s], u[s], v[s], cache) for k, s in segments]
        if all(uv is None for uv in uvs) or all(uv is not None for uv in uvs):
            base = self.colour.base_color(mat, None if uvs[0] is None else joined_frames(uvs), lam,
                                          columns=True)  # (brdf scales it column by column)
        else:  # frames with and without UVs
            base = joined_frames([self.colour.base_color(mat[s], uv, _rows(lam, s))
                                  for (_, s), uv in zip(segments, uvs)])
        one = _only_material(mat)
        if self.lights and one is not None and not mats.emits[one]:  # the direct light alone
            values = self._direct(segments, tau, position, ng, ns, -d_k, base, mat, depth, ids, lam, cache,
                                  cos_view)
        else:
            values = self._emission(segments, tau, prim, mat, lam)
            if self.lights:
                values += self._direct(segments, tau, position, ng, ns, -d_k, base, mat, depth, ids, lam, cache,
                                  cos_view)
        if self._bounces(depth):
            for k, s in segments:
                values[s] += self._secondary(k, tau[s], position[s], ng[s], ns[s], d_k[s], base[s], mat[s], back[s],
                                             depth, ids.take(s), _rows(lam, s), cache)
        return values

    def _emission_only(self, depth: int) -> bool:
        """Whether hits at this depth give their emission alone (no lights, no secondary rays)."""
        return not self.lights and not self._bounces(depth)

    def _bounces(self, depth: int) -> bool:
        """Whether hits at this depth may send secondary (mirror, glass) rays."""
        return self.materials.traces_secondary and depth < self.max_bounces

    def _dark(self, frame, prim) -> bool:
        """Whether none of these hits' surfaces emits (their emission is 0 at every wavelength)."""
        if self.materials.emission_curves:
            return False
        mat = self.hit_materials(frame.index, prim)
        one = _only_material(mat)
        return not (self.materials.emits[one] if one is not None else self.materials.emits[mat].any())

    def _emission(self, segments, tau, prim, mat, lam):
        """The surfaces' own emission at hits of several frames (``segments``: (k, rows)), a new array."""
        values = np.array(self.colour.emission(mat, lam), dtype=np.float64)
        if self.materials.emission_curves:  # optical clocks: the emitter's own time at this event
            clock = joined_frames([self.frames.frames[k].object_clock(tau[s], prim[s]) for k, s in segments])
            values *= self.materials.emission_factor(mat, clock)[:, None]
        return values

    def shading_normals(self, k: int, prim, u, v, d_k, tau_hit=None):
        """The facing shading normals at hits of frame k, normal maps applied (the Normal pass's)."""
        return self.surface_info(k, prim, u, v, d_k, tau_hit)[2]

    def _normal_mapped(self, frame, prim, mat, uv, ng, ns, back, d_k, tau):
        """Shading normals perturbed by tangent-space normal maps, as Cycles' Normal Map node does:
        N = x T + y B + z n with the UV tangent T (per triangle, made orthogonal to the shading
        normal n, which faces the triangle's front), B = sign n x T, then
        n + strength (N - n), turned toward the viewer's side again."""
        local = self.materials.tangent_normals(mat, uv)
        mapped = np.flatnonzero(~np.isnan(local[:, 0]))
        if len(mapped) == 0:
            return ns
        tangent, sign = uv_tangents(frame, prim[mapped], tau[mapped])
        facing = np.where(back[mapped], -1.0, 1.0)
        n = rows.scale(ns[mapped], facing)  # the front side's normal
        tangent = rows.normalized(tangent - rows.scale(n, rows.dot(n, tangent)))
        bitangent = rows.scale(rows.cross(n, tangent), sign)
        c = local[mapped]
        perturbed = rows.normalized(rows.scale(tangent, c[:, 0]) + rows.scale(bitangent, c[:, 1]) + rows.scale(n, c[:, 2]))
        strength = self.materials.normal_strength[mat[mapped]]
        perturbed = rows.normalized(n + rows.scale(perturbed - n, strength))
        perturbed = rows.scale(perturbed, facing)
        away = rows.dot(perturbed, d_k[mapped]) >= 0.0  # turned away from the viewer: the geometric normal
        perturbed[away] = ng[mapped][away]
        ns = ns.copy()
        ns[mapped] = perturbed
        return ns

    # ------------------------------------------------------------------ direct light
    def brdf(self, ns, view, light, base, mat, cos_l=None, cos_v=None):
        """The surfaces' non-delta BSDF f (n, C) (without the cosine), in their rest frame: the
        diffuse lobe and, on rough surfaces with a specular lobe, GGX highlights (``layered``: as
        :class:`LayeredLobes`; ``cos_l``, ``cos_v``: ns . light and ns . view where the caller has them).  Mirror reflection
        and refraction are delta lobes, traced instead (DIRECT: ``_secondary``)."""
        mats = self.materials
        if self.layered:
            return LayeredLobes(mats, base, mat, ns, view).value(light)
        # one material (the common case: a frame's hits on one body): its constants as 1-element
        # arrays, no gathers, no specular work unless it has a lobe
        one = _only_material(mat)
        pick = (lambda table: table[mat]) if one is None else (lambda table: table[one:one + 1])
        value = rows.scale(base, pick(mats.diffuse_weight), columns=True)
        r = np.flatnonzero(mats.glossy[mat]) if one is None else slice(None) if mats.glossy[one] else None
        if r is None or (one is None and not len(r)):
            return value
        m = mat[r] if one is None else slice(one, one + 1)
        f0 = mats.f0_dielectric[m][:, None]  # a grey F0 (one column) unless metallic
        if (mats.metallic[one] > 0.0) if one is not None else np.any(mats.metallic[m] > 0.0):
            f0 = rows.scale(base[r], mats.metallic[m]) + f0
        else:
            f0 = np.broadcast_to(f0, (len(value) if one is not None else len(r), 1))
        specular = ggx_reflection(ns[r], view[r], light[r], mats.alpha[m], f0, mats.f90[m],
                                  None if cos_l is None else cos_l[r], None if cos_v is None else cos_v[r])
        if one is not None and value.shape[1] <= 4:  # column by column (see rows)
            for c in range(value.shape[1]):
                value[:, c] += specular[:, min(c, specular.shape[1] - 1)]
        else:
            value[r] += specular
        return value

    def _direct(self, segments, tau, position, ng, ns, view, base, mat, depth, ids, lam, cache, cos_view=None):
        """The lamps' light reflected toward ``view`` (n, C): one shadow ray per lamp and hit, of
        the hits of several frames (``segments``: (frame k, its rows), in order; ``cos_view``:
        ns . view if known).  A selection of hits is a slice while it is all of them (views, not gathers)."""
        total = None
        for index, light in enumerate(self.lights):
            dim = 1000 + 100 * depth + 4 * index
            xi1 = xi2 = None  # a point light or sharp sun needs no random numbers
            if light.sampled:
                xi1, xi2 = ids.uniforms((dim, dim + 1))  # (from the camera jitter's hash of the samples)
            incident = [self._incident(light, k, tau[s], position[s], None if xi1 is None else xi1[s],
                                       None if xi2 is None else xi2[s]) for k, s in segments]
            e_k, strength, doppler, s_max, clock = (joined_frames([part[i] for part in incident]) for i in range(5))
            cos_n = rows.dot(ns, e_k)
            lit = cos_n > 0.0
            if ns is not ng:  # (flat shading: one array, the same test)
                lit &= rows.dot(ng, e_k) > 0.0
            if strength.strides != (0,) or not (strength[:1] > 0.0).all():  # (one broadcast number: tested once)
                lit &= strength > 0.0
            sel = rows.selection(lit)
            if sel is None:
                continue
            e_sel = rows.take(e_k, sel)
            blocked = self._occluded(segments, sel, tau, position, ng, e_sel, [part[0] for part in incident],
                                     s_max, ids, _cutout_dimension(depth, 8 + index), cache)
            cos_sel = rows.take(cos_n, sel)
            weight = rows.take(strength, sel) * cos_sel
            shadowed = np.count_nonzero(blocked)
            if shadowed == len(blocked):
                continue
            if shadowed * _SHADE_IN_SHADOW > len(blocked):  # many in shadow: shade only the others
                lit = np.flatnonzero(~blocked)
                e_sel, weight, cos_sel = np.take(e_sel, lit, axis=0), np.take(weight, lit), np.take(cos_sel, lit)
                sel = lit if isinstance(sel, slice) else np.take(sel, lit)
            elif shadowed:  # a few: cheaper to shade them too, with no light
                weight[blocked] = 0.0
            f = self.brdf(rows.take(ns, sel), rows.take(view, sel), e_sel, rows.take(base, sel), rows.take(mat, sel),
                          cos_sel, None if cos_view is None else rows.take(cos_view, sel))
            emitted = self.colour.light(index, self.colour.shift(_rows(lam, sel), rows.take(doppler, sel)), len(f),
                                        None if clock is None else rows.take(clock, sel))
            f = _weighted_product(f, emitted, weight)
            if total is not None:
                total[sel] += f
            elif isinstance(sel, slice):
                total = f
            else:
                total = np.zeros(base.shape)  # (rows, whatever base's layout: see rows.put)
                rows.put_selection(total, sel, f)
        return np.zeros(base.shape) if total is None else total

    def _occluded(self, segments, sel, tau, position, ng, e_sel, e_frames, s_max, ids, dimension: int, cache):
        """Whether the shadow rays of the hits ``sel`` (toward ``e_sel``, at most ``s_max`` long) are
        blocked: asked of the tracer frame by frame (``segments``: (frame k, its rows); ``e_frames``:
        each frame's directions, of which a sharp sun's one broadcast row stays one: the tracer sees
        the rays are parallel), each from its frame's surface offset; ``dimension``: the sampler
        dimension of their cut-out decisions."""
        starts = [s.start for _, s in segments] + [segments[-1][1].stop]
        bounds = starts if isinstance(sel, slice) else np.searchsorted(sel, starts).tolist()  # each frame's part
        # each frame's surface offset a row of its rays (the same products as by the one number)
        eps = np.array([self.epsilon[k] for k, _ in segments])
        eps_rays = eps[0] if len(segments) == 1 else np.repeat(eps, np.diff(bounds))
        if rows.is_broadcast(ng) and np.ndim(eps_rays) == 0:  # a flat mesh's one normal: one offset row
            origin = rows.filled(ng[0] * eps_rays, len(e_sel))
        else:
            origin = np.multiply(rows.take(ng, sel), eps_rays if np.ndim(eps_rays) == 0 else eps_rays[:, None])
        origin += rows.take(position, sel)
        reach = rows.take(s_max, sel) - 2.0 * eps_rays if np.ndim(s_max) else s_max  # sunlight: unbounded
        tau_sel, ids_sel = rows.take(tau, sel), ids.take(sel)  # (the samples gathered if cut-outs ask for them)
        parts = []
        for (k, _), e_frame, start, stop in zip(segments, e_frames, bounds[:-1], bounds[1:]):
            if stop == start:
                continue
            rays = slice(start, stop)
            d = e_sel[rays] if e_frame.strides[0] else np.broadcast_to(e_frame[0], (stop - start, 3))
            parts.append(occluded(self.frames, k, tau_sel[rays], origin[rays], d, self.epsilon[k],
                                  reach[rays] if np.ndim(reach) else reach, cache,
                                  see_through=self.cutouts(ids_sel.take(rays), dimension)))
        return joined_frames(parts)

    def _incident(self, pl: PreparedLight, k, tau, position, xi1, xi2):
        """Light arriving at hit events of frame k from one light.

        Returns the direction toward the light's retarded position (frame k), the
        geometric and Doppler factor of its irradiance on a surface facing it (to
        multiply the light's colour at the shifted wavelengths), the Doppler
        factor D = r / r' of the light seen from the surface, the path length
        to the light (inf for the sun), and the lamp's own clock (c*t) when it
        sent that light (None unless its output is keyed).

        The lamp is static in its frame j; an animated lamp in its momentary rest frame
        at the retarded event, different for every hit (:meth:`_momentary`).
        """
        light = pl.light
        n = len(tau)
        x_axis, y_axis, z_axis = pl.axes[:, 0], pl.axes[:, 1], pl.axes[:, 2]
        if light.kind == "SUN":  # the path length is unbounded (one number for all hits)
            if light.sun_angle > 0.0:
                e_j = _cone_sample(z_axis, 0.5 * light.sun_angle, xi1, xi2)
            else:
                e_j = np.broadcast_to(z_axis, (n, 3))
            to_surface = self.frames.map(pl.frame, k)
            clock = None
            if pl.keyed is not None:  # the plane wave passed the lamp's place (P - x).e before reaching x
                tau_j, x_j = self.frames.map(k, pl.frame).events(tau, position)
                clock = tau_j - (pl.position - x_j) @ z_axis + pl.clock_offset
            if to_surface.is_identity:  # at rest with the surface: D = 1, so D^p = 1
                one = np.broadcast_to(1.0, (n,))
                return e_j, one, one, np.inf, clock
            if e_j.strides[0] == 0:  # a sharp sun, one direction for every hit: mapped once per frame
                e_k, sun_strength, doppler = (np.broadcast_to(a, (n,) + a.shape[1:])
                                              for a in self._sharp_sun(pl.frame, k, z_axis))
                return e_k, sun_strength, doppler, np.inf, clock
            return *self._sunlight(to_surface, e_j), np.inf, clock
        if light.trajectory is None:
            tau_j, x_j = self.frames.map(k, pl.frame).events(tau, position)
            sample = np.broadcast_to(pl.position, (n, 3))
            back = self.frames.map(pl.frame, k).rays
            clock_zero = pl.clock_offset
        else:
            tau_j, x_j, sample, back, clock_zero, _ = self._momentary(pl, k, tau, position)
        if light.kind == "AREA":
            sx, sy = light.area_size
            if light.area_shape in ("DISK", "ELLIPSE"):
                radius, (cos_phi, sin_phi) = np.sqrt(xi1), unit_circle(xi2)
                a, b = 0.5 * radius * cos_phi, 0.5 * radius * sin_phi
            else:
                a, b = xi1 - 0.5, xi2 - 0.5
            sample = rows.add_scaled(rows.add_scaled(sample, a * sx, x_axis), b * sy, y_axis)
        delta = sample - x_j
        r_rest = rows.norm(delta)
        e_j = rows.scale(delta, 1.0 / np.maximum(r_rest, 1e-300))
        if light.kind != "AREA" and light.radius > 0.0:
            # a soft (spherical) light: aim at a point of its disc facing the surface
            disc = _disc_sample(e_j, light.radius, xi1, xi2)
            delta = sample + disc - x_j
            r_rest = rows.norm(delta)
            e_j = rows.scale(delta, 1.0 / np.maximum(r_rest, 1e-300))
        if light.kind == "AREA":
            intensity = np.maximum(e_j @ z_axis, 0.0) / np.pi  # Lambertian, emitting along -Z
        else:
            intensity = np.full(n, _POINT_INTENSITY_PER_WATT)
            if light.kind == "SPOT":
                intensity = intensity * _spot_falloff(e_j @ z_axis, light.spot_size, light.spot_blend)
        e_k, doppler = back(e_j)  # s_surface / s_light: the Doppler factor seen by the surface
        r = doppler * r_rest  # distance to the retarded position in the surface frame
        # the light left the lamp (its point ``sample``) r_rest before the hit, in the lamp's frame
        clock = None if pl.keyed is None else tau_j - r_rest + clock_zero
        return e_k, intensity * self.searchlight_power(doppler, 4) / np.maximum(r, 1e-300) ** 2, doppler, r, clock

    def _sunlight(self, to_surface, e_j) -> tuple:
        """Sunlight along directions e_j (toward the sun, in its frame) as a surface sees it
        (``to_surface``: the map into its frame): the directions, the irradiance factor D^2, D."""
        e_k, doppler = to_surface.rays(e_j)
        sun_strength = self.searchlight_power(doppler, 2)
        return e_k, sun_strength, doppler

    def _sharp_sun(self, j: int, k: int, axis) -> tuple:
        """A sharp sun's light in frame k from its frame j (emitting along -``axis``): its direction,
        irradiance factor and D, one read-only row each, mapped once per (j, k, axis) when the
        shader is made (the same steps on the same numbers as for one hit's row: the same bits)."""
        return self._sharp_suns[(j, k, tuple(axis))]

    def _sunlight_row(self, j: int, k: int, axis) -> tuple:
        """:meth:`_sunlight` of the one direction ``axis`` from frame j into frame k, read-only."""
        found = self._sunlight(self.frames.map(j, k), np.array([axis], dtype=np.float64))
        for a in found:
            a.flags.writeable = False
        return found

    def _momentary(self, pl: PreparedLight, k, tau, position):
        """An animated lamp seen from hit events of frame k, in its momentary rest frame at the
        retarded event of each (where its world line crosses the hit's past light cone, solved
        as for animated bodies): the hit events there (tau_j, x_j), the lamp's place, the map of
        backward directions from there to frame k (d, s_k / s_lamp), its clock minus that
        frame's time (None unless keyed), and the map of directions from frame k there (d,
        s_lamp / s_k; the path tracer's bounce rays).  Static in that frame near the event: exact
        for a point lamp, an area lamp's other points as if moving inertially."""
        trajectory = pl.light.trajectory
        from_frame = self.frames.map(k, self.frames.world)
        tau_w, x_w = from_frame.events(tau, position)
        emitted = trajectory.light_cone_crossing(tau_w, x_w)
        lamp_w, beta = trajectory.state(emitted)
        into_lamp = RowBoosts(beta)
        tau_j, x_j = into_lamp.events(tau_w, x_w)
        tau_lamp, lamp = into_lamp.events(emitted, lamp_w)
        out_of_lamp, to_frame = into_lamp.inverse(), self.frames.map(self.frames.world, k)

        def back(e_j):
            e_w, w_world = out_of_lamp.rays(e_j)
            e_k, w_frame = to_frame.rays(e_w)
            return e_k, w_world * w_frame

        def forward(d_k):
            d_w, w_world = from_frame.rays(d_k)
            d_j, w_lamp = into_lamp.rays(d_w)
            return d_j, w_world * w_lamp

        clock_zero = None if pl.keyed is None else trajectory.proper_time(emitted) - tau_lamp
        return tau_j, x_j, lamp, back, clock_zero, forward

    # ------------------------------------------------------------------ mirror and glass
    def _secondary(self, k, tau, position, ng, ns, d_k, base, mat, back, depth, ids, lam, cache):
        mats = self.materials
        values = np.zeros_like(base)
        active = np.flatnonzero(mats.mirror[mat] | mats.glass[mat])
        if len(active) == 0:
            return values
        n_a, ng_a, d_a = ns[active], ng[active], d_k[active]
        m = mat[active]
        cos_i = -np.einsum("ij,ij->i", n_a, d_a)
        # relative index of refraction across the surface, as the ray leaves the viewer's side
        eta = np.where(back[active], mats.ior[m], 1.0 / mats.ior[m])
        fresnel = np.minimum(fresnel_dielectric(cos_i, eta) * mats.specular_scale[m], 1.0)
        metallic = mats.metallic[m][:, None]
        reflect_weight = fresnel[:, None] * (1.0 - metallic) + base[active] * metallic
        transmit_weight = ((1.0 - fresnel) * mats.transmission[m])[:, None] * (1.0 - metallic)
        eps = self.epsilon[k]
        reflected = d_a + 2.0 * cos_i[:, None] * n_a
        values[active] += reflect_weight * self._bounce(k, tau[active], position[active] + eps * ng_a, reflected,
                                                        eps, depth, ids.take(active), _rows(lam, active),
                                                        cache, RAY_GLOSSY)
        refr = np.flatnonzero(np.any(transmit_weight > 0.0, axis=1))
        if len(refr):
            k2 = 1.0 - eta[refr] ** 2 * (1.0 - cos_i[refr] ** 2)
            ok = k2 > 0.0  # total internal reflection is all in the Fresnel term (F = 1)
            refr, k2 = refr[ok], k2[ok]
            transmitted = eta[refr, None] * d_a[refr] + (eta[refr] * cos_i[refr] - np.sqrt(k2))[:, None] * n_a[refr]
            transmitted /= np.linalg.norm(transmitted, axis=1, keepdims=True)
            idx = active[refr]
            values[idx] += transmit_weight[refr] * self._bounce(k, tau[idx], position[idx] - eps * ng_a[refr],
                                                                transmitted, eps, depth, ids.take(idx),
                                                                _rows(lam, idx), cache, RAY_TRANSMISSION)
        return values

    def _bounce(self, k, tau, origin, d, eps, depth, ids, lam, cache, ray: int):
        if len(d) == 0:
            return np.zeros((0, self.colour.channels))
        values, _ = self.radiance(k, tau, origin, d, eps, np.inf, depth + 1, ids, lam, cache=cache, ray=ray)
        return values


def _cutout_dimension(depth: int, stream: int) -> int:
    """The first sampler dimension of the cut-out decisions of one stream of rays at one bounce
    depth (streams 1-5: the ray types, 8 + i: shadow rays toward light i)."""
    return _CUTOUT_DIMENSION + 1000 * (stream + 1_000_000 * depth)


def hit_uv(frame, prim, u, v, cache: TraceCache | None = None):
    """Interpolated UVs at hits of one frame (None when its geometry has none); ``cache``: the
    calling thread's, which keeps small meshes' UVs as 1-D tables (the same bits, half the time:
    the gathered (n, 3, 2) rows are read six times with a 48-byte stride)."""
    corner_uvs = frame.geometry.corner_uvs
    if corner_uvs is None:
        return None
    first = 1.0 - u  # the barycentric weight of the first corner
    first -= v
    tables = None if cache is None else cache.uv_table(frame.geometry)
    if tables is not None:  # (float64 UVs, as frames keeps them: the weights widened once, exactly)
        index = np.asarray(prim, dtype=np.intp)  # (converted once, not by each gather)
        weights = [np.asarray(w, dtype=np.float64) for w in (first, u, v)]
        uv = np.empty((2, len(prim))).T
        term = np.empty(len(prim))
        for c, corners in enumerate(tables):
            column = uv[:, c]
            _weighted_corner(corners[0], index, weights[0], column)
            for corner in (1, 2):
                column += _weighted_corner(corners[corner], index, weights[corner], term)
        return uv
    cuv = np.take(corner_uvs, prim, axis=0)
    # column by column (see rows), into contiguous columns, in place (temporaries cost page faults)
    uv = np.empty((2, len(prim)), dtype=np.result_type(first, cuv)).T
    term = np.empty(len(prim), dtype=uv.dtype)
    for c in range(2):
        column = uv[:, c]
        np.multiply(first, cuv[:, 0, c], out=column)
        column += np.multiply(u, cuv[:, 1, c], out=term)
        column += np.multiply(v, cuv[:, 2, c], out=term)
    return uv


def _weighted_corner(table, index, weight, out):
    """``table[index] * weight`` into ``out``: the corners' values at the hits (a table shared by
    every triangle is one number: the same products, no gather)."""
    if isinstance(table, float):
        return np.multiply(weight, table, out=out)
    np.take(table, index, out=out, mode="clip")  # (prim is in range: clip skips the check)
    out *= weight
    return out


def uv_tangents(frame, prim, tau=None):
    """The direction of increasing U on each triangle (frame coordinates, unnormalised) and the
    sign that makes n x T point along increasing V (the UV map's handedness)."""
    geometry = frame.geometry
    corners = geometry.vertices[geometry.triangles[prim]]
    cuv = geometry.corner_uvs[prim]
    e1, e2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    du1, dv1 = cuv[:, 1, 0] - cuv[:, 0, 0], cuv[:, 1, 1] - cuv[:, 0, 1]
    du2, dv2 = cuv[:, 2, 0] - cuv[:, 0, 0], cuv[:, 2, 1] - cuv[:, 0, 1]
    tangent = rows.scale(e1, dv2) - rows.scale(e2, dv1)
    bitangent = rows.scale(e2, du1) - rows.scale(e1, du2)
    determinant = du1 * dv2 - du2 * dv1
    tangent = rows.scale(tangent, np.where(determinant < 0.0, -1.0, 1.0))
    bitangent = rows.scale(bitangent, np.where(determinant < 0.0, -1.0, 1.0))
    sign = np.where(rows.dot(rows.cross(geometry.face_normals(prim), tangent), bitangent) < 0.0, -1.0, 1.0)
    if frame.spin is not None:
        _, tangent = frame.to_frame(corners[:, 0], tangent, tau)
    return tangent, sign


def _rows(lam, index):
    """The wavelengths of some rays (None in RGB mode)."""
    return None if lam is None else rows.take(lam, index)


def _put_rows(values, mask, index, new):
    """``values[index] = new``, ``index`` the rows where ``mask`` holds: one row broadcast to all
    of them is copied column by column under the mask (5x faster than assigning (n, C) rows)."""
    if new.strides[0] != 0:
        values[index] = new
        return
    for channel in range(values.shape[1]):
        np.copyto(values[:, channel], new[0, channel], where=mask)


def _spot_falloff(cos_angle, spot_size, blend):
    cos_half = np.cos(0.5 * spot_size)
    if blend <= 0.0:
        return (cos_angle > cos_half).astype(np.float64)
    t = np.clip((cos_angle - cos_half) / ((1.0 - cos_half) * blend), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _orthonormal_basis(axis):
    """Two unit vectors perpendicular to each unit axis (n, 3): t1 = axis x (X, or Y for an
    axis near X), t2 = axis x t1; column by column (see rows)."""
    x, y, z = axis[:, 0], axis[:, 1], axis[:, 2]
    near_x = np.abs(x) >= 0.9
    hx, hy = np.where(near_x, 0.0, 1.0), np.where(near_x, 1.0, 0.0)  # the helper (hx, hy, 0)
    t1 = np.empty(axis.shape)
    t1[:, 0] = y * 0.0 - z * hy
    t1[:, 1] = z * hx - x * 0.0
    t1[:, 2] = x * hy - y * hx
    length = np.sqrt(t1[:, 0] * t1[:, 0] + t1[:, 1] * t1[:, 1] + t1[:, 2] * t1[:, 2])
    for c in range(3):
        t1[:, c] /= length
    return t1, rows.cross(axis, t1)


def _disc_sample(axis, radius, xi1, xi2):
    t1, t2 = _orthonormal_basis(axis)
    r, (cos_phi, sin_phi) = radius * np.sqrt(xi1), unit_circle(xi2)
    return _combine(r * cos_phi, t1, r * sin_phi, t2)


@lru_cache(maxsize=64)
def _axis_basis(axis: tuple) -> tuple:
    """:func:`_orthonormal_basis` of one axis (a lamp's, the same for every batch of rays)."""
    t1, t2 = (t[0] for t in _orthonormal_basis(np.array([axis], dtype=np.float64)))
    t1.flags.writeable = t2.flags.writeable = False
    return t1, t2


def _cone_sample(axis, half_angle, xi1, xi2):
    """Directions uniform in the cone about one unit axis (3,): its basis is worked out once."""
    t1, t2 = _axis_basis(tuple(axis))
    cos_t = xi1 * (1.0 - np.cos(half_angle))  # in place from here: temporaries cost page faults
    np.subtract(1.0, cos_t, out=cos_t)
    sin_t = cos_t * cos_t  # (|cos_t| <= 1 for xi1 in [0, 1), so 1 - cos_t^2 >= 0: no clamp)
    np.subtract(1.0, sin_t, out=sin_t)
    np.sqrt(sin_t, out=sin_t)
    cos_phi, sin_phi = unit_circle(xi2)
    cos_phi *= sin_t
    sin_phi *= sin_t
    return _combine(cos_phi, t1, sin_phi, t2, cos_t, axis)


# float32 trigonometry is 15x faster than float64 in numpy; a sample's angle about a cone's axis
# or a disc's centre needs no more than its 6e-8 (tests/core/test_shading.py checks the images)
UNIT_CIRCLE_DTYPE = np.float32


def unit_circle(xi):
    """(cos, sin) (float64 arrays) of the angles 2 pi xi, computed to float32 precision
    (:data:`UNIT_CIRCLE_DTYPE`): they orient the random offsets of cone and disc samples."""
    phi = np.multiply(2.0 * np.pi, xi, out=np.empty(len(xi), UNIT_CIRCLE_DTYPE))
    return np.cos(phi, out=np.empty(len(xi))), np.sin(phi, out=np.empty(len(xi)))


def _combine(*weights_and_vectors):
    """Rows ``a t1 + b t2 (+ c t3)`` of (n,) weights and (n, 3) or (3,) vectors, summed in that order."""
    (first_weight, first_vector), *middle, (last_weight, last_vector) = zip(weights_and_vectors[::2],
                                                                             weights_and_vectors[1::2])
    out = np.empty((len(first_weight), 3))
    column, term = np.empty(len(out)), np.empty(len(out))  # contiguous: twice as fast as out's columns
    for c in range(3):
        np.multiply(first_weight, first_vector[..., c], out=column)
        for weight, vector in middle:
            column += np.multiply(weight, vector[..., c], out=term)
        np.add(column, np.multiply(last_weight, last_vector[..., c], out=term), out=out[:, c])  # the last sum: into out
    return out


def _texels(image, colour: bool = False):
    return None if image is None else Texels(image, colour)


def _only_material(mat):
    """The material number when every hit has the same one, else None."""
    if len(mat) and mat.strides == (0,):  # one number broadcast (Shader.hit_materials)
        return int(mat[0])
    if len(mat) and mat[0] == mat[-1] and bool((mat == mat[0]).all()):
        return int(mat[0])
    return None


def _weighted_product(a, b, s):
    """``a * b * s[:, None]`` (a new row-major array, as the radiance it adds to) for (n, C) a
    (overwritten) and b (often one row broadcast) and (n,) s, column by column for few columns
    (see rows): the last product written into the rows (no copy of contiguous columns into rows after)."""
    if a.shape[1] > 4:
        return rows.scale(a * b, s)
    out = np.empty(a.shape, np.result_type(a, b, s))
    for c in range(a.shape[1]):
        column = a[:, c]
        column *= b[:, c]
        np.multiply(column, s, out=out[:, c])
    return out

"""Path tracing across rest frames: world light, bounced light and emissive surfaces.

Every scattering event happens in the rest frame k of the surface hit: there the BSDF
picks the next incoming direction (cosine for diffuse, GGX visible normals for glossy,
mirror and Fresnel-weighted refraction for the delta lobes), and the bounce ray is traced
backward from the hit event across every frame, exactly as a camera ray is from the
camera's (``Shader.trace(k, ...)``: visibility, cut-outs).  Light crossing from the frame it comes
from into frame k is carried by the Doppler factor D between them: radiance times D^4
(RGB), or D^5 at wavelengths multiplied by D (Spectral): the factors multiply along the
path, each path keeping its throughput and its wavelengths in the current frame
(``docs/physics.md``; the world: ``docs/physics-world.md``).

At each vertex the path adds the emission of the surface hit (emissive meshes light
others by being hit), next-event estimates of the lamps (the direct-light code of
:class:`~.shading.Shader`, retarded positions, one formula with the Direct Light
integrator) and of the world (sampled in the world frame, its density carried into
frame k by the aberration Jacobian D^2, weighed against BSDF sampling by the power
heuristic), then scatters.  Bounce limits follow Cycles' Light Paths: a vertex reached
past a limit only adds what the ray found (emission, world), Russian roulette after
``RR_START`` bounces (survival the square root of the throughput, as Cycles'), clamps on each
sample's light after one (direct) and after more (indirect) scatterings.

All paths of a batch advance together (one numpy call per frame and bounce); random
numbers are keyed by (pixel, sample, dimension), so tiles stay independent, and the world
sample and the scattering direction of each vertex are stratified over a pixel's samples
(:func:`~.sampling.stratified_pair`: per sample uniform, together even, as Cycles' sequences).
"""

from __future__ import annotations

import numpy as np

from . import mis, rows, sampling
from .emitters import EmitterTable, LampShape, solid_angle_pdf
from .bsdf import (dielectric_f0, diffuse_pdf, fresnel_average_dielectric, fresnel_dielectric, ggx_dielectric_albedo,
                   ggx_energy_compensation, ggx_glass_albedo, ggx_reflection_pdf, ggx_single_scattering, reflect, refract,
                   sample_diffuse, sample_ggx_reflection, sample_ggx_transmission)
from .passes import hit_doppler, hit_times
from .scene import RAY_ALL, RAY_CAMERA, RAY_DIFFUSE, RAY_GLOSSY, RAY_TRANSMISSION, RenderSettings, Scene
from .shading import _MIN_ALPHA, MIRROR_ROUGHNESS, LayeredLobes, PreparedLight, Shader, _cutout_dimension, hit_uv
from .tracer import Hits, TraceCache, frames_hit, occluded
from .world import EnvironmentWorld, UniformWorld, frame_pdf, mapping_rotation

RR_START = 3  # bounces without Russian roulette
_DIMENSION = 1 << 20  # first random-number dimension of the path tracer (the direct light uses 1000 + ...)
_DIMENSIONS_PER_BOUNCE = 16
_DIFFUSE, _GLOSSY, _MIRROR, _TRANSMIT, _COAT, _COAT_MIRROR = range(6)  # lobes
# bounce counters: 0 total, 1 diffuse, 2 glossy (mirror and coat too), 3 transmission
_KIND_OF_LOBE = np.array([1, 2, 2, 3, 2, 2])
_RAY_OF_LOBE = np.array([RAY_DIFFUSE, RAY_GLOSSY, RAY_GLOSSY, RAY_TRANSMISSION, RAY_GLOSSY,
                         RAY_GLOSSY])  # what the bounce ray is (visibility)
_RAY_KINDS = RAY_ALL + 1  # frame * _RAY_KINDS + ray type: one key per trace of a bounce
_WORLD_STREAM, _EMITTER_STREAM = 6, 7  # cut-out streams of the shadow rays toward the world and the emitters


def scene_world(scene: Scene):
    """The world light of a scene, at rest in the world frame: its environment image or its colour."""
    texture = scene.world_texture
    if texture is None:
        return UniformWorld(scene.world_color)
    return EnvironmentWorld(texture.image, texture.strength, mapping_rotation(texture.rotation, texture.vector_type),
                            texture.interpolation, texture.name)


class PathTracer:
    """Traces camera paths of one prepared scene (thread-safe: read-only state)."""

    def __init__(self, shader: Shader, world, settings: RenderSettings):
        self.shader = shader
        self.frames = shader.frames
        self.materials = shader.materials
        self.colour = shader.colour
        self.world = world
        self.uniform_world = isinstance(world, UniformWorld)
        self.limits = np.array([settings.max_bounces, settings.diffuse_bounces, settings.glossy_bounces,
                                settings.transmission_bounces])
        self.clamp_direct = float(settings.clamp_direct)
        self.clamp_indirect = float(settings.clamp_indirect)
        self.samples = max(int(settings.samples), 1)  # camera samples per pixel: the strata of light samples
        mats = self.materials
        self.emissive = bool(np.any(mats.emission > 0.0))
        self.emitters = _emitter_tables(self.frames, mats) if self.emissive else {}
        power = np.array([table.total for table, _ in self.emitters.values()])
        self.emitter_frames = np.array(list(self.emitters), dtype=np.int64)
        self.emitter_choice = power / power.sum() if len(power) else power  # probability of each frame
        # lamps with an extent, sampled by shadow rays and found by bounce rays (None: a delta lamp)
        self.lamp_shapes = [LampShape.of(pl.light, pl.axes) for pl in shader.lights]
        self.lamps_found = any(shape is not None and shape.use_mis for shape in self.lamp_shapes)
        # a ray past the limits is still traced for what it finds: only worth it if there is something
        self.findable = self.emissive or not world.is_black or self.lamps_found

    def _searchlit(self, values, doppler):
        """Light ``values`` (n,) or (n, C) arriving with Doppler factors ``doppler``, times the
        searchlight factor D^4 (D^5 at lambda D); as they are where every D is 1 (light from the
        receiver's own frame, the common case: no powers to raise)."""
        if not np.any(doppler != 1.0):
            return values
        power = self.shader.searchlight_power(doppler, 4)
        return values * power if np.ndim(values) == 1 else rows.scale(values, power)

    # ------------------------------------------------------------------ paths
    def radiance(self, src: int, tau0, x0, d, s_lo, s_hi, pixel, sample, lam, hits=None,
                 cache: TraceCache | None = None):
        """Radiance (n, C) arriving at events (tau0, x0) of frame src from backward directions d
        (camera rays), at the wavelengths ``lam`` of frame src; ``hits`` if already traced.
        Returns (values, hits of the first rays)."""
        n = len(d)
        if hits is None:
            hits = self.shader.trace(src, tau0, x0, d, s_lo, s_hi, RAY_CAMERA, pixel, sample, 0, cache)
        first_hits = hits
        out = np.zeros((n, self.colour.channels))
        path = np.arange(n)
        state = _Paths(
            src=np.full(n, src, dtype=np.int64), d=np.asarray(d, dtype=np.float64), lam=lam,
            throughput=np.ones((n, self.colour.channels)), pdf=np.full(n, np.inf),
            counts=np.zeros((n, 4), dtype=np.int64), terminal=np.zeros(n, dtype=bool), reference=np.ones(n),
            ray=np.full(n, RAY_CAMERA, dtype=np.int64))
        bounce = 0
        rays = (np.broadcast_to(tau0, (n,)), np.broadcast_to(x0, (n, 3)), state.d, np.broadcast_to(s_lo, (n,)),
                np.broadcast_to(s_hi, (n,)))
        while len(path):
            absorbed = self._add_lamps(out, path, state, rays, hits, bounce) if self.lamps_found else None
            self._add_world(out, path, state, hits, bounce, absorbed)
            path, state, rays = self._vertices(out, path, state, hits, bounce, pixel, sample, cache, absorbed)
            bounce += 1
            if not len(path):
                break
            hits = self._trace(state, *rays, pixel[path], sample[path], bounce, cache)
        return out, first_hits

    def _trace(self, state, tau, origin, d, s_lo, pixel, sample, depth: int, cache):
        """Nearest hits of bounce rays starting in different frames, of different types (one
        trace per frame and type: ray visibility and cut-outs as the shader's)."""
        n = len(d)
        groups = np.unique(state.src * _RAY_KINDS + state.ray)
        if len(groups) == 1:  # one frame and type (the common case): no gathers
            k, ray = divmod(int(groups[0]), _RAY_KINDS)
            return self.shader.trace(k, tau, origin, d, s_lo, np.inf, ray, pixel, sample, depth, cache)
        hits = Hits(frame=np.full(n, -1, dtype=np.int32), s=np.full(n, np.inf), s_frame=np.full(n, np.inf),
                    w=np.ones(n), prim=np.full(n, -1, dtype=np.int32), u=np.zeros(n, dtype=np.float32),
                    v=np.zeros(n, dtype=np.float32), d_frame=d.copy(), tau_frame=tau.copy())
        for k, ray in (divmod(int(group), _RAY_KINDS) for group in groups):
            sel = np.flatnonzero((state.src == k) & (state.ray == ray))
            part = self.shader.trace(k, tau[sel], origin[sel], d[sel], s_lo[sel], np.inf, ray, pixel[sel],
                                     sample[sel], depth, cache)
            for name in ("frame", "s", "s_frame", "w", "prim", "u", "v", "d_frame", "tau_frame"):
                getattr(hits, name)[sel] = getattr(part, name)
        return hits

    # ------------------------------------------------------------------ the world
    def _world_light(self, to_world, d, lam):
        """World radiance arriving along backward directions d of a frame (``to_world``: its map
        to the world frame), in that frame, with the density of :meth:`_sample_world` there."""
        if to_world.is_identity:
            d_world, doppler = d, np.ones(len(d))
        else:
            d_world, w = to_world.rays(d)
            doppler = 1.0 / w  # nu_frame / nu_world
        values = self._world_values(d_world, self.colour.shift(lam, doppler))
        radiance = self._searchlit(values, doppler)
        return radiance, frame_pdf(self.world.pdf(d_world), doppler)

    def _world_values(self, d_world, lam):
        if self.uniform_world:
            return self.colour.world(lam, len(d_world))
        return self.colour.emitter_rgb(self.world.radiance(d_world), lam)

    def _add_world(self, out, path, state, hits, bounce, absorbed=None):
        """What paths leaving the scene bring from the world (MIS-weighted against the world
        samples of the vertex they left), but those a lamp ``absorbed``."""
        miss = np.flatnonzero(hits.frame < 0 if absorbed is None else (hits.frame < 0) & ~absorbed)
        if not len(miss) or self.world.is_black:
            return
        for k in np.unique(state.src[miss]):
            sel = miss[state.src[miss] == k]
            light, pdf_world = self._world_light(self.frames.map(int(k), self.frames.world), state.d[sel],
                                                 _rows(state.lam, sel))
            pdf_bsdf = state.pdf[sel]
            weight = mis.power_heuristic(pdf_bsdf, pdf_world) if bounce else np.ones(len(sel))
            self._accumulate(out, path[sel], state.throughput[sel] * light, weight, bounce)

    def _sample_world(self, k, tau, origin, ng, ns, view, base, mat, mix, eps, pixel, sample, lam, dim, depth,
                      cache):
        """Next-event estimate of the world at vertices of frame k: a direction drawn from the
        world's own density in the world frame, seen from frame k (density times D^2)."""
        u1, u2 = sampling.stratified_pair(pixel, sample, self.samples, dim)
        d_world, pdf = self.world.sample(u1, u2)
        to_frame = self.frames.map(self.frames.world, k)
        if to_frame.is_identity:
            light, doppler = d_world, np.ones(len(u1))
        else:
            light, doppler = to_frame.rays(d_world)  # w = nu_k / nu_world = D
        pdf = frame_pdf(pdf, doppler)
        cos = rows.dot(ns, light)
        sel = np.flatnonzero((cos > 0.0) & (rows.dot(ng, light) > 0.0) & (pdf > 0.0))
        total = np.zeros((len(u1), self.colour.channels))
        if not len(sel):
            return total
        blocked = occluded(self.frames, k, tau[sel], origin[sel], light[sel], eps, np.inf, cache,
                           see_through=self.shader.cutouts(sampling.Samples(pixel, sample).take(sel),
                                                           _cutout_dimension(depth, _WORLD_STREAM)))
        sel = sel[~blocked]
        if not len(sel):
            return total
        f = mix.value(light[sel], sel)
        values = self._world_values(d_world[sel], self.colour.shift(_rows(lam, sel), doppler[sel]))
        values = self._searchlit(values, doppler[sel])
        mis_weight = mis.power_heuristic(pdf[sel], mix.pdf(sel, ns[sel], view[sel], light[sel], cos[sel]))
        weight = mis_weight * cos[sel] / pdf[sel]
        total[sel] = rows.scale(f * values, weight)
        return total

    # ------------------------------------------------------------------ lamps
    def _lamp_view(self, pl: PreparedLight, k, tau, position):
        """A lamp seen from events of frame k, in its rest frame (an animated lamp's momentary rest
        frame at the retarded event of each, as the shadow rays see it): the events there, the
        lamp's place, the maps of backward directions from frame k there and back (each with its
        path-length ratio s_to / s_from) and the lamp's clock minus that frame's time."""
        if pl.light.trajectory is not None:
            tau_j, x_j, centre, back, clock_zero, forward = self.shader._momentary(pl, k, tau, position)
            return tau_j, x_j, centre, forward, back, clock_zero
        into = self.frames.map(k, pl.frame)
        tau_j, x_j = into.events(tau, position)
        return (tau_j, x_j, np.broadcast_to(pl.position, (len(tau), 3)), into.rays, self.frames.map(pl.frame, k).rays,
                pl.clock_offset)

    def _lamp_clock(self, pl: PreparedLight, tau_j, x_j, length, clock_zero):
        """The lamp's own clock (c*t) when it sent light reaching events (tau_j, x_j) of its frame
        from path length ``length`` there (None unless its output is keyed; a sun's plane wave
        passed the lamp's place (P - x).e before reaching x)."""
        if pl.keyed is None:
            return None
        if pl.light.kind == "SUN":
            return tau_j - (pl.position - x_j) @ pl.axes[:, 2] + pl.clock_offset
        return tau_j - length + clock_zero

    def _sample_lamps(self, k, tau, position, ng, ns, view, base, mat, lobes, depth, pixel, sample, lam, cache):
        """Next-event estimate of the lamps at vertices of frame k: a delta lamp by the direct-light
        integrator's shadow ray (:meth:`~.shading.Shader._incident`), a lamp with an extent by a
        direction drawn from its shape in its rest frame (:class:`~.emitters.LampShape`), density
        carried into frame k by D^2, radiance by D^4 (D^5 at lambda D), weighed against the bounce
        rays that find it by the power heuristic."""
        shader = self.shader
        eps = shader.epsilon[k]
        origin = position + eps * ng
        total = np.zeros_like(base)
        for index, (pl, shape) in enumerate(zip(shader.lights, self.lamp_shapes)):
            dim = 1000 + 100 * depth + 4 * index  # the direct-light integrator's dimensions
            if shape is None:  # a delta lamp (or an area lamp of no area: a point of it)
                xi1 = xi2 = None
                if pl.sampled:
                    xi1, xi2 = sampling.uniform(pixel, sample, dim), sampling.uniform(pixel, sample, dim + 1)
                e_k, strength, doppler, s_max, clock = shader._incident(pl, k, tau, position, xi1, xi2)
                s_max = np.broadcast_to(s_max, (len(tau),))  # one number for a sun
            else:
                u1, u2 = sampling.uniforms(pixel, sample, (dim, dim + 1))
                tau_j, x_j, centre, _, back, clock_zero = self._lamp_view(pl, k, tau, position)
                e_j = shape.sample(centre, x_j, u1, u2)
                length, pdf_j, radiance = shape.hit(centre, x_j, e_j)
                e_k, doppler = back(e_j)  # s_k / s_lamp: the Doppler factor of the lamp seen here
                pdf = frame_pdf(pdf_j, doppler)
                strength = np.where(pdf > 0.0, self._searchlit(radiance, doppler)
                                    / np.where(pdf > 0.0, pdf, 1.0), 0.0)
                s_max = doppler * length
                clock = self._lamp_clock(pl, tau_j, x_j, length, clock_zero)
            cos = rows.dot(ns, e_k)
            sel = np.flatnonzero((cos > 0.0) & (rows.dot(ng, e_k) > 0.0) & (strength > 0.0))
            if not len(sel):
                continue
            e_sel = rows.take(e_k, sel)
            blocked = occluded(self.frames, k, tau[sel], rows.take(origin, sel), e_sel, eps, s_max[sel] - 2.0 * eps,
                               cache, see_through=shader.cutouts(sampling.Samples(pixel, sample).take(sel),
                                                                 _cutout_dimension(depth, 8 + index)))
            if blocked.any():
                lit = np.flatnonzero(~blocked)
                sel, e_sel = sel[lit], rows.take(e_sel, lit)
            if not len(sel):
                continue
            cos_sel = cos[sel]
            weight = strength[sel] * cos_sel
            if shape is not None and shape.use_mis:
                weight = weight * mis.power_heuristic(pdf[sel], lobes.pdf(sel, rows.take(ns, sel), rows.take(view, sel),
                                                                          e_sel, cos_sel))
            f = lobes.value(e_sel, sel)
            emitted = self.colour.light(index, self.colour.shift(_rows(lam, sel), doppler[sel]), len(sel),
                                        None if clock is None else clock[sel])
            total[sel] += rows.scale(f * emitted, weight)
        return total

    def _add_lamps(self, out, path, state, rays, hits, bounce):
        """What camera and bounce rays ``rays`` (tau, origin, d, s_lo, ...) of the paths find of the
        lamps with an extent that they see (MIS-weighted against the lamp samples of the vertex they
        left): a sphere or area lamp nearer than the surface hit ends its path there, a sun adds
        to the world where the ray leaves the scene.  Returns which paths a lamp ended (None: none)."""
        tau, origin, d, s_lo = rays[:4]
        n = len(path)
        nearest = hits.s.copy() if len(rays) < 5 else np.minimum(hits.s, rays[4])
        found = np.zeros((n, self.colour.channels))
        absorbed = np.zeros(n, dtype=bool)
        lit = np.zeros(n, dtype=bool)
        found_by = [i for i, shape in enumerate(self.lamp_shapes) if shape is not None and shape.use_mis]
        for index in sorted(found_by, key=lambda i: self.lamp_shapes[i].is_sun):  # suns last: behind the others
            pl, shape = self.shader.lights[index], self.lamp_shapes[index]
            seen = (state.ray & shape.visibility) != 0
            if shape.is_sun:
                seen &= (hits.frame < 0) & ~absorbed
            for k in np.unique(state.src[seen]):
                sel = np.flatnonzero(seen & (state.src == k))
                tau_j, x_j, centre, forward, _, clock_zero = self._lamp_view(pl, int(k), tau[sel], origin[sel])
                d_j, ratio = forward(d[sel])  # s_lamp / s_k
                length, pdf_j, radiance = shape.hit(centre, x_j, d_j)
                hit = pdf_j > 0.0
                if not shape.is_sun:
                    s_k = length / ratio
                    hit &= (s_k > s_lo[sel]) & (s_k < nearest[sel])
                    nearest[sel[hit]] = s_k[hit]  # a nearer lamp hides a farther one
                sel, d_j, ratio, length, pdf_j, radiance, tau_j, x_j = (
                    a[hit] for a in (sel, d_j, ratio, length, pdf_j, radiance, tau_j, x_j))
                if not len(sel):
                    continue
                doppler = 1.0 / ratio  # nu_k / nu_lamp
                clock = self._lamp_clock(pl, tau_j, x_j, length, clock_zero)
                emitted = self.colour.light(index, self.colour.shift(_rows(state.lam, sel), doppler), len(sel), clock)
                weight = radiance * self.shader.searchlight_power(doppler, 4) * mis.power_heuristic(
                    state.pdf[sel], frame_pdf(pdf_j, doppler))
                value = state.throughput[sel] * rows.scale(np.asarray(emitted, dtype=np.float64), weight)
                lit[sel] = True
                if shape.is_sun:
                    found[sel] += value
                else:  # the nearest lamp so far: replaces what a farther one gave
                    found[sel] = value
                    absorbed[sel] = True
        lit = np.flatnonzero(lit)
        if len(lit):
            self._accumulate(out, path[lit], found[lit], None, bounce)
        return absorbed if absorbed.any() else None

    # ------------------------------------------------------------------ emissive surfaces
    def _emitter_pdf(self, j, prim, distance, cos_emit, doppler):
        """Density per unit solid angle of the receiving frame with which :meth:`_sample_emitters`
        draws points of triangles ``prim`` of frame j seen at path length ``distance`` (frame j)
        under ``cos_emit``, their light's Doppler factor ``doppler`` (frame j to the receiver)."""
        table, rows_of_prim = self.emitters[j]
        row = rows_of_prim[prim]
        choice = self.emitter_choice[np.searchsorted(self.emitter_frames, j)]
        pdf_area = np.where(row >= 0, table.pdf_area(np.maximum(row, 0)), 0.0)
        cos = np.abs(cos_emit)
        pdf = np.where(cos > 0.0, choice * pdf_area * distance**2 / np.maximum(cos, 1e-300), 0.0)
        return frame_pdf(pdf, doppler)

    def _sample_emitters(self, k, tau, origin, ng, ns, view, base, mat, lobes, pixel, sample, lam, dim, depth,
                         cache):
        """Next-event estimate of the emissive triangles: a frame of emitters drawn by power, a
        triangle by area x luminance and a point on it.  An emitter is static in its frame: the
        hit event mapped there sees it where it is (its retarded position), as a lamp."""
        n = len(tau)
        total = np.zeros((n, self.colour.channels))
        pick = np.minimum(np.searchsorted(np.cumsum(self.emitter_choice), sampling.uniform(pixel, sample, dim),
                                          side="right"), len(self.emitter_frames) - 1)
        for slot, j in enumerate(self.emitter_frames):
            sel = np.flatnonzero(pick == slot)
            if not len(sel):
                continue
            table, _ = self.emitters[int(j)]
            row, point, normal, pdf_area = table.sample(sampling.uniform(pixel[sel], sample[sel], dim + 1),
                                                        sampling.uniform(pixel[sel], sample[sel], dim + 2),
                                                        sampling.uniform(pixel[sel], sample[sel], dim + 3))
            tau_j, x_j = self.frames.map(k, int(j)).events(tau[sel], origin[sel])
            e_j, r_j, pdf_j = solid_angle_pdf(pdf_area, x_j, point, normal)
            light, doppler = self.frames.map(int(j), k).rays(e_j)  # w = nu_k / nu_j: D of the emitter seen here
            pdf = frame_pdf(self.emitter_choice[slot] * pdf_j, doppler)
            cos = rows.dot(ns[sel], light)
            ok = (cos > 0.0) & (rows.dot(ng[sel], light) > 0.0) & (pdf > 0.0)
            sel, light, doppler, pdf, cos, r_j, tau_j = (a[ok] for a in (sel, light, doppler, pdf, cos, r_j, tau_j))
            row = row[ok]
            if not len(sel):
                continue
            eps = self.shader.epsilon[k]
            reach = doppler * r_j * (1.0 - 1e-6) - 2.0 * eps  # stop short of the emitter itself
            see_through = self.shader.cutouts(sampling.Samples(pixel, sample).take(sel),
                                              _cutout_dimension(depth, _EMITTER_STREAM))
            blocked = occluded(self.frames, k, tau[sel], origin[sel], light, eps, reach, cache,
                               see_through=see_through)
            sel, light, doppler, pdf, cos, r_j, tau_j, row = (a[~blocked] for a in
                                                               (sel, light, doppler, pdf, cos, r_j, tau_j, row))
            if not len(sel):
                continue
            emitter_mat = self.materials.clamp(self.frames.frames[int(j)].geometry.tri_material[table.prims[row]])
            emitted = np.array(self.colour.emission(emitter_mat, self.colour.shift(_rows(lam, sel), doppler)),
                               dtype=np.float64)
            if self.materials.emission_curves:  # the emitter's clock when the light left it
                clock = self.frames.frames[int(j)].object_clock(tau_j - r_j, table.prims[row])
                emitted *= self.materials.emission_factor(emitter_mat, clock)[:, None]
            emitted = self._searchlit(emitted, doppler)
            f = lobes.value(light, sel)
            weight = mis.power_heuristic(pdf, lobes.pdf(sel, ns[sel], view[sel], light, cos)) * cos / pdf
            total[sel] = rows.scale(f * emitted, weight)
        return total

    # ------------------------------------------------------------------ vertices
    def _vertices(self, out, path, state, hits, bounce, pixel, sample, cache, absorbed=None):
        """Light at the surfaces hit and the scattered rays that continue the paths (but those a
        lamp ``absorbed`` before the surface: they add nothing and end there)."""
        pieces = []
        held = self.shader.held_out(hits) if self.shader.has_holdouts else None  # holdouts end paths, dark
        for k in frames_hit(hits):
            sel = np.flatnonzero(hits.frame == k if held is None else (hits.frame == k) & ~held)
            if not len(sel):
                continue
            if len(sel) == len(path):  # every path is here (one frame hit, the common case): no gathers
                piece = self._vertex(int(k), out, path, state, hits, bounce, pixel[path], sample[path], cache,
                                     absorbed)
            else:
                piece = self._vertex(int(k), out, path[sel], state.take(sel), hits.take(sel), bounce,
                                     pixel[path[sel]], sample[path[sel]], cache, _rows(absorbed, sel))
            if piece is not None:
                pieces.append(piece)
        if not pieces:
            return path[:0], state, None
        path = np.concatenate([p[0] for p in pieces])
        state = _Paths.join([p[1] for p in pieces])
        rays = tuple(np.concatenate([p[2][i] for p in pieces]) for i in range(4))
        return path, state, rays

    def _vertex(self, k, out, path, state, hits, bounce, pixel, sample, cache, absorbed):
        shader, mats, colour = self.shader, self.materials, self.colour
        frame = self.frames.frames[k]
        d_k, tau = hits.d_frame, hit_times(hits, slice(None))
        prim, u, v = hits.prim, hits.u, hits.v
        doppler = hit_doppler(frame, prim, u, v, tau, d_k, hits.w)
        if np.any(doppler != 1.0):
            throughput = rows.scale(state.throughput, shader.searchlight_power(doppler, 4))
            lam = colour.shift(state.lam, doppler)
        else:  # light from the frame the ray started in (the common case): D = 1 exactly, nothing to scale
            throughput, lam = state.throughput, state.lam
        if absorbed is not None:  # (kept along, not gathered out: they bring nothing more)
            throughput = throughput.copy() if throughput is state.throughput else throughput
            throughput[absorbed] = 0.0
        if bounce == 0:  # Russian roulette compares throughputs with the camera hit's
            state.reference = np.maximum(throughput.max(axis=1), 1e-300)
        position, ng, ns, mat, back = shader.surface_info(k, prim, u, v, d_k, tau)
        uv = hit_uv(frame, prim, u, v)
        if self.emissive:
            emitted = np.array(colour.emission(mat, lam), dtype=np.float64)
            if mats.emission_curves:
                emitted *= mats.emission_factor(mat, frame.object_clock(tau, prim))[:, None]
            weight = None
            if bounce and k in self.emitters:  # also drawn by the emitter samples of the last vertex
                pdf_light = self._emitter_pdf(k, prim, hits.s_frame, rows.dot(frame.geometry.face_normals(prim), d_k),
                                              doppler)
                weight = mis.power_heuristic(state.pdf, pdf_light)
            self._accumulate(out, path, throughput * emitted, weight, bounce)
        live = np.flatnonzero(~state.terminal)
        if not len(live):
            return None
        if len(live) < len(path):  # (all live, the common case: no gathers)
            keep = lambda a: a[live] if a is not None else None  # noqa: E731
            path, throughput, lam, state, uv = path[live], throughput[live], keep(lam), state.take(live), keep(uv)
            d_k, tau, position, ng, ns, mat, back = d_k[live], tau[live], position[live], ng[live], ns[live], \
                mat[live], back[live]
            pixel, sample = pixel[live], sample[live]
        base = colour.base_color(mat, uv, lam)
        view = -d_k
        eps = shader.epsilon[k]
        origin = position + eps * ng
        lobes = _Lobes(mats, base, mat, ns, view, back)
        dim = _DIMENSION + _DIMENSIONS_PER_BOUNCE * bounce
        # next-event estimation: lamps (the direct-light integrator's own code) and the world
        direct = None
        if shader.lights:
            direct = self._sample_lamps(k, tau, position, ng, ns, view, base, mat, lobes, bounce, pixel, sample, lam,
                                        cache)
        if not self.world.is_black and lobes.any_smooth:
            world = self._sample_world(k, tau, origin, ng, ns, view, base, mat, lobes, eps, pixel, sample, lam,
                                       dim + 10, bounce, cache)
            direct = world if direct is None else direct + world
        if self.emitters and lobes.any_smooth:
            glow = self._sample_emitters(k, tau, origin, ng, ns, view, base, mat, lobes, pixel, sample, lam,
                                         dim + 6, bounce, cache)
            direct = glow if direct is None else direct + glow
        if direct is not None:
            self._accumulate(out, path, throughput * direct, None, bounce + 1)
        # scattering: one lobe chosen by its weight, a direction from its sampler
        lobe, probability = lobes.choose(sampling.uniform(pixel, sample, dim))
        u1, u2 = sampling.stratified_pair(pixel, sample, self.samples, dim + 1)
        light, weight, pdf = lobes.sample(lobe, probability, u1, u2)
        transmitted = lobe == _TRANSMIT
        side = np.where(transmitted, -1.0, 1.0)
        valid = (probability > 0.0) & (rows.dot(ng, light) * side > 0.0) & np.any(weight > 0.0, axis=1)
        counts = state.counts.copy()
        counts[:, 0] += 1
        kind = _KIND_OF_LOBE[lobe]
        counts[np.arange(len(kind)), kind] += 1
        terminal = (counts[:, 0] > self.limits[0]) | (counts[np.arange(len(kind)), kind] > self.limits[kind])
        throughput = throughput * weight
        if bounce + 1 > RR_START:  # Russian roulette, Cycles' survival: sqrt of the throughput (relative here)
            survive = np.clip(np.sqrt(throughput.max(axis=1) / state.reference), 0.0, 1.0)
            valid &= sampling.uniform(pixel, sample, dim + 5) < survive
            throughput = rows.scale(throughput, 1.0 / np.where(survive > 0.0, survive, 1.0))
        if not self.findable:
            valid &= ~terminal
        if absorbed is not None:
            valid &= ~absorbed
        go = np.flatnonzero(valid)
        if not len(go):
            return None
        if len(go) < len(path):  # (every path goes on: no gathers)
            path, tau, position, ng, side, light, lam, throughput, pdf, counts, terminal, reference, lobe = (
                None if a is None else a[go] for a in (path, tau, position, ng, side, light, lam, throughput, pdf,
                                                       counts, terminal, state.reference, lobe))
        else:
            reference = state.reference
        ray_origin = position + rows.scale(ng, side * eps)
        nxt = _Paths(src=np.full(len(go), k, dtype=np.int64), d=light, lam=lam, throughput=throughput, pdf=pdf,
                     counts=counts, terminal=terminal, reference=reference, ray=_RAY_OF_LOBE[lobe])
        return path, nxt, (tau, ray_origin, light, np.full(len(go), eps))

    # ------------------------------------------------------------------ accumulation
    def _accumulate(self, out, path, values, weight, scatterings: int):
        """Add light to the paths' camera samples: ``scatterings`` = how often the light has
        scattered (0: seen directly, unclamped; 1: direct light; more: indirect)."""
        if weight is not None:
            values = rows.scale(values, weight)
        limit = 0.0 if scatterings == 0 else self.clamp_direct if scatterings == 1 else self.clamp_indirect
        if limit > 0.0:
            total = np.abs(self.colour.to_rgb(values, None)).sum(axis=1)
            values = rows.scale(values, np.minimum(1.0, limit / np.maximum(total, 1e-300)))
        out[path] += values  # a path is one camera sample: no index repeats


def _emitter_tables(frames, mats) -> dict:
    """frame -> (EmitterTable of its emissive triangles in frame coordinates, table row of each
    triangle or -1), for the frames where emitters stay put: inertial, not spinning (emitters
    of spinning or accelerated bodies light others only when bounce rays hit them)."""
    tables = {}
    for k in frames.geometry:
        frame = frames.frames[k]
        if frame.spin is not None or frame.window is not None:
            continue
        geometry = frame.geometry
        emission = mats.emission[mats.clamp(geometry.tri_material)]
        prims = np.flatnonzero(np.any(emission > 0.0, axis=1))
        if not len(prims):
            continue
        corners = geometry.vertices[geometry.triangles[prims]] + frame.offset
        table = EmitterTable(corners, emission[prims], prims)
        if table.is_empty:
            continue
        rows_of_prim = np.full(len(geometry.triangles), -1, dtype=np.int64)
        rows_of_prim[prims] = np.arange(len(prims))
        tables[k] = (table, rows_of_prim)
    return tables


class _Paths:
    """The state of live paths (rows): the frame their next ray starts in and its direction,
    wavelengths in that frame (None: RGB), throughput, the BSDF density of the direction (inf:
    a delta lobe or a camera ray), bounce counters, whether the next vertex is past the limits,
    the Russian roulette reference throughput and the ray's type (``RAY_*``)."""

    __slots__ = ("src", "d", "lam", "throughput", "pdf", "counts", "terminal", "reference", "ray")

    def __init__(self, src, d, lam, throughput, pdf, counts, terminal, reference, ray):
        self.src, self.d, self.lam, self.throughput = src, d, lam, throughput
        self.pdf, self.counts, self.terminal, self.reference, self.ray = pdf, counts, terminal, reference, ray

    def take(self, index) -> "_Paths":
        return _Paths(*(None if getattr(self, name) is None else getattr(self, name)[index]
                        for name in self.__slots__))

    @staticmethod
    def join(parts) -> "_Paths":
        return _Paths(*(None if getattr(parts[0], name) is None else np.concatenate([getattr(p, name) for p in parts])
                        for name in _Paths.__slots__))


class _Lobes(LayeredLobes):
    """The surfaces' lobes at some vertices with the weights that choose among them: diffuse,
    rough specular (multiscatter GGX), mirror and refraction (:class:`~.shading.LayeredLobes`):
    Snell's through smooth glass, GGX microfacet transmission (Walter et al. 2007) through rough
    glass, whose reflection and refraction are scaled by 1 / their single-scattering albedo as
    Cycles' multiscatter glass preserves energy (mixed by Transmission with the opaque
    dielectric's compensation of the reflection).  Transmitted light is found by the refracted
    rays alone (no samples of lights through the surface), so their MIS density is that of a
    delta lobe.  A coat (Coat Weight) is a clear dielectric layer over all of it, as Cycles'
    Principled BSDF: a multiscatter GGX lobe (or a mirror below ``MIRROR_ROUGHNESS``) of the
    coat's IOR, which dims everything under it by 1 - weight x its directional albedo."""

    def __init__(self, mats, base, mat, ns, view, back):
        super().__init__(mats, base, mat, ns, view, back)
        share = mats.transmission[mat]
        self.transmission = share * (1.0 - self.metallic)
        self.glass_compensation = np.broadcast_to(1.0, (len(mat),))
        rough = np.flatnonzero((share > 0.0) & ~self.mirror)
        if len(rough):
            self.glass_compensation = np.ones(len(mat))
            self.glass_compensation[rough] = 1.0 / np.maximum(
                ggx_glass_albedo(self.cos_v[rough], self.alpha[rough], self.eta[rough]), 1e-6)
            mixed = rows.scale(self.compensation_dielectric[rough], 1.0 - share[rough])
            self.compensation_dielectric = self.compensation_dielectric.copy()
            self.compensation_dielectric[rough] = mixed + (share[rough] * self.glass_compensation[rough])[:, None]
        coat_albedo = self._coat(mats, mat)
        # the weights that choose a lobe, worked out for the lobes some point has (the others: 0)
        glossy = np.flatnonzero(self.glossy)
        weights = [(_DIFFUSE, (self.diffuse * np.pi).mean(axis=1))]
        if len(glossy):
            glossy_albedo = np.zeros(self.base.shape)
            glossy_albedo[glossy] = self.fresnel(self.cos_v[glossy], index=glossy)
            weights.append((_GLOSSY, glossy_albedo.mean(axis=1)))
        if self.mirror.any():
            weights.append((_MIRROR, self.reflect_weight.mean(axis=1)))
        if np.any(self.transmission > 0.0):
            weights.append((_TRANSMIT, self.transmit_weight.mean(axis=1)))
        if self.coat_rough.any():
            weights.append((_COAT, np.where(self.coat_rough, coat_albedo, 0.0)))
        if self.coat_mirror.any():
            weights.append((_COAT_MIRROR, np.where(self.coat_mirror, coat_albedo, 0.0)))
        weights = [(lobe, np.maximum(weight, 0.0)) for lobe, weight in weights]
        total = weights[0][1].copy()
        for _, weight in weights[1:]:
            total += weight
        scatters = total > 0.0
        total[~scatters] = 1.0
        self.lobes_present = [lobe for lobe, _ in weights]  # (of the whole batch: not an array of points)
        self.probability = np.zeros((len(mat), len(_KIND_OF_LOBE)))
        for lobe, weight in weights:
            self.probability[:, lobe] = np.where(scatters, weight / total, 0.0)
        self.any_smooth = bool(np.any(self.probability[:, [_DIFFUSE, _GLOSSY, _COAT]].sum(axis=1) > 0.0))

    def _coat(self, mats, mat):
        """Sets up the coat layer (none on the inside of a transmissive body) and dims the lobes
        under it; returns its directional albedo (n,), weight included."""
        n = len(mat)
        self.coat = np.where(self.eta > 1.0, 0.0, mats.coat_weight[mat])
        coated = self.coat > 0.0
        self.coat_rough = coated & (mats.coat_roughness[mat] >= MIRROR_ROUGHNESS)
        self.coat_mirror = coated & ~self.coat_rough
        self.coat_alpha = np.maximum(mats.coat_roughness[mat] ** 2, _MIN_ALPHA)
        self.coat_eta = 1.0 / mats.coat_ior[mat]
        self.coat_compensation = np.broadcast_to(1.0, (n,))
        albedo = np.zeros(n)
        if not coated.any():
            return albedo
        self.coat_compensation = np.ones(n)
        rough = np.flatnonzero(self.coat_rough)
        if len(rough):
            ior, cos_v, alpha = mats.coat_ior[mat[rough]], self.cos_v[rough], self.coat_alpha[rough]
            albedo[rough] = ggx_dielectric_albedo(cos_v, alpha, 1.0 / ior, dielectric_f0(ior)[:, None],
                                                  np.ones(len(rough)))[:, 0]
            self.coat_compensation[rough] = ggx_energy_compensation(cos_v, alpha,
                                                                    fresnel_average_dielectric(ior)[:, None])[:, 0]
        smooth = np.flatnonzero(self.coat_mirror)
        albedo[smooth] = fresnel_dielectric(self.cos_v[smooth], self.coat_eta[smooth])
        albedo *= self.coat
        under = (1.0 - albedo)[:, None]
        self.diffuse = self.diffuse * under
        self.compensation_dielectric = self.compensation_dielectric * under
        self.compensation_metal = self.compensation_metal * under
        self.reflect_weight = self.reflect_weight * under
        self.transmit_weight = self.transmit_weight * under
        self.glass_compensation = self.glass_compensation * under[:, 0]
        return albedo

    def _coat_specular(self, index, light):
        """The rough coat's f (without the cosine) at vertices ``index`` toward ``light``."""
        single, above, cos_vh = ggx_single_scattering(self.ns[index], self.view[index], light, self.coat_alpha[index])
        fresnel = fresnel_dielectric(cos_vh, self.coat_eta[index])
        return np.where(above, self.coat[index] * self.coat_compensation[index] * fresnel * single, 0.0)

    def value(self, light, index=None):
        """f (n, C) without the cosine: the lobes under the coat and the rough coat; at the points
        ``index`` (default: all), one light direction each."""
        value = super().value(light, index)
        r = np.flatnonzero(self.coat_rough if index is None else self.coat_rough[index])
        if len(r):
            value[r] += self._coat_specular(r if index is None else index[r], light[r])[:, None]
        return value

    def pdf(self, index, ns, view, light, cos=None):
        """Density per unit solid angle with which :meth:`sample` draws ``light`` at vertices
        ``index`` (the non-delta lobes, each times its probability); ``cos``: ns . light if known."""
        probability = self.probability
        pdf = probability[index, _DIFFUSE] * diffuse_pdf(ns, light, cos)
        glossy = np.flatnonzero(self.glossy[index])
        if len(glossy):
            at = index[glossy]
            pdf[glossy] += probability[at, _GLOSSY] * ggx_reflection_pdf(ns[glossy], view[glossy], light[glossy],
                                                                         self.alpha[at])
        coat = np.flatnonzero(self.coat_rough[index])
        if len(coat):
            at = index[coat]
            pdf[coat] += probability[at, _COAT] * ggx_reflection_pdf(ns[coat], view[coat], light[coat],
                                                                     self.coat_alpha[at])
        return pdf

    def choose(self, u):
        """A lobe per vertex drawn by the weights, and its probability (0: nothing scatters; past
        the last lobe some point has: the last lobe, of probability 0 there)."""
        cdf = np.cumsum(self.probability[:, self.lobes_present], axis=1)  # (the absent lobes add 0)
        lobe = np.array(self.lobes_present + [len(_KIND_OF_LOBE) - 1])[(u[:, None] >= cdf).sum(axis=1)]
        return lobe, self.probability[np.arange(len(lobe)), lobe]

    def sample(self, lobe, probability, u1, u2):
        """Directions from each vertex's chosen lobe: (light, weight f cos / (pdf probability)
        (n, C), density for MIS against the world samples (inf for the delta lobes))."""
        ns, view = self.ns, self.view
        n = len(lobe)
        light = np.zeros((n, 3))
        weight = np.zeros(self.base.shape)
        pdf = np.full(n, np.inf)
        scale = 1.0 / np.where(probability > 0.0, probability, 1.0)
        sel = np.flatnonzero(lobe == _DIFFUSE)
        if len(sel) == n:  # every vertex scatters diffusely (the common case): no gathers
            light, _ = sample_diffuse(ns, u1, u2)
            return light, rows.scale(self.diffuse, np.pi * scale), self.pdf(sel, ns, view, light)
        if len(sel):
            light[sel], _ = sample_diffuse(ns[sel], u1[sel], u2[sel])
            weight[sel] = rows.scale(self.diffuse[sel], np.pi * scale[sel])  # f cos / pdf = f pi
        sel = np.flatnonzero(lobe == _GLOSSY)
        if len(sel):
            light[sel], _, g = sample_ggx_reflection(ns[sel], view[sel], self.alpha[sel], u1[sel], u2[sel])
            h = rows.normalized(view[sel] + light[sel])
            fresnel = self.fresnel(rows.dot(view[sel], h), index=sel)
            weight[sel] = rows.scale(fresnel, g * scale[sel])
        sel = np.flatnonzero(lobe == _MIRROR)
        if len(sel):
            light[sel] = reflect(view[sel], ns[sel])
            weight[sel] = rows.scale(self.reflect_weight[sel], scale[sel])
        sel = np.flatnonzero((lobe == _TRANSMIT) & self.mirror)
        if len(sel):
            light[sel], ok = refract(view[sel], ns[sel], self.eta[sel])
            weight[sel] = rows.scale(self.transmit_weight[sel], np.where(ok, scale[sel], 0.0))
        sel = np.flatnonzero((lobe == _TRANSMIT) & ~self.mirror)
        if len(sel):
            light[sel], through = sample_ggx_transmission(ns[sel], view[sel], self.eta[sel], self.alpha[sel], u1[sel],
                                                          u2[sel])
            weight[sel] = (through * self.transmission[sel] * self.glass_compensation[sel] * scale[sel])[:, None]
        sel = np.flatnonzero(lobe == _COAT)
        if len(sel):
            light[sel], _, g = sample_ggx_reflection(ns[sel], view[sel], self.coat_alpha[sel], u1[sel], u2[sel])
            fresnel = fresnel_dielectric(rows.dot(view[sel], rows.normalized(view[sel] + light[sel])),
                                         self.coat_eta[sel])
            weight[sel] = (self.coat[sel] * self.coat_compensation[sel] * fresnel * g * scale[sel])[:, None]
        sel = np.flatnonzero(lobe == _COAT_MIRROR)
        if len(sel):
            light[sel] = reflect(view[sel], ns[sel])
            fresnel = fresnel_dielectric(self.cos_v[sel], self.coat_eta[sel])
            weight[sel] = (self.coat[sel] * fresnel * scale[sel])[:, None]
        smooth = np.flatnonzero((lobe == _DIFFUSE) | (lobe == _GLOSSY) | (lobe == _COAT))
        if len(smooth):
            pdf[smooth] = self.pdf(smooth, ns[smooth], view[smooth], light[smooth])
        return light, weight, pdf


def _rows(lam, index):
    return None if lam is None else lam[index]

"""Section 4: what a scene does not use it does not pay for.

(a) a static scene against a plain (non-relativistic) embreex ray tracer with the same shading;
(b) Doppler display modes: OFF must do no spectral work;
(c) no lights: no shadow rays (counted, not timed).
"""

from __future__ import annotations

import numpy as np

from bench_common import Goal, Section, ball_scene, interleaved, look_at_camera, quad, settings, uv_sphere
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh
from restframe_addon.core import spectral, tracer
from restframe_addon.core.camera import primary_rays
from restframe_addon.core.prepared import prepare
from restframe_addon.core.render import render_image, render_tiles
from restframe_addon.core.scene import Light, Material, Mesh, Scene


class PlainTracer:
    """An ordinary ray tracer on one embreex scene: primary rays, Lambert, point lights, shadow rays.

    The same camera model as RESTframe (``core.camera.primary_rays``), the same square tiles.
    """

    def __init__(self, meshes, lights, albedo, world):
        verts = np.concatenate([m[0] for m in meshes])
        offsets = np.cumsum([0] + [len(m[0]) for m in meshes[:-1]])
        tris = np.concatenate([m[1] + o for m, o in zip(meshes, offsets)])
        self.scene = rtcore_scene.EmbreeScene()
        TriangleMesh(self.scene, verts.astype(np.float32), tris.astype(np.int32))
        self.scene.run(np.zeros((1, 3), np.float32), np.array([[1, 0, 0]], np.float32))  # commit
        tri = verts[tris]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        self.normals = n / np.linalg.norm(n, axis=1, keepdims=True)
        self.lights = lights  # [(position, power)]
        self.albedo = np.asarray(albedo, float)
        self.world = np.asarray(world, float)
        self.eps = 1e-5 * float(np.max(verts.max(axis=0) - verts.min(axis=0)))

    def render(self, camera, res, tile):
        image = np.zeros((res[1], res[0], 3))
        for y0 in range(0, res[1], tile):
            for x0 in range(0, res[0], tile):
                y1, x1 = min(y0 + tile, res[1]), min(x0 + tile, res[0])
                ys, xs = np.mgrid[y0:y1, x0:x1]
                o, d, _, _, _ = primary_rays(camera, xs.ravel() + 0.5, ys.ravel() + 0.5, res)
                image[y0:y1, x0:x1] = self.shade(o, d).reshape(y1 - y0, x1 - x0, 3)
        return image

    def shade(self, o, d):
        out = self.scene.run(o.astype(np.float32), d.astype(np.float32), output=1)
        hit = np.flatnonzero(out["primID"] >= 0)
        rgb = np.tile(self.world, (len(d), 1))
        p = o[hit] + out["tfar"][hit, None].astype(np.float64) * d[hit]
        n = self.normals[out["primID"][hit]]
        n = n * -np.sign(np.einsum("ij,ij->i", n, d[hit]))[:, None]
        total = np.zeros(len(hit))
        for position, power in self.lights:
            to_light = np.asarray(position) - p
            r = np.linalg.norm(to_light, axis=1)
            l_dir = to_light / r[:, None]
            cos = np.einsum("ij,ij->i", n, l_dir)
            lit = np.flatnonzero(cos > 0)
            start = (p[lit] + self.eps * n[lit]).astype(np.float32)
            blocked = self.scene.run(start, l_dir[lit].astype(np.float32), dists=(r[lit] - 2 * self.eps).astype(np.float32),
                                     query="OCCLUDED") >= 0
            lit = lit[~blocked]
            total[lit] += power / (4 * np.pi) * cos[lit] / r[lit] ** 2
        rgb[hit] = self.albedo / np.pi * total[:, None]
        return rgb


def static_scene():
    """The static test scene, and a function that builds the plain tracer for it."""
    res_camera = look_at_camera((0.5, -7.0, 2.0), (0.0, 0.0, 0.3), aspect=4 / 3)
    ball = uv_sphere((0.0, 0.0, 0.5), 1.0, 128, 64)
    floor = quad((0.0, 0.0, -0.5), (8.0, 8.0))
    world = (0.05, 0.06, 0.07)
    light = ((2.0, -3.0, 4.0), 800.0)
    scene = Scene(camera=res_camera, meshes=[Mesh("ball", *ball), Mesh("floor", *floor)],
                  lights=[Light("lamp", "POINT", light[0], power=light[1])],
                  materials=[Material(base_color=(0.8, 0.8, 0.8), specular_ior_level=0.0)], world_color=world)
    return scene, lambda: PlainTracer([ball, floor], [light], (0.8, 0.8, 0.8), world)


class Counter:
    """Counts embree queries (and their rays) by wrapping tracer._local_query, and spectral evaluations."""

    def __init__(self):
        self.nearest = self.occlusion = self.nearest_rays = self.occlusion_rays = self.spectral = 0

    def __enter__(self):
        self._query, self._sigmoid = tracer._local_query, spectral.sigmoid_spectrum

        def query(geometry, origin, d, t_lo, t_hi, occlusion):
            if occlusion:
                self.occlusion += 1
                self.occlusion_rays += len(d)
            else:
                self.nearest += 1
                self.nearest_rays += len(d)
            return self._query(geometry, origin, d, t_lo, t_hi, occlusion)

        def sigmoid(*a, **k):
            self.spectral += 1
            return self._sigmoid(*a, **k)

        tracer._local_query = query
        spectral.sigmoid_spectrum = sigmoid
        return self

    def __exit__(self, *exc):
        tracer._local_query, spectral.sigmoid_spectrum = self._query, self._sigmoid


def run(ctx) -> Section:
    sec = Section("4. What a scene does not use it does not pay for")
    repeats = ctx.pick(5, 1)
    res = ctx.pick((256, 192), (32, 24))

    # (a) static scene vs plain tracer
    scene, build_plain = static_scene()
    s = settings(res, passes=())  # the plain tracer fills no passes either
    plain, prepared = build_plain(), prepare(scene, s)
    t = interleaved({"plain": lambda: build_plain().render(scene.camera, res, s.tile_size),
                     "restframe": lambda: render_image(scene, s),
                     "plain tiles": lambda: plain.render(scene.camera, res, s.tile_size),
                     "restframe tiles": lambda: list(render_tiles(prepared))}, repeats)
    ours = t["restframe"]["result"]["Combined"][..., :3]
    ref = t["plain"]["result"]
    diff = np.abs(ours - ref)
    differ = float(np.mean(diff > 1e-4 * (ref + 1e-3)))
    ratio = t["restframe"]["min"] / t["plain"]["min"]
    tiles_ratio = t["restframe tiles"]["min"] / t["plain tiles"]["min"]
    sec.add("### Static scene against a plain embreex ray tracer")
    sec.add("")
    sec.add(f"A 16k-triangle ball on a floor, one point light, Lambert (Specular IOR Level 0), {res[0]}x{res[1]}, "
            f"1 sample, one thread, {s.tile_size}x{s.tile_size} tiles on both sides. The plain tracer "
            "(`PlainTracer` in `tests/bench/bench_frugal.py`): one embreex scene, primary rays from the same camera "
            "code, Lambert, shadow rays; no frames, no passes, no materials, no colour model. RESTframe renders "
            "Combined only (`passes=()`), as the engine does when the view layer asks for no other pass. "
            "**whole render** = building the scene (embree BVH; RESTframe: its rest frames) and rendering it; "
            "**tiles** = rendering an already prepared scene.")
    sec.add("")
    sec.table(["", "whole render (s)", "RESTframe / plain", "tiles (s)", "RESTframe / plain",
               "pixels differing > 1e-4 rel.", "median abs. difference"],
              [["plain embreex tracer", t["plain"]["min"], 1.0, t["plain tiles"]["min"], 1.0, "", ""],
               ["RESTframe", t["restframe"]["min"], ratio, t["restframe tiles"]["min"], tiles_ratio, differ,
                float(np.median(diff))]])
    sec.number("static_vs_plain", ratio)
    sec.number("static_vs_plain_tiles", tiles_ratio)
    sec.number("static_vs_plain_differ", differ)
    sec.goals.append(Goal("static scene vs plain embreex tracer (same shading)", "<= 1.10x",
                          f"{ratio:.2f}x whole render, {tiles_ratio:.2f}x tiles", ratio <= 1.10))

    # (b) Doppler modes
    moving = ball_scene(beta=0.6, segments=64)
    modes = {m: settings(res, doppler_mode=m) for m in ("OFF", "FACTOR", "SPECTRAL")}
    t = interleaved({m: (lambda st=st: render_image(moving, st)) for m, st in modes.items()}, repeats)
    counts = {}
    for m, st in modes.items():
        with Counter() as c:
            render_image(moving, st)
        counts[m] = c.spectral
    sec.add("### Doppler display modes")
    sec.add("")
    sec.add(f"The ball scene with the ball at 0.6c, {res[0]}x{res[1]}, one thread, `spectral_samples=32`; "
            "`spectral calls` = calls of `spectral.sigmoid_spectrum` (the spectral evaluation) during the render.")
    sec.add("")
    off = t["OFF"]["min"]
    sec.table(["mode", "time (s)", "time / OFF", "spectral calls"],
              [[m, t[m]["min"], t[m]["min"] / off, counts[m]] for m in modes])
    for m in modes:
        sec.number(f"doppler_{m}_ratio", t[m]["min"] / off)
    sec.goals.append(Goal("Doppler OFF does no spectral work", "0 spectral calls",
                          f"{counts['OFF']} calls; SPECTRAL costs {t['SPECTRAL']['min'] / off:.2f}x OFF",
                          counts["OFF"] == 0))

    # (c) lights and shadow rays
    lit = ball_scene(beta=0.6, segments=64)
    dark = ball_scene(beta=0.6, segments=64, lights=False, emissive_floor=True)
    s = settings(res)
    rows = []
    for name, sc in (("one point light", lit), ("no lights (emissive floor)", dark)):
        with Counter() as c:
            render_image(sc, s)
        rows.append([name, c.nearest, c.nearest_rays, c.occlusion, c.occlusion_rays])
    t = interleaved({"lit": lambda: render_image(lit, s), "dark": lambda: render_image(dark, s)}, repeats)
    sec.add("### Lights and shadow rays")
    sec.add("")
    sec.add("Embree queries counted by wrapping `tracer._local_query` (one call = one batch sent to one "
            f"frame's embree scene), same scene with and without its light. Render time with the light "
            f"{t['lit']['min']:.3f} s, without {t['dark']['min']:.3f} s.")
    sec.add("")
    sec.table(["scene", "nearest-hit queries", "rays", "shadow (occlusion) queries", "rays"], rows)
    sec.number("dark_occlusion_rays", rows[1][4])
    sec.goals.append(Goal("no lights, no shadow rays", "0 occlusion queries", f"{rows[1][3]} queries, {rows[1][4]} rays",
                          rows[1][3] == 0))
    return sec

"""Section 1: error against run time for each quality knob.

Every study renders one scene at a list of settings of one knob plus a reference
setting, and reports run time and the relative RMS error (RMSE over pixels and RGB
channels of the Combined pass, divided by the reference's mean) of each setting.

A new knob is one more :class:`KnobStudy` in :func:`studies` (the motion-sampling
knobs, e.g. ``motion_tolerance``, are studies like the others).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from bench_common import (Goal, HyperbolicBall, Section, ball_scene, box, look_at_camera, quad, rel_rmse, settings,
                          timed, uv_sphere)
from restframe_addon.core.render import render_image
from restframe_addon.core.scene import Light, Material, Mesh, Scene, Velocity


@dataclass
class KnobStudy:
    key: str  # short name, used for plot files and numbers
    knob: str  # the RenderSettings field
    title: str
    scene: Callable[[], Scene]
    base: dict  # other RenderSettings fields
    values: list
    reference: object
    what: str  # one sentence: the scene and why the knob matters there


def spectral_scene():
    """Four coloured balls moving at different speeds toward/away from and across the view."""
    meshes, materials = [], []
    colours = [(0.9, 0.1, 0.1), (0.1, 0.8, 0.2), (0.1, 0.2, 0.9), (0.8, 0.8, 0.8)]
    betas = [(0.0, -0.5, 0.0), (0.0, 0.4, 0.0), (0.6, 0.0, 0.0), (-0.3, -0.3, 0.0)]
    for i, (colour, beta) in enumerate(zip(colours, betas)):
        centre = np.array([-3.0 + 2.0 * i, 0.0, 0.0])
        v, t = uv_sphere((0.0, 0.0, 0.0), 0.8, 32, 16)
        meshes.append(Mesh(f"ball{i}", v + centre, t, velocity=Velocity(beta), pivot=tuple(centre),
                           material_indices=np.full(len(t), i)))
        materials.append(Material(f"m{i}", base_color=colour, roughness=0.5))
    fv, ft = quad((0.0, 0.0, -0.8), (20.0, 20.0))
    meshes.append(Mesh("floor", fv, ft, velocity=Velocity((0.0, 0.0, 0.0)), material_indices=np.full(2, 4)))
    materials.append(Material("floor", base_color=(0.6, 0.6, 0.5)))
    camera = look_at_camera((0.0, -8.0, 2.0), (0.0, 0.0, 0.0), aspect=2.0, fov_half_tan=0.6)
    lights = [Light("sun", "SUN", (0.0, 0.0, 10.0), power=3.0, temperature=5500.0)]
    return Scene(camera=camera, meshes=meshes, materials=materials, lights=lights, world_color=(0.1, 0.12, 0.2))


def mirror_glass_scene():
    """A mirror ball and a glass ball (moving at 0.5c) in a box of coloured walls: light bounces many times."""
    meshes, materials = [], []

    def add(name, vt, material, velocity=Velocity(), pivot=(0.0, 0.0, 0.0)):
        v, t = vt
        meshes.append(Mesh(name, v, t, velocity=velocity, pivot=pivot, material_indices=np.full(len(t), material)))

    materials += [Material("mirror", base_color=(0.9, 0.9, 0.9), metallic=1.0, roughness=0.0),
                  Material("glass", base_color=(1.0, 1.0, 1.0), roughness=0.0, transmission=1.0, ior=1.5),
                  Material("red", base_color=(0.8, 0.1, 0.1)), Material("green", base_color=(0.1, 0.7, 0.1)),
                  Material("white", base_color=(0.8, 0.8, 0.8)), Material("mirror wall", base_color=(0.9, 0.9, 0.9),
                                                                           metallic=1.0, roughness=0.0)]
    add("mirror ball", uv_sphere((-1.2, 0.5, -1.0), 1.0, 48, 24), 0)
    add("glass ball", uv_sphere((1.3, -0.5, -1.2), 0.8, 48, 24), 1, Velocity((0.0, 0.0, 0.5)), (1.3, -0.5, -1.2))
    add("floor", quad((0.0, 0.0, -2.0), (6.0, 8.0)), 4)
    add("left", quad((-3.0, 0.0, 0.0), (8.0, 4.0), normal_axis=0), 2)
    add("right", quad((3.0, 0.0, 0.0), (8.0, 4.0), normal_axis=0), 3)
    add("back", quad((0.0, 4.0, 0.0), (6.0, 4.0), normal_axis=1), 5)  # a mirror wall: a hall of mirrors
    add("front", quad((0.0, -4.0, 0.0), (6.0, 4.0), normal_axis=1), 5)
    add("ceiling", quad((0.0, 0.0, 2.0), (6.0, 8.0)), 4)
    lights = [Light("lamp", "POINT", (0.0, -1.0, 1.5), power=400.0)]
    camera = look_at_camera((0.0, -3.6, 0.5), (0.0, 0.0, -0.8), fov_half_tan=0.7)
    return Scene(camera=camera, meshes=meshes, materials=materials, lights=lights, world_color=(0.0, 0.0, 0.0))


# The accelerated ball of motion_scene, exactly: Born-rigid, radius 0.8, proper acceleration 0.5 along x,
# turning around at x = -2 at world time 0; the animation samples its centre over |t| <= 6 (0.95c at the ends).
MOTION_BALL = HyperbolicBall(alpha=2.0, radius=0.8, x0=-2.0, y0=1.0, t_end=6.0)


def motion_scene(accelerated=True, spinning=False):
    """A ball on a hyperbolic world line (proper acceleration 0.5, 0.95c at the ends) passing the camera,
    and/or a cube spinning with its corners at 0.7c, over a floor, one point light."""
    from restframe_addon.core.motion import Trajectory

    tau = np.linspace(-MOTION_BALL.t_end, MOTION_BALL.t_end, 25)  # animation samples
    path = MOTION_BALL.centre(tau)
    v, t = uv_sphere((0.0, 0.0, 0.0), MOTION_BALL.radius, 48, 24)
    bv, bt = box((0.0, 0.0, 0.0), (1.2, 1.2, 1.2))
    fv, ft = quad((0.0, 0.0, -1.0), (20.0, 20.0))
    meshes = [Mesh("floor", fv, ft, material_indices=np.full(len(ft), 2))]
    if accelerated:
        meshes.append(Mesh("rocket", v, t, pivot=(0.0, 0.0, 0.0), material_indices=np.zeros(len(t), int),
                           trajectory=Trajectory(tau, path, name="rocket", body_radius=0.8)))
    if spinning:
        meshes.append(Mesh("top", bv + (2.5, -1.0, 0.0), bt, pivot=(2.5, -1.0, 0.0), angular_velocity=(0.0, 0.0, 0.8),
                           material_indices=np.ones(len(bt), int)))
    materials = [Material("rocket", base_color=(0.8, 0.4, 0.1)), Material("top", base_color=(0.2, 0.4, 0.8)),
                 Material("floor", base_color=(0.6, 0.6, 0.6))]
    if accelerated:
        camera = look_at_camera((0.0, -6.0, 1.5), (-1.0, 1.0, 0.0), aspect=4 / 3, fov_half_tan=0.3)
    else:
        camera = look_at_camera((0.0, -7.0, 1.5), (0.5, 0.0, 0.0), aspect=4 / 3, fov_half_tan=0.6)
    return Scene(camera=camera, meshes=meshes, materials=materials,
                 lights=[Light("lamp", "POINT", (1.0, -4.0, 5.0), power=2000.0)], tau_obs=4.0, light_speed=1.0)


def studies(smoke: bool) -> list[KnobStudy]:
    res = (24, 18) if smoke else (128, 96)
    out = [
        KnobStudy("samples", "samples", "Samples per pixel",
                  lambda: ball_scene(beta=0.6, soft=0.6, tau=0.0),
                  dict(resolution=res), [1, 4] if smoke else [1, 2, 4, 8, 16, 32, 64], 16 if smoke else 256,
                  "A ball moving at 0.6c over a floor, lit by a soft (radius 0.6) point light: samples "
                  "anti-alias edges and sample the soft shadow."),
        KnobStudy("spectral", "spectral_samples", "Spectral samples (SPECTRAL Doppler mode)", spectral_scene,
                  dict(resolution=(24, 12) if smoke else (160, 80), doppler_mode="SPECTRAL"),
                  [4, 8] if smoke else [4, 6, 8, 12, 16, 24, 32, 48, 64, 128], 470,
                  "Four coloured balls moving at 0.4-0.6c toward, away from and across the view, a 5500 K sun: "
                  "Doppler-shifted spectra resolved by K wavelengths per ray (reference K = 470, 1 nm strata)."),
        KnobStudy("bounces", "max_bounces", "Bounce limit (mirror and glass)", mirror_glass_scene,
                  dict(resolution=(24, 24) if smoke else (128, 128)),
                  [0, 2] if smoke else [0, 1, 2, 3, 4, 6, 8, 12], 6 if smoke else 32,
                  "A mirror ball and a glass ball (moving at 0.5c) in a box with two facing mirror walls."),
        KnobStudy("motion", "motion_tolerance", "Motion tolerance: accelerated ball", motion_scene,
                  dict(resolution=(16, 12) if smoke else (64, 48)),
                  [3e-1] if smoke else [3e-1, 1e-1, 3e-2, 1e-2, 3e-3], 1e-1 if smoke else 1e-3,
                  "A ball (radius 0.8) on a hyperbolic world line (25 animation samples, proper acceleration 0.5, "
                  "up to 0.95c) passing the camera over a floor, a point light: the tolerance (scene units) bounds "
                  "how far the inertial segments stray from the true Born-rigid motion (default 1e-3, the reference "
                  "here)."),
        KnobStudy("spin", "motion_tolerance", "Motion tolerance: spinning cube", lambda: motion_scene(False, True),
                  dict(resolution=(16, 12) if smoke else (64, 48)),
                  [1e-1] if smoke else [3e-1, 1e-1, 3e-2, 1e-2, 3e-3, 1e-3, 1e-4], 1e-2 if smoke else 1e-6,
                  "A 1.2-unit cube spinning at 0.8 rad per c-unit (corners at 0.68c) over a floor, a point light: "
                  "the tolerance ends the per-ray pose iteration (default 1e-3)."),
    ]
    # A new quality knob is one more KnobStudy here.
    return out


def run_study(study: KnobStudy, ctx) -> dict:
    scene = study.scene()
    rows = []
    failures = []
    try:
        ref_time, ref = timed(lambda: render_image(scene, settings(**study.base, **{study.knob: study.reference})))
    except Exception as error:
        failures.append((study.reference, f"{type(error).__name__}: {error}"))
        ctx.log(f"  {study.key} reference: FAILED {failures[-1][1]}")
        return {"rows": rows, "reference_time": math.nan, "failures": failures}
    ref = ref["Combined"]
    for value in study.values:
        try:
            seconds, passes = timed(lambda: render_image(scene, settings(**study.base, **{study.knob: value})))
        except Exception as error:  # a setting the core cannot render is reported, not hidden
            failures.append((value, f"{type(error).__name__}: {error}"))
            ctx.log(f"  {study.key}={value}: FAILED {failures[-1][1]}")
            continue
        rows.append((value, seconds, rel_rmse(passes["Combined"], ref)))
        ctx.log(f"  {study.key}={value}: {seconds:.2f} s, error {rows[-1][2]:.3g}")
    return {"rows": rows, "reference_time": ref_time, "failures": failures}


FACETS = 0.005  # the 48 x 24 UV sphere of radius 0.8 lies within this of the round ball


def motion_error_bound(scene, tolerance: float) -> float:
    """How far a correct render of motion_scene's ball may stray from MOTION_BALL: the motion tolerance,
    plus how far the 25 animation samples (with rounded corners) stray from the hyperbola -- amplified by
    1 / (1 - R a) for the body's front and back, as in motion.segment_error -- plus the mesh facets."""
    trajectory = next(m.trajectory for m in scene.meshes if m.trajectory is not None)
    t = np.linspace(-MOTION_BALL.t_end, MOTION_BALL.t_end, 4001)
    samples = float(np.max(np.linalg.norm(trajectory.state(t)[0] - MOTION_BALL.centre(t), axis=1)))
    return tolerance + samples / (1.0 - MOTION_BALL.radius / MOTION_BALL.alpha) + FACETS


def against_analytic_ball(scene, s, bound: float) -> dict:
    """Camera rays (pixel centres) and the shadow rays leaving the accelerated ball, checked against the
    exact Born-rigid ball (MOTION_BALL, solved per event, no inertial segments).

    A camera ray is wrong if it goes deeper than ``bound`` into the ball before its hit, or hits the ball
    more than ``bound`` off its surface; a shadow ray, if it is blocked but passes more than ``bound``
    outside the ball, or is free but passes more than ``bound`` inside it.  (The floor cannot block the
    shadow rays, which run up toward the light, so every blocked one is checked against the ball alone.)
    """
    from restframe_addon.core import shading
    from restframe_addon.core.camera import primary_rays
    from restframe_addon.core.tracer import trace_nearest

    original = shading.occluded
    shadow, seen = [], {}

    def recording(frames, src, tau0, x0, d, s_lo, s_hi, cache=None, see_through=None):
        blocked = original(frames, src, tau0, x0, d, s_lo, s_hi, cache, see_through)
        seen["frames"] = frames
        if frames.frames[src].window is not None:
            to_world = frames.map(src, frames.world)
            tau_w, x_w = to_world.events(tau0, x0)
            d_w, w = to_world.rays(d)
            shadow.append((tau_w, x_w, d_w, s_lo * w, s_hi * w, blocked))
        return blocked

    shading.occluded = recording
    try:
        render_image(scene, s)
    finally:
        shading.occluded = original
    frames = seen["frames"]
    step = bound / 4
    width, height = s.resolution
    ys, xs = np.mgrid[0:height, 0:width]
    x0, d, s_lo, s_hi, _ = primary_rays(scene.camera, xs.ravel() + 0.5, ys.ravel() + 0.5, s.resolution)
    x0 = np.array(x0)  # the camera is at rest in S: its frame is S
    tau = np.full(len(d), scene.tau_obs)
    hits = trace_nearest(frames, frames.camera, tau, x0, d, s_lo, s_hi)
    ball = np.array([f.window is not None for f in frames.frames])[hits.frame] & (hits.frame >= 0)
    depth = MOTION_BALL.deepest(tau, x0, d, s_lo, np.where(hits.frame >= 0, hits.s, s_hi), step)
    off = np.abs(MOTION_BALL.margin(tau[ball] - hits.s[ball], x0[ball] + hits.s[ball, None] * d[ball]))
    camera_wrong = np.count_nonzero(depth < -bound) + np.count_nonzero(off > bound)
    blocked = np.concatenate([r[-1] for r in shadow])
    passing = np.concatenate([MOTION_BALL.deepest(*r[:-1], step) for r in shadow])
    shadow_wrong = np.count_nonzero(blocked & (passing > bound)) + np.count_nonzero(~blocked & (passing < -bound))
    return dict(camera=int(ball.sum()), camera_wrong=int(camera_wrong), deepest=float(-min(depth.min(), 0.0)),
                shadow=len(blocked), shadow_blocked=int(blocked.sum()), shadow_exact=int(np.count_nonzero(passing < -bound)),
                shadow_wrong=int(shadow_wrong))


def run(ctx) -> Section:
    sec = Section("1. Error against run time for each quality knob")
    sec.add("Error norm: **relative RMSE** = root-mean-square difference of the Combined RGB from the "
            "reference render, over all pixels and channels, divided by the reference's mean value. "
            "Times are single-thread `render_image` wall times (`threads=1`), including scene "
            "preparation, each measured once in this run.")
    sec.add("")
    import matplotlib.pyplot as plt

    all_studies = studies(ctx.smoke)
    from matplotlib.ticker import FuncFormatter, NullFormatter

    cols = 3
    rows_n = -(-len(all_studies) // cols)
    fig, axes = plt.subplots(rows_n, cols, figsize=(4.0 * cols, 3.2 * rows_n), squeeze=False)
    for ax in axes.ravel()[len(all_studies):]:
        ax.set_visible(False)
    for ax, study in zip(axes.ravel(), all_studies):
        ctx.log(f" knob {study.key}")
        result = run_study(study, ctx)
        rows = result["rows"]
        sec.add(f"### {study.title} (`{study.knob}`)")
        sec.add("")
        sec.add(study.what + f" Resolution {study.base['resolution'][0]}x{study.base['resolution'][1]}; "
                f"reference `{study.knob}={study.reference:g}` ({result['reference_time']:.2f} s).")
        sec.add("")
        if not rows:
            sec.add("No setting rendered:")
        t1 = rows[0][1] if rows else math.nan
        sec.table([f"`{study.knob}`", "time (s)", "time / first", "relative RMSE"],
                  [[v, s, s / t1, e] for v, s, e in rows])
        for v, message in result["failures"]:
            sec.add(f"- `{study.knob}={v:g}` **fails**: `{message}`")
            sec.goals.append(Goal(f"{study.title}: `{study.knob}={v:g}` renders", "no error", f"`{message[:90]}`", False))
        if result["failures"]:
            sec.add("")
        for v, s, e in rows:
            sec.number(f"{study.key}_{v}_time", s)
            sec.number(f"{study.key}_{v}_error", e)
        if study.key == "motion":
            scene = study.scene()
            checks = [(v, motion_error_bound(scene, v)) for v in study.values + [study.reference]]
            checks = [(v, bound, against_analytic_ball(scene, settings(**study.base, **{study.knob: v}), bound))
                      for v, bound in checks]
            sec.add("Check against the exact ball: the Born-rigid ball on the hyperbola the animation samples, "
                    "solved per event without inertial segments (`HyperbolicBall` in `tests/core/shapes.py`). "
                    "Allowed deviation (bound) = the tolerance + how far the 25 animation samples stray from "
                    "the hyperbola (amplified by 1/(1 - R a) = 1.67 for the ball's front and back) + the mesh "
                    "facets (0.005). A camera ray is wrong if it goes deeper than the bound into the ball "
                    "before its hit (it shows the ball's far side from within), or hits the ball off its "
                    "surface; a shadow ray leaving the ball is wrong if it is blocked but passes outside the "
                    "ball by more than the bound, or free but passes inside it. \"through the exact ball\" counts "
                    "the shadow rays that pass deeper than the bound into the exact ball: none should, as they "
                    "start within the bound of its surface and light reaching its lit side does not pass "
                    "through its own past (while its acceleration is uniform the ball is a geodesic ball of "
                    "Rindler optical space, which light leaving it never re-enters). \"deepest inside\" is how "
                    "far the worst camera ray got into the exact ball before its hit.")
            sec.add("")
            sec.table([f"`{study.knob}`", "bound", "camera rays on the ball", "wrong", "deepest inside",
                       "shadow rays from the ball", "blocked", "through the exact ball", "wrong"],
                      [[f"{v:g}", bound, c["camera"], c["camera_wrong"], c["deepest"], c["shadow"],
                        c["shadow_blocked"], c["shadow_exact"], c["shadow_wrong"]] for v, bound, c in checks])
            wrong = max(c["camera_wrong"] + c["shadow_wrong"] for _, _, c in checks)
            sec.number("motion_wrong_rays", wrong)
            sec.goals.append(Goal("accelerated ball vs the exact Born-rigid ball", "0 wrong camera or shadow rays",
                                  f"up to {wrong} wrong", wrong == 0))
        times = np.array([r[1] for r in rows])
        errors = np.array([max(r[2], 1e-12) for r in rows])
        ax.loglog(times, errors, "o-")
        for v, s, e in zip([r[0] for r in rows], times, errors):
            ax.annotate(f"{v:g}", (s, e), textcoords="offset points", xytext=(4, 4), fontsize=7)
        for axis, values in ((ax.xaxis, times), (ax.yaxis, errors)):
            # within a decade the major (power of ten) labels are missing: label the minor ticks sparsely
            narrow = values.max() / values.min() < 10
            axis.set_minor_formatter(FuncFormatter(lambda v, _: f"{v:.2g}") if narrow else NullFormatter())
            axis.set_tick_params(which="minor", labelsize=6)
        ax.set_xlabel("render time (s, 1 thread)")
        ax.set_ylabel("relative RMSE")
        ax.set_title(study.title, fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    name = "knobs.png"
    fig.savefig(ctx.out_dir / name, dpi=80)
    plt.close(fig)
    sec.add(f"![error against run time]({ctx.plot_prefix}/{name})")
    sec.add("")
    return sec

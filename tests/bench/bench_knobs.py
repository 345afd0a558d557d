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

from bench_common import Goal, Section, ball_scene, box, look_at_camera, quad, rel_rmse, settings, timed, uv_sphere
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


def motion_scene(accelerated=True, spinning=False):
    """A ball on a hyperbolic world line (proper acceleration 0.5, 0.95c at the ends) passing the camera,
    and/or a cube spinning with its corners at 0.7c, over a floor, one point light."""
    from restframe_addon.core.motion import Trajectory

    alpha = 2.0
    tau = np.linspace(-6.0, 6.0, 25)  # animation samples; the speed reaches 0.95c at the ends
    x = -alpha + np.sqrt(alpha**2 + tau**2) - 2.0
    path = np.column_stack([x, np.full_like(tau, 1.0), np.zeros_like(tau)])
    v, t = uv_sphere((0.0, 0.0, 0.0), 0.8, 48, 24)
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


def self_shadowing(scene, s) -> tuple[int, int]:
    """Shadow rays leaving the accelerated body's inertial segments (frames with a time window), and
    how many of them are blocked.  In ``motion_scene`` nothing can block them (a convex ball, the
    floor below, the light above its lit side), so every blocked one is a self-shadowing error."""
    from restframe_addon.core import shading

    original = shading.occluded
    count = [0, 0]

    def counting(frames, src, tau0, x0, d, s_lo, s_hi):
        blocked = original(frames, src, tau0, x0, d, s_lo, s_hi)
        if frames.frames[src].window is not None:
            count[0] += len(d)
            count[1] += int(np.count_nonzero(blocked))
        return blocked

    shading.occluded = counting
    try:
        render_image(scene, s)
    finally:
        shading.occluded = original
    return count[0], count[1]


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
            counts = [(v, *self_shadowing(scene, settings(**study.base, **{study.knob: v})))
                      for v in study.values + [study.reference]]
            sec.add("Self-shadowing check: shadow rays that leave the accelerated ball toward the light, and how "
                    "many are blocked. Nothing in this scene can block them (a convex ball, the floor below, the "
                    "light above its lit side), so every blocked ray is a shading error (dark speckles):")
            sec.add("")
            sec.table([f"`{study.knob}`", "shadow rays from the ball", "blocked", "blocked share"],
                      [[f"{v:g}", n, b, b / max(n, 1)] for v, n, b in counts])
            worst = max(b / max(n, 1) for _, n, b in counts)
            sec.number("motion_self_shadow", worst)
            sec.goals.append(Goal("accelerated ball: no self-shadowing", "0 blocked shadow rays",
                                  f"up to {100 * worst:.1f}% blocked", worst == 0.0))
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

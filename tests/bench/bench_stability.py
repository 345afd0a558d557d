"""Section 2: numerical stability from beta = 1e-12 to gamma = 1e8, against mpmath.

(a) every transform of ``core.lorentz`` (events, rays d' and D, velocity composition);
(b) the rendered Doppler pass (float32) and the float64 D behind it, per pixel;
(c) the float32 geometry path: how far from the origin (in space, or in time for a
    moving object) a scene can sit before its image changes by a pixel.
"""

from __future__ import annotations

import math

import mpmath as mp
import numpy as np

from bench_common import Goal, Section, ball_scene, look_at_camera, rel_rmse, settings, uv_sphere
from restframe_addon.core.lorentz import Boost, compose_velocities
from restframe_addon.core.prepared import prepare
from restframe_addon.core.render import render_image
from restframe_addon.core.scene import Mesh, Scene, Velocity
from restframe_addon.core.tracer import trace_nearest

mp.mp.dps = 60
AXIS = np.array([0.36, -0.48, 0.8])


def speeds(smoke):
    if smoke:
        return [("b", 1e-12), ("b", 0.9), ("b", 1 - 1e-12), ("gamma", 1e8)]
    out = [("b", b) for b in (1e-12, 1e-9, 1e-6, 1e-3, 0.1, 0.5, 0.9, 0.99, 1 - 1e-3, 1 - 1e-6, 1 - 1e-9, 1 - 1e-12)]
    return out + [("gamma", g) for g in (1.0 + 1e-6, 10.0, 1e3, 1e5, 1e6, 1e7, 1e8)]


def label(kind, value):
    if kind == "gamma":
        return f"gamma={value:.6g}"
    if value > 0.5 and value < 1:
        return f"b=1-{1 - value:.0e}" if 1 - value < 1e-2 else f"b={value:g}"
    return f"b={value:g}"


def make_boost(kind, value, axis=AXIS):
    """(Boost, mp reference (n, b, gamma)) for a speed given as b or as gamma along axis."""
    if kind == "b":
        beta = value * axis
        boost = Boost.from_velocity(beta)
        b = mp.sqrt(sum(mp.mpf(float(c)) ** 2 for c in beta))
        g = 1 / mp.sqrt(1 - b * b)
    else:
        boost = Boost.from_velocity(axis, lorentz_factor=value)
        g = mp.mpf(value)
        b = mp.sqrt(1 - 1 / (g * g))
    n = [mp.mpf(float(c)) for c in boost.n]
    norm = mp.sqrt(sum(c * c for c in n))
    return boost, ([c / norm for c in n], b, g)


def mp_rays(parts, d):
    n, b, g = parts
    d = [mp.mpf(float(c)) for c in d]
    norm = mp.sqrt(sum(c * c for c in d))
    d = [c / norm for c in d]
    bd = b * sum(a * c for a, c in zip(n, d))
    w = g * (1 + bd)
    k = g * g / (g + 1)
    return [(dc + (k * bd + g) * b * nc) / w for dc, nc in zip(d, n)], w


def mp_events(parts, tau, x):
    n, b, g = parts
    x = [mp.mpf(float(c)) for c in x]
    tau = mp.mpf(float(tau))
    nx = sum(a * c for a, c in zip(n, x))
    return g * (tau - b * nx), [xc + ((g - 1) * nx - g * b * tau) * nc for xc, nc in zip(x, n)]


def directions_for(n):
    n = np.asarray(n, float) / np.linalg.norm(n)
    t = np.cross(n, [1.0, 0.0, 0.0])
    t /= np.linalg.norm(t)
    out = [-n, n, t]
    for angle in (1e-9, 1e-6, 1e-3, 0.3, 1.0, 2.0, math.pi - 1e-3, math.pi - 1e-6):
        out.append(math.cos(math.pi - angle) * n + math.sin(math.pi - angle) * t)
    rng = np.random.default_rng(1)
    for _ in range(6):
        v = rng.normal(size=3)
        out.append(v / np.linalg.norm(v))
    return np.array([d / np.linalg.norm(d) for d in out])


def transform_errors(kind, value):
    """Largest relative errors of one boost's maps against mpmath."""
    boost, ref = make_boost(kind, value)
    err = {}
    rng = np.random.default_rng(7)
    tau = rng.normal(size=12) * 10.0
    x = rng.normal(size=(12, 3)) * 10.0
    tau2, x2 = boost.events(tau, x)
    e = 0.0
    for i in range(len(tau)):
        rt, rx = mp_events(ref, tau[i], x[i])
        scale = abs(rt) + mp.sqrt(sum(c * c for c in rx))
        e = max(e, float(max([abs(mp.mpf(float(tau2[i])) - rt)] + [abs(mp.mpf(float(a)) - c) for a, c in zip(x2[i], rx)]) / scale))
    err["events"] = e
    ds = directions_for(boost.n)
    d_new, w = boost.rays(ds)
    e_d = e_w = 0.0
    for i, d in enumerate(ds):
        rd, rw = mp_rays(ref, d)
        e_w = max(e_w, float(abs(mp.mpf(float(w[i])) - rw) / rw))
        e_d = max(e_d, float(mp.sqrt(sum((mp.mpf(float(a)) - c) ** 2 for a, c in zip(d_new[i], rd)))))
    err["rays_D"], err["rays_d"] = e_w, e_d
    err["gamma"] = float(abs(mp.mpf(boost.gamma) - ref[2]) / ref[2])
    err["one_minus_b"] = float(abs(mp.mpf(boost.one_minus_b) - (1 - ref[1])) / (1 - ref[1]))
    return err


def mp_compose(u, v):
    u, v = [mp.mpf(float(c)) for c in u], [mp.mpf(float(c)) for c in v]
    gu = 1 / mp.sqrt(1 - sum(c * c for c in u))
    uv = sum(a * c for a, c in zip(u, v))
    return [(vc / gu - uc + gu / (gu + 1) * uv * uc) / (1 - uv) for uc, vc in zip(u, v)]


def compose_errors(smoke):
    bs = [1e-12, 0.9, 1 - 1e-12] if smoke else [1e-12, 1e-6, 0.1, 0.5, 0.9, 0.99, 1 - 1e-6, 1 - 1e-9, 1 - 1e-12]
    other = np.array([0.6, 0.8, 0.0])
    worst_v = worst_g = worst_zero = 0.0
    where = where_zero = ""
    for bu in bs:
        for bv in bs:
            for direction in (AXIS, -AXIS, other):
                u, v = tuple(bu * AXIS), tuple(bv * direction)
                got, gamma = compose_velocities(u, v)
                ref = mp_compose(u, v)
                norm = mp.sqrt(sum(c * c for c in ref))
                if bu == bv and direction is AXIS:  # the frame moves with the body: exactly 0
                    zero = float(np.linalg.norm(got))
                    if zero >= worst_zero:
                        worst_zero, where_zero = zero, f"u = v = {label('b', bu)[2:]}"
                    continue
                ev = float(max(abs(mp.mpf(float(a)) - c) for a, c in zip(got, ref)) / norm)
                g_ref = 1 / mp.sqrt(1 - norm * norm) if norm < 1 else mp.inf
                eg = float(abs(mp.mpf(gamma) - g_ref) / g_ref)
                if ev > worst_v:
                    worst_v, where = ev, f"u={label('b', bu)[2:]}, v={label('b', bv)[2:]}"
                    worst_pair = (u, v, ref, norm)
                worst_g = max(worst_g, eg)
    return worst_v, worst_g, worst_zero, where, where_zero, len(bs) ** 2 * 3, ulp_sensitivity(*worst_pair)


def ulp_sensitivity(u, v, ref, norm) -> float:
    """How far the exact composition moves (relative) when one input component moves by one ulp:
    the uncertainty the float inputs themselves carry, against which a computed result is judged."""
    worst = 0.0
    for which in (0, 1):
        for i in range(3):
            for toward in (-np.inf, np.inf):
                moved = [list(u), list(v)]
                moved[which][i] = float(np.nextafter(moved[which][i], toward))
                exact = mp_compose(*moved)
                worst = max(worst, float(max(abs(a - c) for a, c in zip(exact, ref)) / norm))
    return worst


# --------------------------------------------------------------------------- rendered D
def doppler_errors(kind, value, res, camera_beta=(0.0, 0.0, 0.0)):
    """Rendered Doppler pass (float32) and float64 D (trace_nearest) against mpmath, every hit pixel."""
    if kind == "b":
        velocity = Velocity((0.0, -value, 0.0))
    else:
        velocity = Velocity((0.0, -1.0, 0.0), lorentz_factor=value)
    # a sphere around the camera (its pivot at the camera event): every ray hits it at any speed
    v, t = uv_sphere((0.0, 0.0, 0.0), 100.0, 64, 32)
    camera = look_at_camera((0, 0, 0), (0, 1, 0), velocity=Velocity(camera_beta))
    camera.clip_start, camera.clip_end = 1e-30, 1e300  # near c the shell is a pancake 100/gamma thick
    scene = Scene(camera=camera, meshes=[Mesh("shell", v, t, velocity=velocity, pivot=(0, 0, 0))])
    s = settings(res)
    passes = render_image(scene, s)
    prepared = prepare(scene, s)
    ys, xs = np.mgrid[0:res[1], 0:res[0]]
    tau, x, d, s_lo, s_hi = prepared.rays(xs.ravel() + 0.5, ys.ravel() + 0.5)
    hits = trace_nearest(prepared.frames, prepared.frames.camera, tau, x, d, s_lo, s_hi)
    d64 = 1.0 / hits.w
    d32 = passes["Doppler"][..., 0].ravel()
    wall_boost = prepared.frames.frames[hits.frame[hits.frame >= 0][0]].boost if np.any(hits.frame >= 0) else None
    if wall_boost is None:
        return None
    _, wall_ref = make_boost(kind, value, axis=np.array([0.0, -1.0, 0.0]))
    cam_boost = prepared.frames.frames[prepared.frames.camera].boost
    cam_ref = None
    if not cam_boost.is_identity:
        # camera frame -> S: the inverse camera boost (velocity -beta_c), then S -> wall frame
        cb, cref = make_boost("b", float(np.linalg.norm(camera_beta)), axis=np.asarray(camera_beta) / np.linalg.norm(camera_beta))
        cam_ref = ([-c for c in cref[0]], cref[1], cref[2])
    e32 = e64 = 0.0
    hit = np.flatnonzero(hits.frame >= 0)
    for i in hit:
        di = d[i]
        w = mp.mpf(1)
        if cam_ref is not None:
            di_mp, w1 = mp_rays(cam_ref, di)
            w *= w1
            _, w2 = mp_rays_mp(wall_ref, di_mp)
        else:
            _, w2 = mp_rays(wall_ref, di)
        w *= w2
        ref = 1 / w
        e64 = max(e64, float(abs(mp.mpf(float(d64[i])) - ref) / ref))
        e32 = max(e32, float(abs(mp.mpf(float(d32[i])) - ref) / ref))
    centre = (res[1] // 2) * res[0] + res[0] // 2
    return {"pixels": len(hit), "e32": e32, "e64": e64, "centre_D": float(d64[centre])}


def mp_rays_mp(parts, d):
    """mp_rays for a direction already in mpmath (no rounding to float in between)."""
    n, b, g = parts
    norm = mp.sqrt(sum(c * c for c in d))
    d = [c / norm for c in d]
    bd = b * sum(a * c for a, c in zip(n, d))
    w = g * (1 + bd)
    k = g * g / (g + 1)
    return [(dc + (k * bd + g) * b * nc) / w for dc, nc in zip(d, n)], w


# --------------------------------------------------------------------------- float32 geometry
def outline_shift(mask, ref):
    """Largest distance (in pixels, 0/1/2+) of a changed pixel from the reference outline."""
    changed = mask != ref
    if not changed.any():
        return 0
    edge = np.zeros_like(ref)
    edge[:-1] |= ref[:-1] != ref[1:]
    edge[1:] |= ref[:-1] != ref[1:]
    edge[:, :-1] |= ref[:, :-1] != ref[:, 1:]
    edge[:, 1:] |= ref[:, :-1] != ref[:, 1:]
    if not (changed & ~edge).any():
        return 1  # only pixels on the outline flipped: the outline moved by less than a pixel
    grown = edge.copy()
    grown[1:] |= edge[:-1]
    grown[:-1] |= edge[1:]
    grown[:, 1:] |= edge[:, :-1]
    grown[:, :-1] |= edge[:, 1:]
    return 2 if not (changed & ~grown).any() else 3


def far_render(res, offset=0.0, tau=0.0, beta=0.0):
    direction = np.array([1.0, 0.7, 0.3]) / np.linalg.norm([1.0, 0.7, 0.3])
    scene = ball_scene(beta=beta, segments=48, soft=0.0, tau=tau, offset=offset * direction)
    scene.camera.clip_end = 1e30
    p = render_image(scene, settings(res))
    return p["Depth"][..., 0] < 1e9, p["Combined"]


def geometry_limits(ctx, res, sec):
    scales = [0.0] + ([1e3, 1e9] if ctx.smoke else [10.0 ** k for k in range(0, 17)])
    rows = []
    results = {}
    for kind in ("offset, static", "offset, 0.9c ball", "time, 0.9c ball"):
        beta = 0.0 if kind == "offset, static" else 0.9
        ref_mask = ref_img = None
        best_outline = best_shading = 0.0
        broken_outline = broken_shading = False
        for scale in scales:
            try:
                if kind.startswith("time"):
                    mask, img = far_render(res, tau=scale, beta=beta)
                else:
                    mask, img = far_render(res, offset=scale, beta=beta)
                err = rel_rmse(img, ref_img) if ref_img is not None else 0.0
                shift = outline_shift(mask, ref_mask) if ref_mask is not None else 0
            except Exception as error:
                err, shift = math.inf, 99
                ctx.log(f"  {kind} {scale:g}: {type(error).__name__}: {error}")
            if ref_mask is None:
                ref_mask, ref_img = mask, img
            rows.append([kind, scale, shift if shift < 3 else ">2", err])
            if shift <= 1 and not broken_outline:
                best_outline = scale
            else:
                broken_outline = True
            if err < 0.01 and not broken_shading:
                best_shading = scale
            else:
                broken_shading = True
        results[kind] = (best_outline, best_shading)
    return rows, results


def run(ctx) -> Section:
    sec = Section("2. Stability against an mpmath reference (60 digits)")
    import matplotlib.pyplot as plt

    # (a) transforms
    sec.add("### Transforms")
    sec.add("")
    sec.add("Velocity along the unit axis (0.36, -0.48, 0.8) (its float value taken as exact, so the "
            "test measures the algorithm and not the input's last bit), given as a speed b or as a Lorentz "
            "factor. `events`: 12 random events of size ~10, error relative to |tau| + |x| of the result. "
            "`rays`: 17 directions (head-on, receding, perpendicular, 1e-9 .. pi - 1e-6 rad from the axis, "
            "random): D relative; d' absolute (= the direction error in radians; a unit vector in float64 "
            "holds its direction to ~1e-16 absolute, so near the axis this, not a relative error, is the limit).")
    sec.add("")
    rows = []
    worst = {}
    for kind, value in speeds(ctx.smoke):
        e = transform_errors(kind, value)
        rows.append([label(kind, value), e["gamma"], e["one_minus_b"], e["events"], e["rays_D"], e["rays_d"]])
        for k, v in e.items():
            worst[k] = max(worst.get(k, 0.0), v)
    sec.table(["speed", "gamma", "1 - b", "events", "rays: D", "rays: d'"], rows)
    cv, cg, c0, where, where_zero, pairs, sensitivity = compose_errors(ctx.smoke)
    sec.add(f"`compose_velocities` over {pairs} pairs (speeds 1e-12 .. 1 - 1e-12, parallel, antiparallel and "
            f"oblique): largest relative error of the velocity {cv:.2e} (at {where}), of its gamma {cg:.2e}. "
            + (f"That worst pair is ill-conditioned: moving one component of either float input by one ulp moves "
               f"the exact composition by {sensitivity:.1e}, so the computed velocity is far inside the "
               f"uncertainty its own inputs carry (its direction, for nearly parallel velocities near c, is set by "
               f"their last bits); " if cv >= 1e-15 else
               f"(one ulp of either input moves that pair's exact composition by {sensitivity:.1e}); ")
            + f"where the body moves with the frame (exact result 0) the largest |velocity| is {c0:.1e} (at {where_zero}; "
            f"v_par - b and v_perp are worked out exactly from the float inputs, as 1 - u.v, since near c they are "
            f"small differences divided by the small 1 - u.v = 1/gamma^2).")
    sec.add("")
    for k, v in worst.items():
        sec.number(f"transform_{k}", v)
    sec.number("compose_v", cv)
    sec.number("compose_gamma", cg)
    sec.number("compose_same", c0)
    sec.number("compose_ulp_sensitivity", sensitivity)
    worst_all = max(worst["events"], worst["rays_D"], worst["rays_d"], cg, c0)
    sec.goals.append(Goal("transforms vs mpmath, b 1e-12 .. 1-1e-12, gamma to 1e8", "~1e-15 relative (physics.md)",
                          f"events {worst['events']:.1e}, D {worst['rays_D']:.1e}, d' {worst['rays_d']:.1e}, "
                          f"compose: gamma {cg:.1e}, velocity {cv:.1e} where one ulp of input moves it {sensitivity:.0e} "
                          f"(same velocity: {c0:.1e} absolute)",
                          worst_all < 1e-15 and (cv < 1e-15 or cv < sensitivity)))  # (or within its inputs' own ulps)

    fig, ax = plt.subplots(figsize=(6.5, 3.4))
    xs = np.arange(len(rows))
    for col, name in ((3, "events"), (4, "D"), (5, "d' (absolute)")):
        ax.semilogy(xs, [max(r[col], 1e-18) for r in rows], "o-", label=name)
    ax.axhline(2.2e-16, color="grey", lw=0.8, ls=":")
    ax.set_xticks(xs, [r[0] for r in rows], rotation=60, fontsize=7, ha="right")
    ax.set_ylabel("largest relative error")
    ax.set_title("Lorentz maps vs mpmath (dotted: float64 epsilon)", fontsize=9)
    ax.legend(fontsize=7)
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(ctx.out_dir / "stability.png", dpi=80)
    plt.close(fig)
    sec.add(f"![transform errors]({ctx.plot_prefix}/stability.png)")
    sec.add("")

    # (b) rendered D
    res = (9, 9) if ctx.smoke else (17, 17)
    sec.add("### Rendered Doppler factor")
    sec.add("")
    sec.add(f"The camera inside a sphere (radius 100) moving at the given speed along -y, toward where the "
            f"camera looks (so the axis pixel sees D = gamma (1 + b)), rendered at {res[0]}x{res[1]} (odd: the centre pixel "
            "is the exact axis ray); every pixel-centre ray that hits, against the mpmath D of the same float64 "
            "ray direction. `float32 pass` = the Doppler pass as rendered; `float64` = 1 / `hits.w` of "
            "`trace_nearest` for the same rays. `camera 0.5c`: the camera moves at 0.5c along x as well "
            "(the chain camera -> S -> sphere, two boosts).")
    sec.add("")
    rows = []
    e32w = e64w = 0.0
    for kind, value in speeds(ctx.smoke):
        for cam in ((0.0, 0.0, 0.0), (0.5, 0.0, 0.0)):
            r = doppler_errors(kind, value, res, cam)
            if r is None:
                rows.append([label(kind, value), "0.5c" if cam[0] else "rest", 0, "-", "-", "-"])
                continue
            e32w, e64w = max(e32w, r["e32"]), max(e64w, r["e64"])
            rows.append([label(kind, value), "0.5c" if cam[0] else "rest", r["pixels"], r["centre_D"], r["e64"], r["e32"]])
    sec.table(["sphere speed", "camera", "pixels hit", "D on the axis", "float64 D: max rel. error",
               "float32 pass: max rel. error"], rows)
    sec.number("render_D_float64", e64w)
    sec.number("render_D_float32", e32w)
    sec.goals.append(Goal("rendered per-pixel D vs mpmath", "float64 ~1e-15; the float32 pass to its rounding (6e-8)",
                          f"float64 {e64w:.1e}, float32 pass {e32w:.1e}", e64w < 1e-13 and e32w < 1.2e-7))

    # (c) float32 geometry
    res = (24, 18) if ctx.smoke else (96, 72)
    sec.add("### Float32 geometry path: far from the origin, late in time")
    sec.add("")
    sec.add(f"The ball scene ({res[0]}x{res[1]}, ball + floor + point light) moved far away, camera and light with it "
            "(`offset`, along (1, 0.7, 0.3)), or rendered at a late observation time `tau_obs` with the moving "
            "ball's pivot set back by `beta * tau_obs`, so in exact arithmetic the image is unchanged. Compared "
            "with the render at 0: `outline` = how far any pixel whose hit/miss status changed lies from the "
            "reference outline (0 = identical mask, 1 = only outline pixels flipped = under a pixel, "
            "'>2' = broken); `shading` = relative RMSE of the Combined pass.")
    sec.add("")
    rows, results = geometry_limits(ctx, res, sec)
    sec.table(["case", "offset or tau_obs", "outline (px)", "shading rel. RMSE"], rows)
    for kind, (outline, shading) in results.items():
        sec.add(f"- {kind}: outline within a pixel up to **{outline:.0e}**, shading within 1% up to **{shading:.0e}**.")
        key = kind.replace(", ", "_").replace(" ", "_").replace(".", "")
        sec.number(f"far_{key}_outline", outline)
        sec.number(f"far_{key}_shading", shading)
    sec.add("")
    o_static, s_static = results["offset, static"]
    o_time, s_time = results["time, 0.9c ball"]
    sec.goals.append(Goal("largest coordinate with image error < 1 px", "measure",
                          f"outline {o_static:.0e}, shading {s_static:.0e} (static); "
                          f"{results['offset, 0.9c ball'][0]:.0e} / {results['offset, 0.9c ball'][1]:.0e} (0.9c)", None))
    sec.goals.append(Goal("largest time offset tau_obs with image error < 1 px (0.9c ball)", "measure",
                          f"outline {o_time:.0e}, shading {s_time:.0e}", None))
    return sec

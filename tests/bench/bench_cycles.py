"""Section 5: against Cycles (CPU, module mode) at 512x512, time for time at matched quality."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from bench_common import ROOT, Goal, Section, rel_rmse


def equal_error_time(curve, error):
    """Time the (time, error) curve needs for ``error``: log-log interpolation, or beyond its ends
    the Monte Carlo slope error ~ time^-1/2 from the nearest point (flagged)."""
    t = np.log([c[0] for c in curve])
    e = np.log([c[1] for c in curve])
    order = np.argsort(-e)  # decreasing error
    t, e = t[order], e[order]
    x = math.log(error)
    if e[-1] <= x <= e[0]:
        return float(np.exp(np.interp(-x, -e, t))), False
    i = 0 if x > e[0] else -1
    return float(np.exp(t[i] + 2.0 * (e[i] - x))), True


def run(ctx) -> Section:
    sec = Section("5. Against Cycles (CPU, bpy module mode)")
    size = ctx.pick(512, 32)
    cycles = ctx.pick([1, 4, 16, 64], [1, 4])
    cycles_ref = ctx.pick(256, 16)
    ours = ctx.pick([1, 4, 16], [1, 4])
    ours_ref = ctx.pick(64, 16)
    plan = f"CYCLES:{','.join(map(str, cycles + [cycles_ref]))};RESTFRAME:{','.join(map(str, ours + [ours_ref]))}"
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "cycles.json"
        run = subprocess.run([sys.executable, str(Path(__file__).with_name("bench_cycles_worker.py")), str(out), str(size), plan],
                             capture_output=True, text=True, cwd=ROOT, timeout=3600)
        if run.returncode != 0:
            raise RuntimeError(f"Cycles worker failed:\n{run.stderr[-3000:]}")
        results = json.loads(out.read_text())
        images = {(r["engine"], r["samples"]): np.load(r["image"]) for r in results}
    seconds = {(r["engine"], r["samples"]): r["seconds"] for r in results}
    ref_c, ref_r = images[("CYCLES", cycles_ref)], images[("RESTFRAME", ours_ref)]
    curve_c = [(seconds[("CYCLES", n)], rel_rmse(images[("CYCLES", n)], ref_c)) for n in cycles]
    curve_r = [(seconds[("RESTFRAME", n)], rel_rmse(images[("RESTFRAME", n)], ref_r)) for n in ours]
    cross = rel_rmse(ref_r, ref_c)
    mean_ratio = float(np.mean(ref_r) / np.mean(ref_c))

    sec.add(f"One static scene built with bpy (UV sphere 64x32 and a floor, Principled BSDF, a point light of "
            f"radius 0.6, black world), {size}x{size}, rendered through `bpy.ops.render.render()` by each engine "
            "with 2 threads; times are wall clock around that call (scene sync and BVH build included on both "
            "sides), in one subprocess. Cycles: CPU, no denoising, no adaptive sampling, `max_bounces = 0` (direct "
            "light only, which is what RESTframe computes for diffuse surfaces), pixel filter 0.01 (box).")
    sec.add("")
    sec.add("**Method: equal noise.** The two engines do not make the same image (their light sampling and BSDFs "
            f"differ), so each is compared with its *own* converged render (Cycles {cycles_ref} samples, RESTframe "
            f"{ours_ref} samples): error = relative RMSE against it. For each RESTframe setting the Cycles time for "
            "the same error is read off the Cycles curve (log-log interpolation; beyond its ends extrapolated "
            "with error ~ time^-1/2, marked *). Ratio = RESTframe time / Cycles time at equal error.")
    sec.add("")
    rows = []
    ratios = []
    for n in ours:
        t, e = seconds[("RESTFRAME", n)], rel_rmse(images[("RESTFRAME", n)], ref_r)
        tc, extrapolated = equal_error_time(curve_c, e)
        ratios.append(t / tc)
        rows.append([f"RESTframe {n} spp", t, e, f"{tc:.3g}{' *' if extrapolated else ''}", t / tc])
        sec.number(f"cycles_ratio_{n}", t / tc)
    for n in cycles:
        rows.append([f"Cycles {n} spp", seconds[("CYCLES", n)], rel_rmse(images[("CYCLES", n)], ref_c), "", ""])
    rows.append([f"Cycles reference {cycles_ref} spp", seconds[("CYCLES", cycles_ref)], "", "", ""])
    rows.append([f"RESTframe reference {ours_ref} spp", seconds[("RESTFRAME", ours_ref)], "", "", ""])
    sec.table(["render", "time (s)", "rel. RMSE vs own reference", "Cycles time at this error (s)",
               "RESTframe / Cycles"], rows)
    sec.add(f"The two references differ by a relative RMSE of {cross:.3f} (mean brightness ratio RESTframe / Cycles "
            f"{mean_ratio:.3f}): the same scene, not the same estimator; side by side below (Cycles left).")
    sec.add("")
    import matplotlib.pyplot as plt

    step = max(size // 200, 1)
    pair = np.concatenate([ref_c[::step, ::step], ref_r[::step, ::step]], axis=1)
    plt.imsave(ctx.out_dir / "cycles_images.png", np.clip(pair, 0.0, 1.0) ** (1 / 2.2))
    sec.add(f"![Cycles reference (left) and RESTframe reference (right)]({ctx.plot_prefix}/cycles_images.png)")
    sec.add("")
    sec.number("cycles_cross_error", cross)

    fig, ax = plt.subplots(figsize=(5, 3.4))
    ax.loglog([c[0] for c in curve_c], [c[1] for c in curve_c], "o-", label="Cycles (CPU)")
    ax.loglog([c[0] for c in curve_r], [c[1] for c in curve_r], "s-", label="RESTframe")
    for (t, e), n in zip(curve_c, cycles):
        ax.annotate(str(n), (t, e), textcoords="offset points", xytext=(3, 3), fontsize=7)
    for (t, e), n in zip(curve_r, ours):
        ax.annotate(str(n), (t, e), textcoords="offset points", xytext=(3, 3), fontsize=7)
    ax.set_xlabel("render time (s, 2 threads)")
    ax.set_ylabel("relative RMSE vs own reference")
    ax.set_title(f"{size}x{size}, samples per pixel annotated", fontsize=9)
    ax.legend(fontsize=7)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(ctx.out_dir / "cycles.png", dpi=80)
    plt.close(fig)
    sec.add(f"![RESTframe against Cycles]({ctx.plot_prefix}/cycles.png)")
    sec.add("")
    worst = max(ratios)
    sec.goals.append(Goal("against Cycles at 512x512, equal noise", "measure (time for time)",
                          f"RESTframe takes {min(ratios):.2f}x .. {worst:.2f}x Cycles' time", None))
    return sec

"""Shared helpers of the benchmark suite: timing in one run, error norms, scenes, report sections.

Timing rule: every number that is compared is a *ratio* of times measured in the same
process, interleaved (A, B, A, B, ...), so both sides see the same machine load.  Each
side's time is the minimum over the repeats (the run least disturbed by other work);
the median is kept for the record.
"""

from __future__ import annotations

import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
for path in (ROOT, ROOT / "tests" / "core"):
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))

from shapes import HyperbolicBall, box, look_at_camera, quad, uv_sphere  # noqa: E402  (tests/core/shapes.py)

from restframe_addon.core.scene import Light, Material, Mesh, RenderSettings, Scene, Velocity  # noqa: E402


# --------------------------------------------------------------------------- report pieces
@dataclass
class Goal:
    name: str
    target: str
    measured: str
    met: bool | None  # None: no pass/fail (a measurement only)
    note: str = ""


@dataclass
class Section:
    title: str
    body: list[str] = field(default_factory=list)
    goals: list[Goal] = field(default_factory=list)
    numbers: dict = field(default_factory=dict)  # name -> float, checked finite by the smoke test
    seconds: float = 0.0

    def add(self, text: str = "") -> None:
        self.body.append(text)

    def add_paragraphs(self, text: str) -> None:
        """Each paragraph of ``text`` (a docstring's, split by blank lines) as one line, a blank one after it."""
        for paragraph in text.split("\n\n"):
            self.add(" ".join(paragraph.split()))
            self.add()

    def table(self, header: list[str], rows: list[list]) -> None:
        self.body.append("| " + " | ".join(header) + " |")
        self.body.append("|" + "|".join("---" for _ in header) + "|")
        for row in rows:
            self.body.append("| " + " | ".join(fmt(c) for c in row) + " |")
        self.body.append("")

    def number(self, name: str, value) -> float:
        self.numbers[name] = float(value)
        return float(value)


def fmt(value) -> str:
    if isinstance(value, str):
        return value
    if isinstance(value, (bool, np.bool_)):
        return "yes" if value else "no"
    if isinstance(value, (int, np.integer)):
        return f"{int(value):,}".replace(",", " ")
    value = float(value)
    if value == 0.0:
        return "0"
    if not math.isfinite(value):
        return str(value)
    if abs(value) >= 1e5 or abs(value) < 1e-3:
        return f"{value:.2e}"
    if abs(value) >= 100:
        return f"{value:.0f}"
    return f"{value:.3g}"


@dataclass
class Context:
    smoke: bool
    out_dir: Path  # where the PNG plots go
    plot_prefix: str  # relative path from the report to out_dir
    log: callable = print

    def pick(self, full, smoke):
        return smoke if self.smoke else full


def standalone_context(smoke: bool) -> Context:
    """The context of a section run on its own: no plots, progress on stderr."""
    return Context(smoke=smoke, out_dir=None, plot_prefix="", log=lambda *a: print(*a, file=sys.stderr, flush=True))


def print_section(section: Section) -> None:
    """A section run on its own, printed as Markdown, then its goals."""
    print("\n".join([f"## {section.title}", "", *section.body]))
    for goal in section.goals:
        print(f"- {goal.name}: {goal.target}, measured {goal.measured}, met: {goal.met}")


def register_addon() -> None:
    """Register the add-on (its properties, which a .blend's export reads) once per process: several
    sections of one run need it, and registering a second time raises."""
    import bpy

    import restframe_addon

    if not hasattr(bpy.types.Scene, "restframe"):
        restframe_addon.register()


def load() -> float:
    return os.getloadavg()[0]


# --------------------------------------------------------------------------- timing
def _interleaved_times(funcs: dict, repeats: int, warmup: int, clock, results: dict | None = None) -> dict:
    """Each callable's ``clock`` seconds over ``repeats`` rounds after ``warmup`` untimed ones, the order
    reversed every other round; name -> [seconds].  ``results``: where each one's last result is kept
    (None: each is dropped at once)."""
    for _ in range(warmup):
        for f in funcs.values():
            f()
    times = {name: [] for name in funcs}
    names = list(funcs)
    for r in range(repeats):
        for name in (names if r % 2 == 0 else names[::-1]):
            t0 = clock()
            if results is None:
                funcs[name]()
            else:
                results[name] = funcs[name]()
            times[name].append(clock() - t0)
    return times


def interleaved(funcs: dict, repeats: int, warmup: int = 1) -> dict:
    """Time each callable ``repeats`` times, interleaved; returns name -> {min, median, result}."""
    results = {}
    times = _interleaved_times(funcs, repeats, warmup, time.perf_counter, results)
    return {name: {"min": min(t), "median": float(np.median(t)), "result": results[name], "all": t}
            for name, t in times.items()}


def cpu_interleaved(funcs: dict, repeats: int, warmup: int = 1) -> dict:
    """Like :func:`interleaved`, in CPU seconds of this process (one thread: immune to the other work
    of a shared machine), the results not kept; returns name -> min."""
    return {name: min(t) for name, t in _interleaved_times(funcs, repeats, warmup, time.process_time).items()}


def wall_interleaved(funcs: dict, repeats: int, warmup: int = 1) -> dict:
    """Like :func:`cpu_interleaved`, in wall seconds (for work on several threads)."""
    return {name: min(t) for name, t in _interleaved_times(funcs, repeats, warmup, time.perf_counter).items()}


def timed(f):
    t0 = time.perf_counter()
    value = f()
    return time.perf_counter() - t0, value


# --------------------------------------------------------------------------- errors
def rel_rmse(image, reference) -> float:
    """Root-mean-square error over pixels and RGB channels, divided by the reference's mean."""
    image = np.asarray(image, dtype=np.float64)[..., :3]
    reference = np.asarray(reference, dtype=np.float64)[..., :3]
    return float(np.sqrt(np.mean((image - reference) ** 2)) / max(np.mean(reference), 1e-300))


# --------------------------------------------------------------------------- scenes
def settings(resolution, **kw) -> RenderSettings:
    """Render settings for the benchmarks: one thread unless told otherwise."""
    kw.setdefault("threads", 1)
    return RenderSettings(resolution=tuple(resolution), **kw)


def ball_scene(beta=0.0, segments=48, soft=0.0, lights=True, tau=0.0, offset=(0.0, 0.0, 0.0), aspect=4 / 3,
               emissive_floor=False):
    """A UV sphere (optionally moving along x) over a floor, one point light, camera in front."""
    o = np.asarray(offset, dtype=np.float64)
    v, t = uv_sphere((0.0, 0.0, 0.0), 1.0, segments, max(segments // 2, 3))
    fv, ft = quad((0.0, 0.0, -1.0), (12.0, 12.0))
    vel = Velocity((beta, 0.0, 0.0)) if beta else Velocity()
    # pivot at the ball's centre shifted back by beta*tau, so at tau the ball is in view
    pivot = o - np.array([beta, 0.0, 0.0]) * tau
    meshes = [Mesh("ball", v + pivot, t, velocity=vel, pivot=tuple(pivot), material_indices=np.zeros(len(t), int)),
              Mesh("floor", fv + o, ft, material_indices=np.ones(len(ft), int))]
    materials = [Material("ball", base_color=(0.8, 0.3, 0.2), roughness=0.4),
                 Material("floor", base_color=(0.7, 0.7, 0.7), roughness=0.8,
                          emission=(0.2, 0.2, 0.2) if emissive_floor else (0.0, 0.0, 0.0))]
    light_list = [Light("lamp", "POINT", tuple(o + (3.0, -4.0, 5.0)), power=2500.0, radius=soft)] if lights else []
    camera = look_at_camera(o + (0.0, -6.0, 1.5), o + (0.0, 0.0, -0.2), aspect=aspect)
    return Scene(camera=camera, meshes=meshes, materials=materials, lights=light_list,
                 world_color=(0.05, 0.06, 0.08), tau_obs=tau)

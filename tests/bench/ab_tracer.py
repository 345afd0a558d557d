"""Before/after of the tracer's bookkeeping and the sample jitter, both checkouts in one process, interleaved.

    git worktree add /tmp/base origin/main
    tools/dev.sh tests/bench/ab_tracer.py /tmp/base              # this checkout against /tmp/base

One render of ``moving_sphere.blend`` (960x540, 8 samples, one thread) by this checkout records
every call the shader makes to ``tracer.trace_nearest`` and ``tracer.occluded``, the passes to
``tracer.hit_geometry`` and render_tile to ``sampling.stratified_positions`` (their arguments, as
they were); then each checkout's own functions replay those calls, the checkouts in turn
(alternating which goes first), each with its own warm ``TraceCache``.  Times are CPU seconds of
one replay of all the recorded calls of a function (embree included), min over the repeats: the
process's memory layout and the machine's load fall on both alike (ab_cpu.py's separate processes
differ by up to 15% even for the same checkout).  ``same`` says whether both checkouts return the
same bits for every call.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import inspect
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve()
FUNCTIONS = (("shading", "trace_nearest"), ("shading", "occluded"), ("passes", "hit_geometry"),
             ("sampling", "stratified_positions"))


def _load(root: str):
    """The tracer and sampling modules of the checkout at ``root`` (imported afresh)."""
    sys.path.insert(0, root)
    for name in [name for name in sys.modules if name.split(".")[0] == "restframe_addon"]:
        del sys.modules[name]
    from restframe_addon.core import sampling, tracer
    sys.path.pop(0)
    return {"trace_nearest": tracer.trace_nearest, "occluded": tracer.occluded, "hit_geometry": tracer.hit_geometry,
            "stratified_positions": sampling.stratified_positions, "TraceCache": tracer.TraceCache}


def _record(root: str) -> dict:
    """The calls of one moving_sphere render by the checkout at ``root``: name -> [(args, kwargs)]."""
    sys.path[:0] = [root + "/tests/bench", root]
    from bench_parallel import export_blend

    import restframe_addon
    from restframe_addon.core import passes, prepared, sampling, shading
    from restframe_addon.core.render import render_tiles

    restframe_addon.register()
    scene, settings = export_blend("moving_sphere.blend", (960, 540), 8, None)
    prep = prepared.prepare(scene, dataclasses.replace(settings, parallelism="THREADS", threads=1))
    list(render_tiles(prep, threads=1))  # (warm: the thread's cache, malloc's tuning)
    calls = {name: [] for _, name in FUNCTIONS}
    modules = {"shading": shading, "passes": passes, "sampling": sampling}
    originals = {}
    for module, name in FUNCTIONS:
        originals[name] = getattr(modules[module], name)
        setattr(modules[module], name, _recording(originals[name], calls[name]))
    list(render_tiles(prep, threads=1))
    for module, name in FUNCTIONS:
        setattr(modules[module], name, originals[name])
    sys.path[:2] = []
    return calls


def _recording(func, calls: list):
    def recorded(*args, **kwargs):
        calls.append((tuple(_kept(a) for a in args), {k: _kept(v) for k, v in kwargs.items()}))
        return func(*args, **kwargs)
    return recorded


def _kept(value):
    """A copy of an array argument (broadcast views stay views: the tracer tells them apart)."""
    if isinstance(value, np.ndarray) and 0 not in value.strides:
        return value.copy()
    return value


def _replay(functions: dict, name: str, calls: list, cache) -> list:
    """One side's results of the recorded calls of ``name``, with its own cache for the recording's
    (optional arguments a side's function does not take yet, worked-out data such as the strata's
    starts, left out: it works them out itself)."""
    own = lambda value: cache if type(value).__name__ == "TraceCache" else value  # noqa: E731
    func = functions[name]
    taken = len(inspect.signature(func).parameters)
    return [func(*map(own, args[:taken]), **{k: own(v) for k, v in kwargs.items()}) for args, kwargs in calls]


def _bits(value) -> list:
    """Every array in a result, as bytes (dataclasses and tuples opened)."""
    if isinstance(value, (tuple, list)):
        return [b for v in value for b in _bits(v)]
    if dataclasses.is_dataclass(value):
        return [b for f in dataclasses.fields(value) for b in _bits(getattr(value, f.name))]
    if isinstance(value, np.ndarray):
        return [value.dtype.str.encode() + str(value.shape).encode() + np.ascontiguousarray(value).tobytes()]
    return [repr(value).encode()]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("before", help="the checkout to compare against (a git worktree)")
    parser.add_argument("--after", default=str(HERE.parents[2]), help="default: this checkout")
    parser.add_argument("--repeats", type=int, default=9)
    args = parser.parse_args()
    calls = _record(args.after)
    from restframe_addon.core import blas  # (the recording checkout's: render_tiles keeps BLAS on one thread)

    from bench_common import cpu_interleaved  # (after the recording, which imports the --after checkout's core first)

    sides = {"after": _load(args.after), "before": _load(args.before)}
    caches = {side: functions["TraceCache"]() for side, functions in sides.items()}
    same = {}
    with blas.single_threaded():
        for side, functions in sides.items():  # warm each side's cache; compare the results
            for _, name in FUNCTIONS:
                same.setdefault(name, []).append(_bits(_replay(functions, name, calls[name], caches[side])))
        best = cpu_interleaved({(side, name): functools.partial(_replay, sides[side], name, calls[name], caches[side])
                                for side in ("before", "after") for _, name in FUNCTIONS}, args.repeats, warmup=0)
    print(f"moving_sphere's recorded calls replayed, CPU seconds, min of {args.repeats} interleaved repeats")
    print("| function | calls | before | after | after / before | same bits |\n|---|---|---|---|---|---|")
    for _, name in FUNCTIONS:
        before, after = best["before", name], best["after", name]
        print(f"| {name} | {len(calls[name])} | {before:.4f} | {after:.4f} | {after / before:.2f} | "
              f"{same[name][0] == same[name][1]} |")
    total_before = sum(best["before", name] for _, name in FUNCTIONS)
    total_after = sum(best["after", name] for _, name in FUNCTIONS)
    print(f"| all | | {total_before:.4f} | {total_after:.4f} | {total_after / total_before:.2f} | |")
    return 0


if __name__ == "__main__":
    sys.exit(main())

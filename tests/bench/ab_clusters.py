"""Before/after in one process for the culling clusters (``frames._clusters``): the base
checkout's ``frames.py`` and this one's, loaded as two modules, timed in turns (alternating the
order, ``bench_common.cpu_interleaved``) on a random 132-triangle mesh (a row of the 11x11 bars)
and a 261k-triangle one, CPU microseconds (min of the rounds); checks that both give the same
clusters bit for bit.

    git worktree add /tmp/base origin/main
    tools/dev.sh tests/bench/ab_clusters.py /tmp/base --rounds 15
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
from pathlib import Path

import numpy as np

from bench_common import cpu_interleaved

REPO = Path(__file__).resolve().parents[2]


def load(path: Path, name: str):
    """``frames.py`` at ``path`` as the module restframe_addon.core.<name> (its relative imports resolve)."""
    spec = importlib.util.spec_from_file_location(f"restframe_addon.core.{name}", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("base", help="the other checkout")
    parser.add_argument("--rounds", type=int, default=15)
    args = parser.parse_args()
    sys.path.insert(0, str(REPO))
    import restframe_addon.core  # noqa: F401  (the package the two modules live in)

    modules = {"before": load(Path(args.base) / "restframe_addon/core/frames.py", "frames_before"),
               "after": load(REPO / "restframe_addon/core/frames.py", "frames_after")}
    rng = np.random.default_rng(1)
    meshes = {"132 triangles": (rng.normal(size=(80, 3)), rng.integers(0, 80, size=(132, 3)), 100),
              "261k triangles": (rng.normal(size=(150_000, 3)), rng.integers(0, 150_000, size=(261_000, 3)), 1)}
    def calling(module, vertices, triangles, calls):
        return lambda: [module._clusters(vertices, triangles) for _ in range(calls)]

    seconds = cpu_interleaved({(label, mesh): calling(module, *meshes[mesh]) for label, module in modules.items()
                               for mesh in meshes}, args.rounds)
    best = {(label, mesh): seconds[label, mesh] / meshes[mesh][2] * 1e6 for label, mesh in seconds}
    same = all(np.array_equal(modules["before"]._clusters(v, t), modules["after"]._clusters(v, t))
               for v, t, _ in meshes.values())
    print("| | " + " | ".join(meshes) + " |\n|---|" + "---|" * len(meshes))
    for label in modules:
        print(f"| {label} | " + " | ".join(f"{best[label, mesh]:.0f} us" for mesh in meshes) + " |")
    print("clusters bit-identical:", same)


if __name__ == "__main__":
    main()

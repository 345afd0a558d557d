"""Time to prepare and render scenes with thousands of distinct velocities (issue 9).

    tools/dev.sh tests/robustness/measure_velocities.py [COUNT ...]

Small quads each with its own velocity (one rest frame each) and a point light, the scene of
``test_a_thousand_distinct_velocities_finish``; a 32x32 render, one thread.  Not part of the test run.
"""

import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
for path in (HERE.parents[1], HERE, HERE.parent / "core"):
    sys.path.insert(0, str(path))

from test_robustness_core import many_velocities_scene, settings  # noqa: E402

from restframe_addon.core.prepared import prepare  # noqa: E402
from restframe_addon.core.render import render_tiles  # noqa: E402


def main(counts):
    for count in counts:
        scene = many_velocities_scene(count)
        started = time.perf_counter()
        prepared_scene = prepare(scene, settings((32, 32)))
        prepared = time.perf_counter()
        list(render_tiles(prepared_scene))
        print(f"{count} velocities: prepare {prepared - started:.2f} s, 32x32 render {time.perf_counter() - prepared:.2f} s")


if __name__ == "__main__":
    main([int(a) for a in sys.argv[1:]] or [1000, 2000])

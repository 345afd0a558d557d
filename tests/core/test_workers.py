"""Tiles in worker processes (core.workers): the same bits as threads, the scene pickled once,
only the core imported in a worker, Esc reaching into the tile a worker renders, a killed
worker's tiles dealt again, the extension's in-memory package path recreated, workers ending
with their parent."""

import dataclasses
import glob
import io
import mmap
import os
import pickle
import shutil
import signal
import subprocess
import sys
import tempfile
import textwrap
import time

import numpy as np
import pytest
from test_prepared import MODES, assemble, assert_same_passes, busy_scene, settings

from restframe_addon.core import render as render_module
from restframe_addon.core import workers
from restframe_addon.core.prepared import prepare
from restframe_addon.core.render import RenderError, render_tiles
from restframe_addon.core.scene import Scene, Velocity

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


@pytest.fixture(scope="module")
def pool():
    pool = workers.WorkerPool()
    yield pool
    pool.close()


def in_threads(prepared):
    return assemble(prepared, render_tiles(dataclasses.replace(prepared, settings=dataclasses.replace(
        prepared.settings, parallelism="THREADS")), threads=2))


@pytest.mark.parametrize("mode", MODES, ids=["rgb", "spectral", "factor", "transparent"])
def test_processes_render_the_same_bits_as_threads(mode):
    """Through render_tiles and the session's pool, as the engine renders."""
    prepared = prepare(busy_scene(Velocity((0.0, 0.4, 0.0))), settings(tile_size=8, parallelism="PROCESSES", **mode))
    warnings = []
    assert_same_passes(assemble(prepared, render_tiles(prepared, threads=2, warn=warnings.append)), in_threads(prepared))
    assert warnings == [] and len(workers.pool().pids) == 2


def test_the_scene_is_pickled_once_per_render_and_not_again_for_the_same_scene(pool, monkeypatch):
    pickled = []
    monkeypatch.setattr(Scene, "__reduce_ex__", lambda self, protocol: pickled.append(self)
                        or object.__reduce_ex__(self, protocol))
    first = prepare(busy_scene(), settings(tile_size=6))
    second = prepare(busy_scene(Velocity((0.3, 0.0, 0.0))), settings(tile_size=6))
    started = []
    for prepared in (first, first, second):  # 12 tiles each, two workers
        assert_same_passes(assemble(prepared, pool.render(prepared, lambda: False, 2)), in_threads(prepared))
        started.append(pool.pids)
    assert pickled == [first.scene, second.scene]  # a new scene replaces the old one in the workers
    assert started[0] == started[1] == started[2] and len(started[0]) == 2  # kept warm


def test_a_worker_imports_only_the_core(pool):
    prepared = prepare(busy_scene(), settings())
    assemble(prepared, pool.render(prepared, lambda: False, 2))
    answers = pool.status()
    assert len(answers) == 2
    for answer in answers.values():
        modules = answer["modules"]
        assert "restframe_addon.core.render" in modules and "embreex" in modules
        assert not [m for m in modules if m.split(".")[0] in {"bpy", "_bpy", "mathutils", "__mp_main__", "pytest"}]
        assert not [m for m in modules if m.startswith("restframe_addon.") and not m.startswith("restframe_addon.core")]


def test_esc_stops_the_tile_a_worker_renders_and_the_tiles_it_holds(pool):
    """One worker, four tiles of 5-9 sample batches each: Esc after a moment leaves at most the
    tile it was rendering, cut short, and the next render is still right."""
    prepared = prepare(busy_scene(), settings(tile_size=12, samples=4096))
    polls = []
    tiles = list(pool.render(prepared, lambda: polls.append(1) or len(polls) > 20, 1))
    answers = pool.status()
    answer = answers.pop(pool.pids[0])  # the one worker used
    assert all(other["late_shares"] == [] for other in answers.values())
    assert len(tiles) + len(answer["late_shares"]) <= 2  # dealt before Esc: two; the second never started
    assert len(answer["late_shares"]) <= 1 and not any(answer["late_shares"])  # cut short
    small = prepare(busy_scene(), settings(tile_size=8))
    assert_same_passes(assemble(small, pool.render(small, lambda: False, 1)), in_threads(small))


def test_a_killed_workers_tiles_are_dealt_again(pool):
    prepared = prepare(busy_scene(Velocity((0.0, 0.4, 0.0))), settings(tile_size=4))
    tiles = []
    for tile in pool.render(prepared, lambda: False, 2):
        if not tiles:
            os.kill(pool.pids[0], signal.SIGKILL)
        tiles.append(tile)
    assert len(tiles) == len(prepared.tiles()) and len(pool.pids) == 1
    assert_same_passes(assemble(prepared, tiles), in_threads(prepared))


def test_without_a_python_it_renders_in_threads_with_a_warning(monkeypatch):
    monkeypatch.setattr(sys, "executable", "")
    prepared = prepare(busy_scene(), settings(tile_size=8))
    pool, warnings = workers.WorkerPool(), []
    assert_same_passes(assemble(prepared, pool.render(prepared, lambda: False, 2, warnings.append)),
                       in_threads(prepared))
    assert len(warnings) == 1 and "sys.executable is ''" in warnings[0] and pool.pids == []


def test_a_python_that_cannot_run_workers_falls_back_to_threads_for_the_session(monkeypatch):
    monkeypatch.setattr(sys, "executable", "/bin/false")  # starts, and ends at once
    prepared = prepare(busy_scene(), settings(tile_size=8))
    pool, warnings = workers.WorkerPool(), []
    for _ in range(2):
        assert_same_passes(assemble(prepared, pool.render(prepared, lambda: False, 2, warnings.append)),
                           in_threads(prepared))
    assert warnings == ["every worker process ended: rendering the rest in threads",
                        "no worker process started with /bin/false (see the console): rendering in threads"]


def test_the_worker_count_follows_the_request_and_the_memory():
    gib = 1 << 30
    assert workers.worker_count(8, 0, None) == 8
    assert workers.worker_count(8, 0, 64 * gib) == 8
    assert workers.worker_count(8, 0, gib) == gib // workers._WORKER_MEMORY
    assert workers.worker_count(8, 100 << 20, 4 * gib) < workers.worker_count(8, 0, 4 * gib)
    assert workers.worker_count(8, 0, 0) == 1  # always one: the render goes on, if slowly


def test_a_worker_error_reaches_the_render():
    """An error in a worker (here: a tile with a bad corner) is raised by the render."""
    prepared = prepare(busy_scene(), settings())
    broken = workers.WorkerPool()
    try:
        with pytest.raises(TypeError):
            list(broken.render(_with_tiles(prepared, [(0, 0, 24, 18), (0, 0, "24", 18)]), lambda: False, 1))
    finally:
        broken.close()


def _with_tiles(prepared, rects):
    class Tiled(type(prepared)):
        def tiles(self, area=None):
            return rects
    return Tiled(**{f.name: getattr(prepared, f.name) for f in dataclasses.fields(prepared)})


def test_the_extensions_package_path_is_recreated_and_the_main_script_not_rerun(tmp_path):
    """As inside Blender: the add-on imported as bl_ext.user_default.restframe.restframe_addon from
    packages that exist only in memory, rendering from a script run as __main__."""
    marker = tmp_path / "runs"
    script = tmp_path / "blender_script.py"
    script.write_text(textwrap.dedent(f"""
        import importlib, json, sys, types
        with open({str(marker)!r}, "a") as runs:
            runs.write("run\\n")
        sys.path[:] = [p for p in sys.path if p not in ({ROOT!r}, "")] + [{os.path.join(ROOT, "tests", "core")!r}]
        for name in ("bl_ext", "bl_ext.user_default", "bl_ext.user_default.restframe"):
            package = types.ModuleType(name)
            package.__path__ = [{ROOT!r}] if name.endswith("restframe") else []
            sys.modules[name] = package
        base = "bl_ext.user_default.restframe.restframe_addon.core."
        prepared_module, render, scene, workers = (importlib.import_module(base + m)
                                                    for m in ("prepared", "render", "scene", "workers"))
        import numpy as np
        camera = scene.Camera(matrix=np.array([[1, 0, 0, 0], [0, 0, -1, -3], [0, 1, 0, 1], [0, 0, 0, 1.0]]))
        tri = np.array([[-2, 0, -2], [2, 0, -2], [0, 0, 3.0]]), np.array([[0, 1, 2]])
        world = scene.Scene(camera=camera, meshes=[scene.Mesh("tri", *tri, velocity=scene.Velocity((0.5, 0, 0)))],
                            lights=[scene.Light("lamp", "POINT", (0, -2, 2), power=50.0)], light_speed=1.0)
        images = []
        for parallelism in ("PROCESSES", "THREADS"):
            prepared = prepared_module.prepare(world, scene.RenderSettings(
                resolution=(16, 12), tile_size=4, samples=2, threads=2, parallelism=parallelism))
            tiles = sorted(render.render_tiles(prepared, warn=print), key=lambda t: (t.y0, t.x0))
            images.append(np.concatenate([t.passes["Combined"].ravel() for t in tiles]))
        modules = list(workers.pool().status().values())[0]["modules"]
        print(json.dumps({{"same": bool(np.array_equal(images[0].view(np.uint32), images[1].view(np.uint32))),
                          "core": [m for m in modules if m.endswith(".core.render")],
                          "bpy": [m for m in modules if m.startswith(("bpy", "_bpy"))]}}))
    """))
    result = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    assert result.stdout.strip().splitlines()[-1] == (
        '{"same": true, "core": ["bl_ext.user_default.restframe.restframe_addon.core.render"], "bpy": []}')
    assert marker.read_text() == "run\n"  # the workers did not run the script again


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_workers_end_with_their_parent(tmp_path):
    """Killed parent: the watchdog ends its workers, which remove the scene's file; closed pool: EOF
    ends them (they exit, not killed) and the file is gone."""
    script = tmp_path / "parent.py"
    script.write_text(textwrap.dedent(f"""
        import os, sys, time
        sys.path[:0] = [{ROOT!r}, {os.path.join(ROOT, "tests", "core")!r}]
        from test_prepared import busy_scene, settings
        from restframe_addon.core import workers
        from restframe_addon.core.prepared import prepare
        pool = workers.WorkerPool()
        prepared = prepare(busy_scene(), settings(tile_size=8))
        list(pool.render(prepared, lambda: False, 2))
        print(*pool.pids, flush=True)
        print(os.getpid(), os.path.exists(pool._scene_files.paths[0]), flush=True)
        if sys.argv[1] == "close":
            codes = [worker.process for worker in pool._workers]
            pool.close()
            print(*[process.returncode for process in codes], flush=True)
        else:
            time.sleep(600)
    """))
    closing = subprocess.run([sys.executable, str(script), "close"], capture_output=True, text=True, timeout=300)
    assert closing.returncode == 0, closing.stderr
    lines = closing.stdout.split("\n")
    assert lines[2].split() == ["0", "0"] and lines[1].split()[1] == "True" and not _scene_files(lines[1].split()[0])
    parent = subprocess.Popen([sys.executable, str(script), "orphan"], stdout=subprocess.PIPE, text=True)
    try:
        pids = [int(pid) for pid in parent.stdout.readline().split()]
        assert len(pids) == 2 and parent.stdout.readline().split() == [str(parent.pid), "True"]
    finally:
        parent.kill()
        parent.wait()
    for _ in range(600):  # the watchdog checks every 0.2 s
        if not any(_alive(pid) for pid in pids):
            break
        time.sleep(0.1)
    assert not any(_alive(pid) for pid in pids)
    assert not _scene_files(parent.pid)
    # SIGTERM to the whole process group: the parent dies of it at once, the workers remove its file
    group = subprocess.Popen([sys.executable, str(script), "orphan"], stdout=subprocess.PIPE, text=True,
                             start_new_session=True)
    try:
        pids = [int(pid) for pid in group.stdout.readline().split()]
        assert group.stdout.readline().split() == [str(group.pid), "True"]
    finally:
        os.killpg(group.pid, signal.SIGTERM)
        group.wait()
    for _ in range(100):
        if not any(_alive(pid) for pid in pids):
            break
        time.sleep(0.1)
    assert not any(_alive(pid) for pid in pids) and not _scene_files(group.pid)


def _scene_files(pid):
    return [path for folder in workers._SHARED_FOLDERS
            for path in glob.glob(os.path.join(folder, f"restframe-scene-{pid}-*"))] + _results_files(pid)


def _results_files(pid):
    return [path for folder in workers._SHARED_FOLDERS
            for path in glob.glob(os.path.join(folder, f"restframe-tiles-{pid}-*"))]


def _alive(pid):
    try:
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().split(") ")[1][0] != "Z"
    except FileNotFoundError:
        return False


def test_an_unknown_parallelism_is_refused():
    with pytest.raises(RenderError, match="parallelism 'GPU'"):
        prepare(busy_scene(), settings(parallelism="GPU"))


def _rows_of(shares, rects):
    """Every (tile index, row) the shares cover, in dealing order."""
    return [(index, y) for index, rows in shares for y in range(*(rows or rects[index][1::2]))]


@pytest.mark.parametrize("workers_count", [1, 2, 16])
def test_the_shares_cover_every_row_of_every_tile_once_in_tile_order(workers_count):
    rects = prepare(busy_scene(), settings(resolution=(960, 540), tile_size=256)).tiles()
    shares = workers.share_out(rects, workers_count)
    assert _rows_of(shares, rects) == [(index, y) for index, rect in enumerate(rects) for y in range(rect[1], rect[3])]
    pixels = [(rects[i][2] - rects[i][0]) * ((rows or rects[i][1::2])[1] - (rows or rects[i][1::2])[0])
              for i, rows in shares]
    if workers_count == 1:
        assert shares == [(index, None) for index in range(len(rects))]  # one worker: whole tiles
    else:  # guided: whole tiles first, smaller bands towards the end, none below the minimum (but a tile's last rows)
        assert (shares[0] == (0, None)) == (workers_count == 2)
        assert len(shares) >= workers._SHARES_PER_WORKER * workers_count
        assert max(pixels[-3:]) <= 960 * 540 / (workers_count * workers._SHARES_PER_WORKER)
        assert min(pixels) >= min(workers._MIN_SHARE_PIXELS, 192 * 28) / 2


def test_a_band_of_rows_is_batched_as_in_its_whole_tile(monkeypatch):
    """Each pixel's samples are summed in the same groups whether its tile renders whole or in
    bands (here the tile's pixels are split into two parts with different batch sizes)."""
    monkeypatch.setattr(render_module, "_MAX_VALUES", 3 * 288)

    def groups(n, share=None):
        start = share.start if share else 0
        by_pixel = {}
        for part, first, count in render_module._batches(n, 4, 3, share):
            for pixel in range(part.start + start, part.stop + start):
                by_pixel.setdefault(pixel, []).append((first, count))
        return by_pixel

    whole = groups(432)
    assert {len(grouping) for grouping in whole.values()} == {2, 4}  # the test means something
    banded = {}
    for y0 in range(0, 18, 5):  # bands of 5 rows of 24 pixels
        banded.update(groups(432, slice(24 * y0, 24 * min(y0 + 5, 18))))
    assert banded == whole


def test_bands_of_tiles_render_the_same_bits_as_whole_tiles(pool, monkeypatch):
    monkeypatch.setattr(workers, "_MIN_SHARE_PIXELS", 1)
    monkeypatch.setattr(render_module, "_MAX_VALUES", 3 * 100)  # several sample batches per tile
    prepared = prepare(busy_scene(Velocity((0.0, 0.4, 0.0))), settings(tile_size=12, samples=5))
    assert_same_passes(assemble(prepared, pool.render(prepared, lambda: False, 2)), in_threads(prepared))
    stats = pool.last_stats
    assert stats.shares > len(prepared.tiles()) and len(stats.rendered) == 2


def test_render_stats_account_for_every_share(pool):
    prepared = prepare(busy_scene(), settings(tile_size=6))
    tiles = []
    for tile in pool.render(prepared, lambda: False, 2):
        sum(range(20000))  # the caller's own work between tiles (the engine: streaming into Blender)
        tiles.append(tile)
    stats = pool.last_stats
    assert len(tiles) == len(prepared.tiles()) and stats.workers == 2 and sorted(stats.builds) == sorted(pool.pids)
    assert stats.caller_cpu > 0
    rendered = [share for shares in stats.rendered.values() for share in shares]
    assert len(rendered) == stats.shares and sum(share[1] for share in rendered) == 24 * 18
    assert sorted({share[0] for share in rendered}) == list(range(len(tiles)))
    for _, _, started, ended, cpu in rendered:
        assert stats.started <= started <= ended <= stats.ended and cpu >= 0
    for started, ended, cpu in stats.builds.values():
        assert stats.started <= started <= ended <= stats.ended
    assert stats.pickling > 0 and stats.parent_seconds > 0
    list(pool.render(prepared, lambda: False, 2))  # the same scene again: not pickled, sent or rebuilt
    assert pool.last_stats.pickling == 0 and pool.last_stats.builds == {}


def test_shares_come_back_in_the_results_image_and_it_is_removed(pool, monkeypatch):
    """Every share, bands too, is written in place (nothing comes through the pipes), and a
    worker keeps only the image the parent keeps mapped, until its file goes.  A whole render's image is kept for the next render of its
    size, which takes it (its pages stay mapped here) once no tile of it is held; while one is,
    the next render makes its own and removes the kept file (the held tiles outlive it,
    unchanged); a render of another size removes it too."""
    monkeypatch.setattr(workers, "_MIN_SHARE_PIXELS", 1)
    prepared = prepare(busy_scene(Velocity((0.0, 0.4, 0.0))), settings(tile_size=12, samples=2))
    others = set(_results_files(os.getpid())) - {image.path for image in pool._kept}  # other pools' images
    tiles = list(pool.render(prepared, lambda: False, 2))
    stats = pool.last_stats
    assert stats.shares > len(prepared.tiles()) and stats.in_place == stats.shares
    (first,) = [image.path for image in pool._kept]
    assert set(_results_files(os.getpid())) - others == {first}
    assert set().union(*(_mapped_results(pid) for pid in pool.pids)) <= {first}
    expected = assemble(prepared, tiles)
    assert_same_passes(expected, in_threads(prepared))
    again = assemble(prepared, pool.render(prepared, lambda: False, 2))  # the first render's tiles are held
    (second,) = [image.path for image in pool._kept]
    assert second != first and set(_results_files(os.getpid())) - others == {second}
    assert_same_passes(assemble(prepared, tiles), expected) and assert_same_passes(again, expected)
    del tiles
    assert_same_passes(assemble(prepared, pool.render(prepared, lambda: False, 2)), expected)
    assert [image.path for image in pool._kept] == [second]  # taken again: no tile of it was held
    smaller = prepare(busy_scene(), settings(tile_size=12, resolution=(12, 6)))
    list(pool.render(smaller, lambda: False, 2))
    assert second not in _results_files(os.getpid()) and len(pool._kept) == 1
    deadline = time.monotonic() + 5.0  # an idle worker lets a removed image go within _WATCHDOG
    while any(second in _mapped_results(pid) for pid in pool.pids) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(second in _mapped_results(pid) for pid in pool.pids)


def _mapped_results(pid) -> set:
    """The results images the process ``pid`` maps."""
    with open(f"/proc/{pid}/maps") as maps:
        return {line.split()[5] for line in maps if "restframe-tiles-" in line}


def test_a_stopped_render_keeps_no_results_image(pool):
    """A render stopped early may have shares out, which a worker could still write: its image
    is removed, not kept for the next render."""
    prepared = prepare(busy_scene(), settings(tile_size=6))
    list(pool.render(prepared, lambda: False, 2))
    (kept,) = [image.path for image in pool._kept]
    for _ in pool.render(prepared, lambda: True, 2):
        pass
    assert pool._kept == [] and kept not in _results_files(os.getpid())
    renders = iter(pool.render(prepared, lambda: False, 2))
    next(renders)
    renders.close()  # the caller stopped iterating
    assert pool._kept == []


def test_a_large_results_image_is_not_kept_between_renders(pool, monkeypatch):
    """Keeping a finished render's image saves page faults, not worth holding a large image's
    shared memory until the next render: above ``_KEPT_RESULTS_BYTES`` its file goes at once."""
    prepared = prepare(busy_scene(), settings(tile_size=6))
    list(pool.render(prepared, lambda: False, 2))
    (kept,) = pool._kept
    path = kept.path
    monkeypatch.setattr(workers, "_KEPT_RESULTS_BYTES", kept.values.nbytes - 1)
    del kept
    list(pool.render(prepared, lambda: False, 2))  # (takes the kept image, then lets it go)
    assert pool._kept == [] and path not in _results_files(os.getpid())


def test_a_results_image_that_cannot_be_removed_yet_goes_with_the_next_render(pool, monkeypatch):
    """As on Windows, where a file stays while the tiles that map it live."""
    remove = os.remove

    def refuse(path):
        if "restframe-tiles-" in path:
            raise PermissionError(path)
        remove(path)

    prepared = prepare(busy_scene(), settings(tile_size=12))
    held = list(pool.render(prepared, lambda: False, 2))  # kept, but held: not taken again
    (first,) = [image.path for image in pool._kept]
    monkeypatch.setattr(os, "remove", refuse)
    list(pool.render(prepared, lambda: False, 2))
    assert pool._unremoved == [first] and first in _results_files(os.getpid())
    monkeypatch.setattr(os, "remove", remove)
    del held
    list(pool.render(prepared, lambda: False, 2))
    assert first not in _results_files(os.getpid()) and pool._unremoved == []


def test_without_room_for_a_results_image_the_results_come_through_the_pipes(pool, monkeypatch):
    monkeypatch.setattr(workers, "_SHARED_FOLDERS", ("/nonexistent-folder",))
    monkeypatch.setattr(workers, "_MIN_SHARE_PIXELS", 1)
    # a size of its own: an image kept from an earlier render of this pool would be taken again
    prepared = prepare(busy_scene(Velocity((0.0, 0.4, 0.0))), settings(tile_size=12, samples=2, resolution=(30, 18)))
    assert_same_passes(assemble(prepared, pool.render(prepared, lambda: False, 2)), in_threads(prepared))
    assert pool.last_stats.in_place == 0 and pool.last_stats.shares > len(prepared.tiles())


def test_bands_in_place_and_through_the_pipe_make_one_tile():
    """A tile whose bands came back both ways (a worker could not map the image) is whole, in
    the image; without a file the bands that came through the pipes are whole too."""
    rects, rect, layout = [(0, 0, 2, 2), (2, 4, 5, 8)], (2, 4, 5, 8), {"Combined": 4, "Depth": 1}
    whole = {name: np.arange(12 * channels, dtype=np.float32).reshape(4, 3, channels) + 100 * channels
             for name, channels in layout.items()}
    results = workers._ResultsImage.create(rects, layout)
    try:
        in_place = workers._write_share(results.place(1), rect, (4, 6),
                                        {name: value[:2] for name, value in whole.items()})
        results.put(1, rect, (6, 8), {name: value[2:] for name, value in whole.items()})
        tile = results.tile(1, rect)
    finally:
        workers._remove(results.path)
    assert in_place and (tile.x0, tile.y0, tile.x1, tile.y1) == rect
    assert all(np.array_equal(tile.passes[name], whole[name]) for name in layout)
    assert not workers._write_share(results.place(1), rect, None, whole)  # file gone
    own = workers._ResultsImage(None, None, layout, results.offsets)  # no room for a file
    assert own.place(1) is None
    for rows in ((6, 8), (4, 6)):
        own.put(1, rect, rows, {name: value[rows[0] - 4:rows[1] - 4] for name, value in whole.items()})
    tile = own.tile(1, rect)
    assert all(np.array_equal(tile.passes[name], whole[name]) for name in layout) and own._own == {}


@pytest.mark.parametrize("mode", MODES, ids=["rgb", "spectral", "factor", "transparent"])
def test_a_scene_built_ahead_is_not_sent_again_and_renders_with_the_measured_values(pool, monkeypatch, mode):
    """The workers build while this process prepares; the render sends only the pre-passes'
    values (FACTOR: the measured Doppler range) and counts the pickling done ahead."""
    pickled = []
    monkeypatch.setattr(Scene, "__reduce_ex__", lambda self, protocol: pickled.append(self)
                        or object.__reduce_ex__(self, protocol))
    scene, render_settings = busy_scene(Velocity((0.0, 0.4, 0.0))), settings(tile_size=8, **mode)
    pool.build_ahead(scene, render_settings, 2)
    held = {worker.scene_id for worker in pool._workers}  # sent before preparing
    prepared = prepare(scene, render_settings)
    tiles = list(pool.render(prepared, lambda: False, 2))
    stats = pool.last_stats
    assert pickled == [scene] and stats.pickling > 0 and len(stats.builds) == 2
    assert len(held) == 1 and held == {worker.scene_id for worker in pool._workers} != {None}
    assert_same_passes(assemble(prepared, tiles), in_threads(prepared))


def test_a_scene_built_ahead_with_other_settings_is_sent_again(pool):
    scene = busy_scene()
    pool.build_ahead(scene, settings(tile_size=8), 2)
    prepared = prepare(scene, settings(tile_size=8, samples=3))
    assert_same_passes(assemble(prepared, pool.render(prepared, lambda: False, 2)), in_threads(prepared))
    assert len(pool.last_stats.builds) == 2
    assert all(started >= pool.last_stats.started for started, _, _ in pool.last_stats.builds.values())


def test_two_tiles_go_to_two_workers(pool):
    """The first round deals one share to every worker (dealing two to the first would leave the
    second idle)."""
    prepared = prepare(busy_scene(), settings(resolution=(24, 12), tile_size=12))
    assert_same_passes(assemble(prepared, pool.render(prepared, lambda: False, 2)), in_threads(prepared))
    assert sorted(len(shares) for shares in pool.last_stats.rendered.values()) == [1, 1]


@pytest.mark.parametrize("reader_threads", [False, True], ids=["selector", "reader threads"])
def test_the_workers_messages_come_whole_and_in_order_however_the_pipe_cuts_them(reader_threads):
    """A message split across reads, and several in one write, come out whole and in order, then
    the writer's end as ("dead",): in this process's loop (selectors) and through reader threads
    (Windows, where pipes cannot be selected)."""
    child = textwrap.dedent("""
        import pickle, struct, sys, time
        out = sys.stdout.buffer
        frames = [pickle.dumps(("tile", k, "x" * 70000 * k)) for k in range(3)]
        frames = [struct.pack("<Q", len(f)) + f for f in frames]
        out.write(frames[0][:5]); out.flush(); time.sleep(0.05)  # a cut inside the length
        out.write(frames[0][5:] + frames[1][:100]); out.flush(); time.sleep(0.05)
        out.write(frames[1][100:] + frames[2]); out.flush()
    """)

    class Writer:
        def __init__(self):
            self.process = subprocess.Popen([sys.executable, "-c", child], stdout=subprocess.PIPE)
            self.pid, self.receiving_cpu = self.process.pid, 0.0

    inbox, writer = workers._Inbox(reader_threads=reader_threads), Writer()
    inbox.add(writer)
    messages, deadline = [], time.monotonic() + 30
    while (not messages or messages[-1][0] != "dead") and time.monotonic() < deadline:
        messages += [message for source, message in inbox.take(0.05) if source is writer]
    writer.process.wait()
    assert messages == [("tile", k, "x" * 70000 * k) for k in range(3)] + [("dead",)]


@pytest.mark.parametrize("reader_threads", [False, True], ids=["selector", "reader threads"])
def test_reading_the_workers_pipes_allocates_no_buffer_a_read(reader_threads):
    """Many small messages are read into one buffer, not each into a fresh one of the read's size
    (os.read of 1 MiB: a mapping made and unmapped per read)."""
    tracemalloc = pytest.importorskip("tracemalloc")
    child = textwrap.dedent("""
        import pickle, struct, sys, time
        out = sys.stdout.buffer
        for k in range(40):
            frame = pickle.dumps(("tile", k))
            out.write(struct.pack("<Q", len(frame)) + frame); out.flush(); time.sleep(0.002)
    """)

    class Writer:
        def __init__(self):
            self.process = subprocess.Popen([sys.executable, "-c", child], stdout=subprocess.PIPE)
            self.pid, self.receiving_cpu = self.process.pid, 0.0

    inbox, writer = workers._Inbox(reader_threads=reader_threads), Writer()
    tracemalloc.start()
    try:
        inbox.add(writer)
        messages, deadline = [], time.monotonic() + 30
        while (not messages or messages[-1][0] != "dead") and time.monotonic() < deadline:
            messages += [message for source, message in inbox.take(0.05) if source is writer]
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    writer.process.wait()
    assert messages == [("tile", k) for k in range(40)] + [("dead",)]
    assert peak < 4 * workers._READ_BYTES, peak


def test_a_workers_built_comes_with_its_first_share(pool, monkeypatch):
    """A scene built ahead says so with the worker's first share, in one read: no read (and no
    wake-up of the render loop) for the "built" alone; the render's stats still have each build."""
    reads = []
    read_chunk = workers._Inbox._read_chunk

    def recorded(worker, pending, buffer, take):
        kinds = []
        alive = read_chunk(worker, pending, buffer, lambda item: (kinds.append(item[1][0]), take(item)))
        reads.append(kinds)
        return alive

    monkeypatch.setattr(workers._Inbox, "_read_chunk", staticmethod(recorded))
    scene, render_settings = busy_scene(Velocity((0.0, 0.3, 0.0))), settings(tile_size=6)
    pool.build_ahead(scene, render_settings, 2)
    prepared = prepare(scene, render_settings)
    assert_same_passes(assemble(prepared, pool.render(prepared, lambda: False, 2)), in_threads(prepared))
    assert any("built" in kinds for kinds in reads)
    assert all("tile" in kinds for kinds in reads if "built" in kinds), reads
    assert sorted(pool.last_stats.builds) == sorted(pool.pids[:2])


def test_processes_render_the_same_bits_through_reader_threads():
    """Windows' way of reading the workers (a reader thread per worker) on this platform."""
    pool = workers.WorkerPool()
    pool._inbox = workers._Inbox(reader_threads=True)
    try:
        prepared = prepare(busy_scene(Velocity((0.0, 0.4, 0.0))), settings(tile_size=6))
        assert_same_passes(assemble(prepared, pool.render(prepared, lambda: False, 2)), in_threads(prepared))
        assert pool.last_stats.receiving_cpu > 0 and not pool._inbox.in_this_thread
    finally:
        pool.close()


class _Dealt:
    """What _Pace reads of a worker: the shares it holds."""

    def __init__(self, *shares):
        self.dealt = dict.fromkeys(shares)


def test_short_shares_are_dealt_for_a_batch_and_the_loop_sleeps_half_of_it():
    """Shares shorter than _BATCH: each worker is dealt work for 2 _BATCH and the loop sleeps a
    batch, or half the work a worker holds, between rounds; with little left a worker, two shares
    each.  Long shares: two each, and the loop waits for each."""
    rects = [(0, y, 100, y + 10) for y in range(0, 1000, 10)]  # 100 tiles of 1000 pixels
    shares = [(tile, None) for tile in range(len(rects))]
    pace = workers._Pace(shares, rects)
    todo = list(enumerate(shares))[4:]
    worker = _Dealt(0, 1)
    batching = pace.batching(todo, 2)
    assert pace.wants(_Dealt(0), batching) and not pace.wants(worker, batching)  # none finished yet: two
    assert pace.pause([worker]) == 0
    assert pace.finished(0, 0.25 * workers._BATCH) == 1000  # a share takes a quarter of a batch
    assert pace.batching(todo, 2)
    assert pace.wants(_Dealt(0, 1, 2, 3, 4, 5, 6), True)  # 7 shares: 1.75 batches of work
    assert not pace.wants(_Dealt(*range(8)), True)  # 8: 2 batches
    assert pace.pause([_Dealt(*range(8)), _Dealt(*range(8, 16))]) == workers._BATCH
    assert pace.pause([_Dealt(*range(8)), _Dealt(8, 9)]) == pytest.approx(0.25 * workers._BATCH)  # half of 2 shares
    assert pace.pause([_Dealt(*range(8)), _Dealt()], todo) == 0  # a worker with nothing: wait for the first message
    # nothing left to deal: no sleep once each worker holds at most two shares (the render's end), a sleep before
    assert pace.pause([_Dealt(0, 1), _Dealt(2)], []) == 0 and pace.pause([_Dealt(0, 1)], []) == 0
    assert pace.pause([_Dealt(0, 1, 2), _Dealt(3)], []) == pytest.approx(0.125 * workers._BATCH)
    assert pace.pause([_Dealt(0, 1), _Dealt(2)], todo) > 0  # more to deal: one wake-up for several shares
    end = todo[-8:]  # 2 batches of work left: 1 a worker, so no more than two shares each
    assert not pace.batching(end, 2) and not pace.wants(_Dealt(0, 1), pace.batching(end, 2))
    assert pace.batching(end, 1) and pace.wants(_Dealt(0, 1), pace.batching(end, 1))  # one worker: nobody to wait for
    slow = workers._Pace(shares, rects)
    slow.finished(0, 3 * workers._BATCH)  # a share takes 1.5 batches a worker
    assert not slow.batching(todo, 2) and slow.pause([_Dealt(0, 1), _Dealt(2, 3)]) == 0


def test_short_shares_render_the_same_bits_in_batches_with_fewer_wake_ups(pool, monkeypatch):
    """With shares far shorter than a batch, the loop wakes fewer times than shares come, the
    worker holding more than two, and the pixels are those of threads."""
    prepared = prepare(busy_scene(), settings(tile_size=4))
    list(pool.render(prepared, lambda: False, 1))  # a warm worker: its first share is no slower than the rest
    monkeypatch.setattr(workers, "_BATCH", 0.5)
    takes, held = [], []
    take, deal = workers._Inbox.take, workers.WorkerPool._deal

    def counted_take(self, timeout):
        messages = take(self, timeout)
        takes.append(len(messages))
        return messages

    def counted_deal(self, workers_, *args):
        deal(self, workers_, *args)
        held.append(max(len(worker.dealt) for worker in workers_))

    monkeypatch.setattr(workers._Inbox, "take", counted_take)
    monkeypatch.setattr(workers.WorkerPool, "_deal", counted_deal)
    tiles = list(pool.render(prepared, lambda: False, 1))
    assert_same_passes(assemble(prepared, tiles), in_threads(prepared))
    shares = pool.last_stats.shares
    assert shares == len(prepared.tiles()) == 30
    assert len([count for count in takes if count]) < shares and max(held) > workers._TILES_IN_FLIGHT, (takes, held)
    # the tiles of one wake-up say that another follows, but the last of each: one a wake-up that brought tiles
    last_of_rounds = [tile for tile in tiles if not tile.more_ready]
    assert not tiles[-1].more_ready and len(last_of_rounds) <= len([count for count in takes if count]) < shares


def test_once_every_share_is_dealt_the_loop_deals_no_more(pool, monkeypatch):
    """The wake-ups after the last share is dealt (one a finished share) do not go through the
    workers to deal nothing; the pixels are those of threads."""
    prepared = prepare(busy_scene(), settings(tile_size=4))
    queued, deal = [], workers.WorkerPool._deal

    def counted_deal(self, workers_, todo, *args):
        queued.append(len(todo))
        deal(self, workers_, todo, *args)

    monkeypatch.setattr(workers.WorkerPool, "_deal", counted_deal)
    tiles = list(pool.render(prepared, lambda: False, 2))
    assert_same_passes(assemble(prepared, tiles), in_threads(prepared))
    assert queued and 0 not in queued, queued


def test_in_the_tail_of_long_shares_a_worker_holds_one_share_and_the_loop_does_not_sleep():
    rects = [(0, y, 100, y + 10) for y in range(0, 1000, 10)]  # 100 tiles of 1000 pixels
    shares = [(tile, None) for tile in range(len(rects))]
    pace = workers._Pace(shares, rects)
    todo = list(enumerate(shares))
    assert not pace.tail(todo[-2:], 2)  # nothing finished yet: no estimate
    pace.finished(0, workers._TAIL_SECONDS)
    tail = todo[-workers._TAIL_SHARES * 2:]
    assert not pace.tail(todo[-workers._TAIL_SHARES * 2 - 1:], 2) and pace.tail(tail, 2)
    assert not pace.tail(tail, 1)  # one worker: nobody to balance with
    assert pace.wants(_Dealt(), False, True) and not pace.wants(_Dealt(0), False, True)
    assert pace.wants(_Dealt(0), False, False)  # before the tail: two each
    short = workers._Pace(shares, rects)
    short.finished(0, workers._TAIL_SECONDS / 2)  # short shares: a round trip would weigh, no tail
    assert not short.tail(tail, 2) and short.pause([_Dealt(1, 2), _Dealt(3, 4)], tail) > 0
    assert pace.pause([_Dealt(1), _Dealt(3)], tail) == 0


def test_a_workers_messages_of_a_round_go_in_one_write(pool):
    """The measurements of a scene built ahead and a worker's first shares: one write (each
    costs both processes a system call, and the worker a wake-up)."""

    class Recorded:
        def __init__(self, stream):
            self.stream, self.writes = stream, []

        def write(self, data):
            stream = io.BytesIO(data)
            self.writes.append([pickle.load(stream)[0] for _ in iter(lambda: stream.tell() < len(data), False)])
            return self.stream.write(data)

        def __getattr__(self, name):
            return getattr(self.stream, name)

    scene, render_settings = busy_scene(), settings(tile_size=6)
    pool.build_ahead(scene, render_settings, 2)
    prepared = prepare(scene, render_settings)
    for worker in pool._workers:
        worker.process.stdin = Recorded(worker.process.stdin)
    try:
        assert_same_passes(assemble(prepared, pool.render(prepared, lambda: False, 2)), in_threads(prepared))
        assert [worker.process.stdin.writes[0] for worker in pool._workers] == [["measured", "tile", "tile"]] * 2
    finally:
        for worker in pool._workers:
            worker.process.stdin = worker.process.stdin.stream


@pytest.mark.parametrize("mapped", [True, False], ids=["mapped", "read"])
def test_a_pickled_scene_file_gives_back_aligned_writable_arrays(tmp_path, monkeypatch, mapped):
    """Its arrays out of band: each read back as a view of the file's one buffer (mapped or read),
    aligned, writable."""
    monkeypatch.setattr(workers, "_MAP_SCENE_FILES", mapped)
    large = workers._IN_BAND_BYTES // 8
    value = {"a": np.arange(large, dtype=np.float64), "b": np.arange(12, dtype=np.int32).reshape(3, 4)[:, 1:],
             "f": np.asfortranarray(np.arange(2.0 * large).reshape(2, large)), "text": "x", "empty": np.zeros(0),
             "small": np.arange(5.0)}
    pickled = workers._Pickled(value)
    assert len(pickled.arrays) == 2  # the large ones out of band: not in the pickle
    with open(tmp_path / "scene", "wb") as file:
        pickled.write(file)
    assert pickled.size == os.path.getsize(tmp_path / "scene")
    back = workers._Pickled.read(str(tmp_path / "scene"))
    assert back.keys() == value.keys() and back["text"] == "x"
    for name in ("a", "b", "f", "empty", "small"):
        assert np.array_equal(back[name], value[name]) and back[name].dtype == value[name].dtype
    for name in ("a", "f"):
        assert back[name].flags.writeable and back[name].ctypes.data % workers._ALIGN == 0


def test_a_scene_file_goes_into_the_first_shared_folder_with_room_else_the_temporary_folder(tmp_path, monkeypatch):
    """Shared memory first (no file system blocks to allocate: the write is what an F12 waits
    for), a folder without room for the file twice over skipped, the temporary folder last."""
    pickled = workers._Pickled({"a": np.arange(workers._IN_BAND_BYTES // 4, dtype=np.float64)})
    small, roomy = tmp_path / "small", tmp_path / "roomy"
    small.mkdir(), roomy.mkdir()
    usage = shutil.disk_usage
    monkeypatch.setattr(workers.shutil, "disk_usage", lambda folder: usage(folder)._replace(
        free=2 * pickled.size - 1 if str(folder) == str(small) else 2 * pickled.size))
    monkeypatch.setattr(workers, "_SHARED_FOLDERS", (str(tmp_path / "missing"), str(small), str(roomy)))
    path = pickled.save("restframe-scene-test-")
    assert os.path.dirname(path) == str(roomy) and os.listdir(small) == []
    assert workers._Pickled.read(path)["a"].tolist() == list(range(workers._IN_BAND_BYTES // 4))
    monkeypatch.setattr(workers, "_SHARED_FOLDERS", (str(small),))
    path = pickled.save("restframe-scene-test-")
    try:
        assert os.path.dirname(path) == tempfile.gettempdir() and os.path.getsize(path) == pickled.size
    finally:
        os.remove(path)


@pytest.mark.skipif(sys.platform == "win32", reason="a worker reads the scene's file there (a mapped file cannot be removed)")
def test_a_worker_maps_the_scene_file_copy_on_write_and_its_arrays_outlive_the_file(tmp_path):
    """A worker's scene arrays are views of a private mapping of the file the parent wrote (its
    pages shared, not copied into the worker's memory): writing to them leaves the file as it
    was, and they stay whole once the file is removed (the parent removes it for the next scene)."""
    value = {"a": np.arange(workers._IN_BAND_BYTES // 4, dtype=np.float64)}
    path = tmp_path / "scene"
    with open(path, "wb") as file:
        workers._Pickled(value).write(file)
    written = path.read_bytes()
    back = workers._Pickled.read(str(path))["a"]
    base = back
    while not isinstance(base, mmap.mmap) and getattr(base, "base", None) is not None:
        base = base.base
    base = base.obj if isinstance(base, memoryview) else base
    assert isinstance(base, mmap.mmap)
    back[0] = -1.0
    assert path.read_bytes() == written
    os.remove(path)
    assert back[0] == -1.0 and np.array_equal(back[1:], value["a"][1:])


def test_a_worker_runs_as_batch_work_at_the_same_nice(pool):
    """Linux: SCHED_BATCH, so a worker woken by the parent's message does not preempt the parent
    mid-deal (the next worker's shares were written milliseconds later)."""
    if not hasattr(os, "SCHED_BATCH"):
        pytest.skip("no SCHED_BATCH here")
    prepared = prepare(busy_scene(), settings())
    assemble(prepared, pool.render(prepared, lambda: False, 2))
    for pid in pool.pids:
        assert os.sched_getscheduler(pid) == os.SCHED_BATCH
        assert os.getpriority(os.PRIO_PROCESS, pid) == os.getpriority(os.PRIO_PROCESS, 0)


def test_a_scene_warmed_as_it_is_built_finds_no_tiles_emptiness_again(monkeypatch):
    """render.warm_up finds every tile's emptiness at once; the shares of whole tiles then look
    for none again, and the measured scene keeps what was found but not the kept passes."""
    from test_render import lone_ball_off_centre

    from restframe_addon.core.prepared import build_unmeasured, measured_as
    from restframe_addon.core.tracer import TraceCache

    prepared = prepare(lone_ball_off_centre(), settings(resolution=(44, 40), tile_size=8, threads=2))
    built, cache = build_unmeasured(prepared.scene, prepared.settings), TraceCache()
    built_unseen = render_module.warm_up(built, cache)
    unseen = built_unseen.measured(measured_as(built, prepared.measurements))
    monkeypatch.setattr(type(prepared), "each_misses_everything", lambda *args: pytest.fail("looked again"))
    tiles = [render_module.render_tile(unseen.prepared, rect, cache=cache, unseen=unseen) for rect in prepared.tiles()]
    assert built_unseen._passes == {} and unseen._passes  # kept for the measured scene alone
    monkeypatch.undo()
    assert_same_passes(assemble(prepared, iter(tiles)), in_threads(prepared))


def test_a_workers_mapping_of_the_results_image_is_kept_until_its_file_goes(monkeypatch):
    rects, layout = [(0, 0, 4, 2), (0, 2, 4, 4)], {"Combined": 4, "Depth": 1}
    share = {name: np.full((2, 4, channels), 7.0, np.float32) for name, channels in layout.items()}
    results = workers._ResultsImage.create(rects, layout)
    mapping, maps = workers._ResultsMapping(), []
    real_mmap = mmap.mmap
    monkeypatch.setattr(workers.mmap, "mmap", lambda *args, **kw: maps.append(args) or real_mmap(*args, **kw))
    try:
        assert workers._write_share(results.place(0), rects[0], None, share, mapping)
        assert workers._write_share(results.place(1), rects[1], None, share, mapping)
        assert len(maps) == 1 and mapping.held  # one mapping for both shares
        mapping.release_if_gone()
        assert mapping.held  # its file is still there: kept for the next render
        assert np.all(results.values == 7.0)
    finally:
        workers._remove(results.path)
    mapping.release_if_gone()
    assert not mapping.held
    monkeypatch.setattr(workers, "_KEPT_RESULTS_BYTES", 8)  # too large to keep
    again = workers._ResultsImage.create(rects, layout)
    try:
        assert workers._write_share(again.place(0), rects[0], None, share, mapping) and not mapping.held
    finally:
        workers._remove(again.path)


def test_a_scene_file_names_the_arrays_an_earlier_file_holds_and_writes_only_the_others(tmp_path):
    """An array byte for byte one of the last scene's (a texture exported again for the next F12)
    is named by its file and place, not written again; read back through both files, every array
    is whole; a changed array (its last byte) is written."""
    large = workers._IN_BAND_BYTES // 8
    first = {"kept": np.arange(large, dtype=np.float64), "changed": np.ones(large), "f": np.asfortranarray(
        np.arange(2.0 * large).reshape(2, large))}
    known = workers._SceneFiles()
    pickled = workers._Pickled(first, known)
    known.replace(pickled.save(str(tmp_path / "one-")), pickled)
    first_path = known.paths[0]
    second = {"kept": first["kept"].copy(), "changed": first["changed"].copy(), "f": first["f"].copy(order="F"),
              "text": "x"}
    second["changed"][-1] = 2.0
    again = workers._Pickled(second, known)
    assert [array.nbytes for array in again.arrays] == [second["changed"].nbytes] and again.named == [first_path]
    assert again.size < pickled.size - 2 * first["kept"].nbytes
    known.replace(again.save(str(tmp_path / "two-")), again)
    assert known.paths[1:] == [first_path] and os.path.exists(first_path)
    back = workers._Pickled.read(tuple(known.paths))
    assert back.keys() == second.keys() and back["text"] == "x"
    for name in ("kept", "changed", "f"):
        assert np.array_equal(back[name], second[name]) and back[name].dtype == second[name].dtype
        assert back[name].flags.writeable and back[name].ctypes.data % workers._ALIGN == 0
    assert back["f"].flags.f_contiguous
    third = workers._Pickled({"other": np.zeros(large)}, known)  # names nothing: the earlier files go
    known.replace(third.save(str(tmp_path / "three-")), third)
    assert not os.path.exists(first_path) and len(known.paths) == 1 and sorted(os.listdir(tmp_path)) == [
        os.path.basename(known.paths[0])]
    known.clear()
    assert os.listdir(tmp_path) == [] and known.paths == []


def test_a_new_scene_sends_only_its_changed_arrays_and_renders_the_same_bits(pool, monkeypatch):
    """Two F12s of one scene exported twice (the camera's velocity changed): the second scene's
    file names the first's mesh arrays instead of holding them, the workers build it from both
    files to the same bits as threads; a scene that shares nothing removes the first file."""
    monkeypatch.setattr(workers, "_IN_BAND_BYTES", 256)  # busy_scene's meshes out of band
    first, second = (prepare(busy_scene(velocity), settings(tile_size=6)) for velocity in (
        Velocity(), Velocity((0.3, 0.0, 0.0))))
    files = []
    for prepared in (first, second):
        assert_same_passes(assemble(prepared, pool.render(prepared, lambda: False, 2)), in_threads(prepared))
        files.append(list(pool._scene_files.paths))
    assert len(files[0]) == 1 and files[1][1:] == files[0]
    assert os.path.getsize(files[1][0]) < os.path.getsize(files[0][0]) / 2
    monkeypatch.setattr(workers, "_IN_BAND_BYTES", 1 << 30)  # nothing out of band: nothing named
    third = prepare(busy_scene(Velocity((0.0, 0.3, 0.0))), settings(tile_size=6))
    assert_same_passes(assemble(third, pool.render(third, lambda: False, 2)), in_threads(third))
    assert not any(os.path.exists(path) for path in files[1]) and len(pool._scene_files.paths) == 1


def test_a_workers_build_leaves_the_check_to_the_preparing_process(pool, monkeypatch):
    """build_unmeasured does not check the scene again (prepare does, meanwhile); a scene that
    prepare refuses after the workers built it ahead is never rendered, and the pool renders the
    next one."""
    from restframe_addon.core import prepared as prepared_module
    from restframe_addon.core.prepared import build_unmeasured

    checked = []
    check = prepared_module.check_render
    monkeypatch.setattr(prepared_module, "check_render", lambda *args: checked.append(args) or check(*args))
    good = busy_scene()
    build_unmeasured(good, settings())
    assert checked == []
    prepare(good, settings())
    assert len(checked) == 1
    refused = settings(passes=("NoSuchPass",))
    pool.build_ahead(busy_scene(), refused, 2)
    with pytest.raises(RenderError, match="NoSuchPass"):
        prepare(busy_scene(), refused)
    later = prepare(busy_scene(), settings(tile_size=8))
    assert_same_passes(assemble(later, pool.render(later, lambda: False, 2)), in_threads(later))


def test_the_files_a_scene_names_hold_at_most_twice_its_bytes_before_they_are_written_again(tmp_path):
    """Each scene keeps one array of an earlier file and changes the rest: once the files hold more
    than twice the scene's bytes, the next scene names only the last file and writes the others'
    arrays again, and the earlier files go."""
    large = workers._IN_BAND_BYTES // 8
    known, versions = workers._SceneFiles(), {name: 0 for name in "abcd"}
    scenes, paths = [], []
    for changed in ("abcd", "bcd", "cd", "d"):
        for name in changed:
            versions[name] += 1
        value = {name: np.full(large, float(10 * version + ord(name))) for name, version in versions.items()}
        pickled = workers._Pickled(value, known)
        known.replace(pickled.save(str(tmp_path / f"{len(scenes)}-")), pickled)
        scenes.append(value)
        paths.append(list(known.paths))
        back = workers._Pickled.read(tuple(known.paths))
        assert all(np.array_equal(back[name], value[name]) for name in value)
    assert [len(files) for files in paths] == [1, 2, 3, 2]
    assert paths[3][1:] == paths[2][:1] and not any(os.path.exists(path) for path in paths[2][1:])
    assert sorted(os.listdir(tmp_path)) == sorted(os.path.basename(path) for path in paths[3])
    known.clear()

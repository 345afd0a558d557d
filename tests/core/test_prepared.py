"""The prepared scene: one immutable object that any tile split, thread count or process
renders to the same bits; nothing in it changes while it renders."""

import multiprocessing
import pickle
from concurrent.futures import ProcessPoolExecutor
from types import MappingProxyType

import numpy as np
import pytest
from scenes import busy_scene

from restframe_addon.core import prepared as prepared_module
from restframe_addon.core import render
from restframe_addon.core.lorentz import Boost
from restframe_addon.core.passes import ALL_PASSES, DEFAULT_PASSES, EXTRA_PASSES, PASSES
from restframe_addon.core.prepared import prepare
from restframe_addon.core.render import render_image, render_tile, render_tiles
from restframe_addon.core.scene import RenderSettings, Velocity
from restframe_addon.core.tracer import TraceCache, trace_nearest
from restframe_addon.core.validation import check_velocity


def settings(**kw):
    return RenderSettings(**{"resolution": (24, 18), "threads": 1, "samples": 2, **kw})


def assert_same_passes(a: dict, b: dict):
    assert a.keys() == b.keys()
    for name in a:
        assert a[name].dtype == b[name].dtype and a[name].shape == b[name].shape, name
        assert np.array_equal(a[name].view(np.uint8), b[name].view(np.uint8)), name  # bit for bit


def assemble(prepared, tiles):
    width, height = prepared.settings.resolution
    out = {name: np.zeros((height, width, ALL_PASSES[name]), np.float32) for name in ("Combined", *prepared.passes)}
    for tile in tiles:
        assert tile.complete
        for name, data in tile.passes.items():
            out[name][tile.y0:tile.y1, tile.x0:tile.x1] = data
    return out


MODES = [dict(), dict(doppler_mode="SPECTRAL", spectral_samples=6, normalize_exposure=True),
         dict(doppler_mode="FACTOR", doppler_levels=4), dict(film_transparent=True, searchlight=False)]


@pytest.mark.parametrize("mode", MODES, ids=["rgb", "spectral", "factor", "transparent"])
def test_any_tile_split_renders_the_same_bits_as_render_image(mode):
    """Odd tiles of render_tile, each with a fresh trace cache, against render_image's 16-px tiles."""
    scene = busy_scene()
    whole = render_image(scene, settings(tile_size=16, **mode))
    prepared = prepare(scene, settings(**mode))
    rects = [(x, y, min(x + 7, 24), min(y + 5, 18)) for y in range(0, 18, 5) for x in range(0, 24, 7)]
    assert_same_passes(assemble(prepared, [render_tile(prepared, rect) for rect in rects]), whole)


def test_two_threads_render_the_same_bits_as_one():
    prepared = prepare(busy_scene(Velocity((0.0, 0.4, 0.0))), settings(tile_size=4))
    one = assemble(prepared, render_tiles(prepared, threads=1))
    assert_same_passes(assemble(prepared, render_tiles(prepared, threads=2)), one)


def test_a_pickled_prepared_scene_renders_the_same_bits_without_measuring_again(monkeypatch):
    scene = busy_scene(Velocity((0.0, 0.4, 0.0)))
    for mode in (dict(doppler_mode="FACTOR"), dict(doppler_mode="SPECTRAL", spectral_samples=4,
                                                     normalize_exposure=True)):
        prepared = prepare(scene, settings(**mode))
        data = pickle.dumps(prepared)

        def measured_again(*args):
            raise AssertionError("the pre-pass ran again")

        with monkeypatch.context() as patch:
            patch.setattr(prepared_module, "_measure_doppler_range", measured_again)
            patch.setattr(prepared_module, "_measure_exposure", measured_again)
            rebuilt = pickle.loads(data)
        assert (rebuilt.doppler_range, rebuilt.exposure) == (prepared.doppler_range, prepared.exposure)
        assert rebuilt.frames is not prepared.frames
        rect = (3, 2, 20, 15)
        assert_same_passes(render_tile(rebuilt, rect).passes, render_tile(prepared, rect).passes)


def test_another_process_renders_the_same_tile():
    """What a process-parallel renderer does: send the prepared scene, get a tile back."""
    prepared = prepare(busy_scene(), settings())
    rect = (0, 0, 24, 18)
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        tile = pool.submit(render_tile, prepared, rect).result(timeout=120)
    assert_same_passes(tile.passes, render_tile(prepared, rect).passes)


def test_the_frame_set_is_read_only_and_rendering_changes_nothing_in_it():
    prepared = prepare(busy_scene(), settings(tile_size=8))
    frames = prepared.frames
    before = dict(vars(frames))
    assemble(prepared, render_tiles(prepared, threads=2))
    assert vars(frames).keys() == before.keys()
    for name, value in vars(frames).items():
        assert value is before[name], name
        assert isinstance(value, (int, tuple, MappingProxyType, np.ndarray)), f"FrameSet.{name} is a {type(value)}"
        if isinstance(value, np.ndarray):
            assert not value.flags.writeable, name
    for k in frames.geometry:
        geometry = frames.frames[k].geometry
        assert not geometry.vertices.flags.writeable and not geometry.triangles.flags.writeable
    with pytest.raises(Exception):
        prepared.exposure = 2.0


def test_the_trace_cache_changes_no_hit():
    """Culling cones and body boxes kept by a TraceCache give the very hits computed afresh."""
    prepared = prepare(busy_scene(), settings())
    frames, cache = prepared.frames, TraceCache()
    for rect in prepared.tiles() * 2:  # the second round reads the cache
        rays = prepared.centre_rays(rect)
        cached, fresh = trace_nearest(frames, frames.camera, *rays, cache), trace_nearest(frames, frames.camera, *rays)
        for name in ("frame", "s", "prim", "u", "v"):
            assert np.array_equal(getattr(cached, name), getattr(fresh, name))


def test_render_tiles_never_yields_a_tile_cut_short(monkeypatch):
    """Esc between the sample batches of a tile: render_tile says so, render_tiles drops it."""
    monkeypatch.setattr(render, "_MAX_VALUES", 24 * 18 * 3)  # one sample per batch
    prepared = prepare(busy_scene(), settings(samples=3, tile_size=64))

    def stop_from_call(n):
        calls = []
        return lambda: calls.append(1) or len(calls) >= n

    tile = render_tile(prepared, prepared.region, stop_from_call(1))  # asked first before the second batch
    assert not tile.complete
    assert render_tile(prepared, prepared.region, stop_from_call(3)).complete
    assert list(render_tiles(prepared, stop_from_call(2))) == []  # asked once before the tile, then in it


def test_velocity_errors_have_one_wording_in_every_layer():
    """The core's boost and the add-on's export both word a tachyon the same (validation.py)."""
    with pytest.raises(ValueError) as core:
        Boost.from_velocity((0.0, 0.0, 1.5), name="Tachyon")
    assert str(core.value) == ("Tachyon: speed 1.5 c is not below the speed of light; "
                               "use the Lorentz factor for speeds very close to c")
    with pytest.raises(ValueError, match="Tachyon: a Lorentz factor must be at least 1 .got 0.5.; 0 means unused"):
        check_velocity((0.1, 0.0, 0.0), 0.5, "Tachyon")
    with pytest.raises(ValueError, match="Tachyon: a Lorentz factor above 1 needs a velocity"):
        Boost.from_velocity((0.0, 0.0, 0.0), 3.0, name="Tachyon")


def test_the_pass_table_keeps_its_public_names_and_order():
    assert list(PASSES) == ["Doppler", "Emission Time", "Object Time"]
    assert EXTRA_PASSES == {"Doppler": 1, "Emission Time": 1, "Object Time": 1, "Depth": 1, "Normal": 3, "IndexOB": 1,
                            "Denoising Normal": 3, "Denoising Albedo": 3}
    assert list(DEFAULT_PASSES) == list(EXTRA_PASSES)[:6]  # the denoising data only when asked for
    assert list(ALL_PASSES) == ["Combined", *EXTRA_PASSES] and ALL_PASSES["Combined"] == 4
    assert (render.PASSES, render.EXTRA_PASSES, render.ALL_PASSES) == (PASSES, EXTRA_PASSES, ALL_PASSES)


@pytest.mark.parametrize("threads, tile_size, resolution, expected_size", [
    (1, 256, (255, 255), (256, 256)),  # one worker: the one tile
    (2, 256, (255, 255), (256, 128)),  # two workers: the height halved, 2 tiles
    (4, 256, (255, 255), (128, 128)),  # then the width
    (5, 256, (255, 255), (128, 64)),
    (2, 256, (32, 32), (256, 16)),  # 2 bands, not 4 squares: a worker renders one tile, not two
    (2, 16, (24, 18), (16, 16)),  # already 4 tiles
    (8, 20, (24, 18), (10, 10)),  # halved (rounding up) to 6 tiles, then no further below 8 pixels
    (3, 10, (10, 10), (10, 10)),  # not split below 8 pixels
])
def test_an_image_is_split_into_at_least_one_tile_per_worker(threads, tile_size, resolution, expected_size):
    """Each worker renders whole tiles: with fewer tiles than workers the tile's height and width
    are halved in turn (no more tiles than needed: each costs a render_tile call), and the pixels
    stay the same."""
    prepared = prepare(busy_scene(), settings(resolution=resolution, threads=threads, tile_size=tile_size))
    width, height = resolution
    tile_width, tile_height = expected_size
    expected = [(x, y, min(x + tile_width, width), min(y + tile_height, height))
                for y in range(0, height, tile_height) for x in range(0, width, tile_width)]
    assert prepared.tiles() == expected
    covered = np.zeros((height, width), dtype=int)
    for x0, y0, x1, y1 in prepared.tiles():
        covered[y0:y1, x0:x1] += 1
    assert (covered == 1).all()


def test_split_tiles_give_the_pixels_of_one_tile():
    scene = busy_scene(Velocity((0.0, 0.4, 0.0)))
    one = render_image(scene, settings(resolution=(24, 18), threads=1, tile_size=32))
    split = render_image(scene, settings(resolution=(24, 18), threads=4, tile_size=32))
    assert_same_passes(one, split)

"""Render a :class:`~.prepared.PreparedScene`: tiles of camera rays through every rest frame, in threads.

The observer is the camera's rest frame (S itself for a camera at rest).  Its
observation event is the camera's position at world time ``tau_obs``; every
primary ray starts there (orthographic rays start on the image plane, all at the
same camera-frame time; with depth of field each sample starts at its aperture
point, with motion blur at its own time of the camera's clock: see
docs/physics-camera.md).  The passes other than Combined are those of the
pixel-centre ray at the observation event.  Tiles are independent and every
random number is keyed by (pixel, sample), so any split into tiles, regions,
threads or machines gives the same image.  Memory is bounded by the tile size (and samples are batched).

Pass arrays are float32 ``(h, w, C)`` with row 0 at the bottom (Blender's order).
"""

from __future__ import annotations

import threading
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np

from . import blas, malloc, sampling
from .passes import (ALL_PASSES, DENOISING_PASSES, EXTRA_PASSES, PASSES, pixel_passes,  # noqa: F401 (PASSES: public)
                     ray_doppler)
from .prepared import PreparedScene, prepare
from .scene import RAY_CAMERA, RenderSettings, Scene, render_workers
from .tracer import RunBounds, TraceCache, no_hits
from .validation import DOPPLER_MODES, RenderError  # noqa: F401 (public names of this module)

# ray colour values per group of samples: bounds memory, and sets which samples of a pixel are summed together
_MAX_VALUES = 3 << 16
# colour values per batch: a group's pixels split further so that a batch's arrays stay in cache (32768 RGB rays)
_BATCH_VALUES = 3 << 15


@dataclass
class Tile:
    """The pass arrays of the pixels (x0, y0) .. (x1, y1) (exclusive) of the image."""

    x0: int
    y0: int
    x1: int
    y1: int
    passes: dict
    complete: bool = True  # False: stopped between sample batches (its Combined lacks samples)
    # another tile finished with this one is yielded right after it (worker processes: the tiles of
    # one wake-up), so a caller may report its progress once for them all, at the last
    more_ready: bool = False


class UnseenTiles:
    """The tiles of one render of a prepared scene that see nothing
    (:meth:`~.prepared.PreparedScene.misses_everything`), each found once (those dealt, all at once), and their pass arrays
    by :func:`_unseen_key`, rendered once: every such tile of a shape has the same ones.  Shared
    by the render's threads (a dict's get and set are atomic; two threads may find the same)."""

    def __init__(self, prepared: PreparedScene):
        self.prepared = prepared
        self._found: dict[tuple, bool] = {}
        self._passes: dict[tuple, dict] = {}

    def sees_nothing(self, rect, cache: TraceCache) -> bool:
        found = self._found.get(tuple(rect))
        if found is None:
            found = self.find([rect], cache)[0]
        return found

    def find(self, rects, cache: TraceCache) -> list[bool]:
        """Whether each tile of ``rects`` sees nothing, those not yet found all at once."""
        keys = [tuple(rect) for rect in rects]
        new = [key for key in dict.fromkeys(keys) if key not in self._found]
        if new:
            self._found.update(zip(new, self.prepared.each_misses_everything(new, cache)))
        return [self._found[key] for key in keys]

    def passes(self, key) -> dict | None:
        """The pass arrays (read-only) of the tiles of ``key`` that see nothing, once one is rendered."""
        kept = self._passes.get(key)
        return None if kept is None else dict(kept)

    def keep(self, key, passes: dict) -> None:
        for values in passes.values():
            values.flags.writeable = False  # shared by every tile of this shape that sees nothing
        self._passes[key] = passes

    def measured(self, prepared: PreparedScene) -> "UnseenTiles":
        """These tiles for ``prepared``, the same built scene with its pre-passes' values
        (:func:`~.prepared.measured_as`): what was found carries over (it depends on the frames
        and the camera alone), the kept passes do not (the exposure scales them)."""
        unseen = UnseenTiles(prepared)
        unseen._found = self._found
        return unseen


def warm_up(prepared: PreparedScene, cache: TraceCache) -> UnseenTiles:
    """Work out ahead what a render's first tile would: whether each of the scene's tiles sees
    nothing (all at once, with the cones of the frames seen from the camera's event, into
    ``cache``) and the body boxes seen from the camera's frame; the render's :class:`UnseenTiles`.
    A worker process does it as it builds the scene, so that its first share costs no more than
    the others (the 11x11 bars' 64-px tiles: ~1 ms more without, each worker once a render) and
    no share looks for its tile's emptiness again."""
    unseen = UnseenTiles(prepared)
    unseen.find(prepared.tiles(), cache)
    if prepared.frames.geometry:
        cache.boxes(prepared.frames, prepared.frames.camera, prepared.frames.geometry)
    return unseen


def _tile_runs(prepared: PreparedScene, tile_runs: dict, rect, part: slice, count: int = 1) -> RunBounds | None:
    """The :class:`~.tracer.RunBounds` of the pinhole rays through the pixels ``part`` of ``rect``,
    ``count`` consecutive ones a pixel (a divisor of ``RunBounds.RUN``), wherever in it, kept in
    ``tile_runs`` for the tile's later bundles of them.  One sample a pixel, a stretch of the runs
    of all the tile's pixels (the pixel-centre rays'), their culls included, once those are kept."""
    key = part.start, part.stop, count
    if key not in tile_runs:
        x0, y0, x1, y1 = rect
        whole = tile_runs.get((0, (x1 - x0) * (y1 - y0), 1))  # (the pixel-centre rays')
        if whole is not None and count == 1 and part.start % RunBounds.RUN == 0:
            tile_runs[key] = whole.stretch(part.start // RunBounds.RUN, (part.stop - part.start) // RunBounds.RUN)
        else:
            bounds = prepared.camera_rays.run_bounds(rect, part, RunBounds.RUN // count)
            tile_runs[key] = None if bounds is None else RunBounds(*bounds)
    return tile_runs[key]


def render_tile(prepared: PreparedScene, rect, should_stop: Callable[[], bool] = lambda: False,
                cache: TraceCache | None = None, rows: tuple[int, int] | None = None,
                unseen: UnseenTiles | None = None) -> Tile:
    """Render the pixels ``rect`` = (x0, y0, x1, y1) (x1, y1 exclusive) of a prepared scene.

    ``should_stop()`` is polled between sample batches of a long tile (the tile is then
    returned with ``complete`` False: never show it as finished); ``cache``: the calling thread's
    :class:`~.tracer.TraceCache` (None: one for this tile); ``rows`` = (y0, y1): only these rows
    of the tile (a share of it for another worker), in the whole tile's sample batches, so they
    are the same bits as in the whole tile; ``unseen``: the render's :class:`UnseenTiles` (None:
    this tile's own).  The pass arrays of a tile that sees nothing are read-only (shared).
    """
    cache = cache if cache is not None else TraceCache()
    settings, frames = prepared.settings, prepared.frames
    x0, y0, x1, y1 = rect
    tile_pixels, share = (x1 - x0) * (y1 - y0), None
    unseen_key = _unseen_key(rect, rows)
    if rows is not None:
        share = slice((rows[0] - y0) * (x1 - x0), (rows[1] - y0) * (x1 - x0))
        y0, y1 = rows
        rect = x0, y0, x1, y1
    h, w = y1 - y0, x1 - x0
    unseen = unseen if unseen is not None else UnseenTiles(prepared)
    empty = unseen.sees_nothing(rect, cache)  # then no ray of the tile is made or traced
    kept = unseen.passes(unseen_key) if empty else None
    if kept is not None:
        return Tile(x0, y0, x1, y1, kept)
    pixel = prepared.pixel_ids(rect)
    n = len(pixel)
    # the pixels' coordinates, their strata's starts and halves of the (pixel, sample) hash, for jittered samples
    xs = ys = starts = halves = None
    tile_runs = {}  # (first pixel, pixel past the last, rays a pixel) -> their rays' RunBounds (None: the camera has none)
    shader = prepared.shader
    if empty:
        centre, centre_hits = prepared.missing_rays(n), no_hits(n, read_only=True)
    else:
        centre = prepared.centre_rays(rect)  # (pinhole rays: the tile's run bounds hold them, as every sample's)
        centre_hits = shader.trace(frames.camera, *centre, RAY_CAMERA, pixel, np.broadcast_to(np.int64(0), (n,)), 0,
                                   cache, for_passes=True, runs=_tile_runs(prepared, tile_runs, rect, slice(0, n)))
    passes = pixel_passes(frames, prepared.scene.light_speed, prepared.passes, centre, centre_hits,
                          shader.shading_normals if prepared.materials.normal_mapped else None, cache)
    samples = max(int(settings.samples), 1)
    batches = list(_batches(tile_pixels, samples, prepared.colour.channels, share))
    # one batch of every pixel and sample: its colours are the sums (added to 0.0 below, as to the sums' zeros)
    rgb = None if len(batches) == 1 and batches[0][0] == slice(0, n) else np.zeros((n, 3))
    summed = rgb is not None
    # the share of samples that hit a surface (holdouts included): a transparent film's alpha
    coverage = np.zeros(n) if settings.film_transparent else None
    held = np.zeros(n) if shader.has_holdouts else None  # the share of samples that hit a holdout
    denoising = {name: np.zeros((n, 3)) for name in DENOISING_PASSES if name in prepared.passes}
    complete = True
    for index, (part, first, count) in enumerate(batches):
        if index and should_stop():  # Esc between sample batches of a long tile
            complete = False
            break
        m = part.stop - part.start
        pix = pixel[part] if count == 1 else np.repeat(pixel[part], count)  # (a view: nothing writes into it)
        smp = np.broadcast_to(np.int64(first), (m,)) if count == 1 else np.tile(np.arange(first, first + count), m)
        ids = sampling.Samples(pix, smp)
        observed = None  # the Doppler factor of the camera frame seen by each sample's observer (None: 1)
        if samples == 1 and not prepared.samples_vary:  # the one sample is the pixel-centre ray
            rays = tuple(a[part] for a in centre)
            # already traced, unless cut-outs pass it by chance (the passes' trace used a threshold)
            hits = (shader.trace(frames.camera, *rays, RAY_CAMERA, pix, smp, 0, cache)
                    if prepared.materials.cuts_out and not empty else centre_hits.take(part))
        elif empty:
            rays, hits = prepared.missing_rays(len(pix)), no_hits(len(pix), read_only=True)
        else:
            if xs is None:
                xs, ys, _ = prepared.pixel_grid(rect)
                starts = sampling.strata_starts(pixel, samples)  # (per pixel: once for all its batches)
                halves = None if samples == 1 else sampling.pixel_halves(pixel)
            keys = None if halves is None else sampling.block_keys(halves[part], first, count)
            ids = sampling.Samples(pix, smp, keys)  # (the jitter's hash kept for the samples' other numbers)
            px, py = sampling.stratified_positions(xs[part], ys[part], pixel[part], first, count, samples,
                                                   None if starts is None else starts[part], keys)
            rays, observed = prepared.sample_rays(px, py, keys=(pix, smp, samples))
            runs = None
            if RunBounds.RUN % count == 0 and not prepared.samples_vary:  # rays from one event: cull them once a tile
                runs = _tile_runs(prepared, tile_runs, rect, part, count)
            hits = shader.trace(frames.camera, *rays, RAY_CAMERA, pix, smp, 0, cache, runs=runs)
        color, hit, hole = _sample(prepared, rays, hits, ids, cache, observed)
        if summed:
            rgb[part] += _per_pixel(color, m, count)
        else:
            rgb = _per_pixel(color, m, count)
        if denoising:
            for name, values in prepared.shader.denoising_data(hits).items():
                if name in denoising:
                    denoising[name][part] += _per_pixel(values, m, count)
        if coverage is not None:
            coverage[part] += _per_pixel(hit, m, count)
        if hole is not None:
            held[part] += _per_pixel(hole, m, count)
    # holdouts are holes in the image whether or not the film is transparent (as in Cycles)
    alpha = coverage / samples if settings.film_transparent else 1.0
    if held is not None:
        alpha = alpha - held / samples
    combined = np.empty((n, 4), dtype=np.float32)  # rounded to float32 once, as every pass
    for axis in range(3):  # by column: a cast into a 2-d slice is 3x slower
        column = rgb[:, axis] if summed else np.add(rgb[:, axis], 0.0)  # (0.0 + x: a sum's bits, -0.0 too)
        np.multiply(column, prepared.exposure / samples, out=combined[:, axis])
    combined[:, 3] = alpha
    passes["Combined"] = combined
    for name, total in denoising.items():
        passes[name] = total / samples
    passes = {k: v.reshape(h, w, -1).astype(np.float32, copy=False) for k, v in passes.items()}
    if empty and complete:
        unseen.keep(unseen_key, passes)
        passes = dict(passes)
    return Tile(x0, y0, x1, y1, passes, complete)


def _unseen_key(rect, rows: tuple[int, int] | None) -> tuple[int, int, int, int]:
    """What the passes of a tile that sees nothing depend on: its shape and share of rows.  Its
    camera rays are then one ray repeated (:meth:`~.prepared.PreparedScene.missing_rays`) and
    its hits none, and nothing else the tile computes depends on where it is (a pixel's
    wavelengths and random numbers come in only where rays are made or hit a surface)."""
    x0, y0, x1, y1 = rect
    first, last = rows if rows is not None else (y0, y1)
    return x1 - x0, y1 - y0, first - y0, last - y0


def _per_pixel(values, m: int, count: int):
    """Sums of ``count`` consecutive samples' values for each of ``m`` pixels (one sample: the values as
    they are, which adding to a sum gives the same bits)."""
    if count == 1:
        return values
    return values.reshape(m, count, *values.shape[1:]).sum(axis=1)


def _sample(prepared: PreparedScene, rays, hits, ids: sampling.Samples, cache: TraceCache, observed=None):
    """Colour of camera samples ``ids`` (already traced: ``hits``), whether they hit anything and whether
    a holdout (None: the scene has none; a holdout's colour is 0); ``observed``: the Doppler factor
    of the camera frame as each sample's observer sees it (an accelerating camera's shutter
    samples), None for 1."""
    settings = prepared.settings
    if settings.doppler_mode == "FACTOR":
        hit = hits.frame >= 0
        doppler = ray_doppler(prepared.frames, hits)
        if observed is not None:
            doppler = doppler * observed
        rgb = np.repeat(_doppler_grey(prepared, doppler)[:, None], 3, axis=1)
    else:
        colour = prepared.colour
        pixel, sample = ids.pixel, ids.sample
        lam = colour.camera_wavelengths(pixel, sample)
        traced = lam if observed is None else colour.shift(lam, observed)  # the wavelengths in the camera frame
        if prepared.path_tracer is not None:
            values, hits = prepared.path_tracer.radiance(prepared.frames.camera, *rays, pixel, sample, traced, hits,
                                                         cache)
        else:
            values, hits = prepared.shader.radiance(prepared.frames.camera, *rays, 0, ids, traced, hits, cache)
        if observed is not None:
            values = values * prepared.shader.searchlight_power(observed, 4)[:, None]
        rgb = colour.to_rgb(values, lam)
        hit = hits.frame >= 0
    if settings.film_transparent:
        rgb[~hit] = 0.0
    elif settings.doppler_mode == "FACTOR":
        rgb[~hit] = prepared.scene.world_color
    if not prepared.shader.has_holdouts:
        return rgb, hit, None
    hole = prepared.shader.held_out(hits)
    rgb[hole] = 0.0
    return rgb, hit, hole


def _doppler_grey(prepared: PreparedScene, doppler):
    """The FACTOR display: D mapped linearly from the Doppler range to black .. white, continuous
    with 0 levels, else in that many (at least 2: ``validation.check_doppler_levels``)."""
    lo, hi = prepared.doppler_range
    t = np.clip((doppler - lo) / (hi - lo), 0.0, 1.0) if hi > lo else np.ones_like(doppler)
    levels = int(prepared.settings.doppler_levels)
    if levels:
        t = np.minimum(np.floor(t * levels), levels - 1) / (levels - 1)
    return t


def _batches(n: int, samples: int, channels: int, share: slice | None = None):
    """(pixels, first sample, sample count) of a tile's batches: at most ``_MAX_VALUES`` colour
    values each, whatever the tile size, samples and wavelengths (pixels split when one sample
    of the whole tile is already more), in batches of at most ``_BATCH_VALUES`` (a group of samples
    split by pixels: each pixel's samples are still summed in the groups ``_MAX_VALUES`` makes).
    ``share``: a range of the tile's ``n`` pixels; the batches are the whole tile's, cut to it and
    counted from its start (a pixel's samples are summed in the same groups, so its bits do not
    depend on how the tile is shared out)."""
    share = share or slice(0, n)
    part_size = n if n * channels <= _MAX_VALUES else max(_MAX_VALUES // channels, 1)
    for start in range(0, n, part_size):
        part = slice(start, min(start + part_size, n))
        per_batch = max(_MAX_VALUES // ((part.stop - part.start) * channels), 1)
        mine = slice(max(part.start, share.start) - share.start, min(part.stop, share.stop) - share.start)
        if mine.stop <= mine.start:
            continue
        for first in range(0, samples, per_batch):
            count = min(per_batch, samples - first)
            step = max(_BATCH_VALUES // (count * channels), 1)  # (pixels: the group's sums are the same bits)
            for lo in range(mine.start, mine.stop, step):
                yield slice(lo, min(lo + step, mine.stop)), first, count


def render_tiles(prepared: PreparedScene, should_stop: Callable[[], bool] = lambda: False,
                 threads: int | None = None, warn: Callable[[str], None] | None = None) -> Iterator[Tile]:
    """Yield the tiles of the prepared scene's region as they complete, rendered by ``threads``
    threads or worker processes (``settings.parallelism``; None: the settings' count; 0: one per
    core); return early once ``should_stop()`` is true (a tile cut short by it is never yielded).
    ``warn(message)`` hears why worker processes fell back to threads."""
    workers = render_workers(prepared.settings.threads if threads is None else threads)
    malloc.tune()  # for render threads in this process (worker processes have it from their start)
    with blas.single_threaded():  # the render threads use the cores (see blas)
        if prepared.settings.parallelism == "PROCESSES":
            from . import workers as processes  # (it imports this module)

            yield from processes.render_tiles(prepared, should_stop, workers, warn)
        else:
            yield from tiles_in_threads(prepared, prepared.tiles(), workers, should_stop)


def tiles_in_threads(prepared: PreparedScene, rects, workers: int, should_stop) -> Iterator[Tile]:
    """Yield the tiles ``rects`` of the prepared scene as ``workers`` threads complete them:
    with more than one thread, those that see something first, so that the short ones that see
    nothing even out the threads' ends (one thread: in their order, every tile's emptiness found
    at once first: 0.35 ms for the floor's 36 tiles, where one at a time took 2.6 ms)."""
    unseen = UnseenTiles(prepared)
    if workers == 1:
        cache, rects = TraceCache(), list(rects)
        unseen.find(rects, cache)
        for rect in rects:
            if should_stop():
                return
            tile = render_tile(prepared, rect, should_stop, cache, unseen=unseen)
            if not tile.complete:
                return
            yield tile
        return
    owned = threading.local()  # one trace cache per worker thread

    def work(rect):
        if not hasattr(owned, "cache"):
            owned.cache = TraceCache()
        return render_tile(prepared, rect, should_stop, owned.cache, unseen=unseen)

    pool = ThreadPoolExecutor(max_workers=workers)
    pending = set()
    queue = seen_first(unseen, rects, should_stop)
    try:
        while True:
            while len(pending) < 2 * workers and not should_stop():
                rect = next(queue, None)
                if rect is None:
                    break
                pending.add(pool.submit(work, rect))
            if not pending or should_stop():
                return
            done, pending = wait(pending, timeout=0.1, return_when=FIRST_COMPLETED)
            for future in done:
                tile = future.result()
                if tile.complete:
                    yield tile
    finally:
        # on Esc, return at once: tiles still running stop at their next sample batch
        pool.shutdown(wait=False, cancel_futures=True)


def seen_first(unseen: UnseenTiles, rects, should_stop: Callable[[], bool] = lambda: False) -> Iterator[tuple]:
    """The tiles ``rects`` that see something, then those that see nothing (in their order),
    all found at once when the first is asked for (on the calling thread, with a trace cache of
    its own: ~1 ms for a render's tiles, where one at a time took 0.1 ms a tile of the threads'
    GIL); none more once ``should_stop()`` is true."""
    rects = list(rects)
    empty = unseen.find(rects, TraceCache())
    later = [rect for rect, nothing in zip(rects, empty) if nothing]
    for rect in [rect for rect, nothing in zip(rects, empty) if not nothing] + later:
        if should_stop():
            return
        yield rect


def render_image(scene: Scene, settings: RenderSettings, should_stop: Callable[[], bool] = lambda: False,
                 progress: Callable[[int, int], None] | None = None) -> dict[str, np.ndarray]:
    """Prepare and render the whole image (or region) into full-size pass arrays, row 0 at the bottom."""
    prepared = prepare(scene, settings, should_stop)
    width, height = settings.resolution
    passes = {name: np.zeros((height, width, ALL_PASSES[name]), dtype=np.float32)
              for name in ("Combined", *prepared.passes)}
    total = len(prepared.tiles())
    for done, tile in enumerate(render_tiles(prepared, should_stop), start=1):
        for name, data in tile.passes.items():
            passes[name][tile.y0:tile.y1, tile.x0:tile.x1] = data
        if progress is not None:
            progress(done, total)
    return passes

"""Deterministic per-pixel random numbers and stratified sample positions.

Every number depends only on (pixel, sample, dimension), never on how the image
is split into tiles or threads, so region renders and full renders agree exactly.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from . import rows

_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


def _mix(z: np.ndarray) -> np.ndarray:
    """splitmix64's finaliser: a bijective, well-mixing hash of uint64 (in place: ``z`` is the
    caller's own scratch array, returned)."""
    shifted = z >> np.uint64(30)
    z ^= shifted
    z *= _M1
    np.right_shift(z, np.uint64(27), out=shifted)
    z ^= shifted
    z *= _M2
    np.right_shift(z, np.uint64(31), out=shifted)
    z ^= shifted
    return z


def pixel_halves(pixel: np.ndarray) -> np.ndarray:
    """The pixel's half of the (pixel, sample) hash's input (xor-ed with :func:`_sample_halves`),
    to keep across a tile's batches of samples (:func:`block_keys`)."""
    return np.multiply(_as_uint64(pixel), _GOLDEN)


def _sample_halves(sample: np.ndarray) -> np.ndarray:
    """The sample number's half of the (pixel, sample) hash's input."""
    half = np.add(_as_uint64(sample), np.uint64(1))
    half *= _M2
    return half


def _as_uint64(a: np.ndarray) -> np.ndarray:
    """``a.astype(np.uint64)`` for the arithmetic that follows: an int64 array viewed as uint64 (the
    same bits, negative numbers wrapped modulo 2^64 alike), with no pass of its own."""
    a = np.asarray(a)
    return a.view(np.uint64) if a.dtype == np.int64 else a.astype(np.uint64)


def _sample_keys(pixel: np.ndarray, sample: np.ndarray | None) -> np.ndarray:
    """The hash of (pixel, sample) that every dimension's numbers start from (sample None: 0)."""
    key = pixel_halves(pixel)
    key ^= _M2 if sample is None else _sample_halves(sample)  # None: (0 + 1) * _M2
    return _mix(key)


def block_keys(halves: np.ndarray, first: int, count: int) -> np.ndarray:
    """:func:`_sample_keys` of samples first .. first + count - 1 of each pixel (its
    :func:`pixel_halves`), pixel-major: each half of the hash's input worked out once (per pixel,
    per sample number), not once per sample."""
    key = np.bitwise_xor.outer(halves, _sample_halves(np.arange(first, first + count)))
    return _mix(key.ravel())


class Samples:
    """Samples by (pixel id, sample number), one pair per ray, and the (pixel, sample) hash that
    every dimension of their random numbers starts from: worked out once (or handed in by the
    camera jitter, which needs it first) and gathered with the rows, not hashed again by each
    user of the numbers (the lamps' samples).  A :meth:`take` gathers each array when it is
    first read: the shader takes its hits' samples for the lamps' numbers and the cut-outs, and
    without cut-outs reads their hash alone."""

    __slots__ = ("_pixel", "_sample", "_keys", "_source", "_index")

    def __init__(self, pixel: np.ndarray | None, sample: np.ndarray | None, keys: np.ndarray | None = None):
        self._pixel, self._sample, self._keys = pixel, sample, keys
        self._source = self._index = None  # (a take: the samples and rows it gathers from when read)

    @property
    def pixel(self) -> np.ndarray:
        if self._pixel is None:
            self._pixel = rows.take(self._source.pixel, self._index)
        return self._pixel

    @property
    def sample(self) -> np.ndarray:
        """(One sample number broadcast stays a broadcast, as rows.take keeps it: a batch of one
        sample per pixel.)"""
        if self._sample is None:
            self._sample = rows.take(self._source.sample, self._index)
        return self._sample

    @property
    def keys(self) -> np.ndarray:
        """:func:`_sample_keys` of each (pixel, sample) (read-only: shared with the rows taken)."""
        if self._known_keys() is None:
            self._keys = _sample_keys(self.pixel, self.sample)
        return self._keys

    def _known_keys(self) -> np.ndarray | None:
        """The hash where gathers of a known one give it (else None: hashing these rows is cheaper)."""
        if self._keys is None and self._source is not None:
            keys = self._source._known_keys()
            if keys is not None:
                self._keys = rows.take(keys, self._index)
        return self._keys

    def uniforms(self, dimensions) -> list[np.ndarray]:
        """:func:`uniforms` of these samples."""
        return [_from_keys(self.keys, dimension) for dimension in dimensions]

    def take(self, index) -> "Samples":
        """The samples at ``index`` (:func:`~.rows.take`: a slice gives views), gathered when read."""
        taken = Samples(None, None)
        taken._source, taken._index = self, index
        return taken


def _from_keys(keys: np.ndarray, dimension: int) -> np.ndarray:
    """The numbers of one dimension from :func:`_sample_keys`."""
    # (the offset modulo 2^64 in Python's integers: no overflow of numpy scalars to silence, 3 us a call)
    z = _mix(keys + np.uint64(dimension * int(_GOLDEN) % (1 << 64)))
    z >>= np.uint64(11)
    # (exact: z < 2^53 converts without rounding; as int64, the same bits, twice as fast as uint64)
    return np.multiply(z.view(np.int64), np.float64(1.0 / (1 << 53)))


def uniform(pixel: np.ndarray, sample: np.ndarray, dimension: int) -> np.ndarray:
    """Uniform numbers in [0, 1) keyed by pixel id, sample number and dimension."""
    return _from_keys(_sample_keys(pixel, sample), dimension)


def uniforms(pixel: np.ndarray, sample: np.ndarray, dimensions) -> list[np.ndarray]:
    """:func:`uniform` of several dimensions of the same samples (their common hash done once)."""
    return Samples(pixel, sample).uniforms(dimensions)


def stratified_offsets(pixel: np.ndarray, sample: np.ndarray, count: int):
    """Jittered sub-pixel positions in [0, 1)^2: sample k of ``count`` lands in its own stratum.

    The strata form a ceil(sqrt(count)) grid visited in a per-pixel order
    ``(k * step + start) mod cells`` (step coprime to the cell count, near the golden
    ratio for spread), so a partial grid (non-square count) is spread over the pixel and
    each sample costs O(1).  A single sample is the pixel centre.
    """
    if count == 1:
        half = np.full(len(pixel), 0.5)
        return half, half
    side = int(np.ceil(np.sqrt(count)))
    stratum = strata(pixel, sample, side * side, 0)
    return _jittered(_sample_keys(pixel, sample), (stratum % side).astype(np.float64),
                     (stratum // side).astype(np.float64), side)


def stratified_positions(xs: np.ndarray, ys: np.ndarray, pixel: np.ndarray, first: int, count: int,
                         samples: int, starts: np.ndarray | None = None, keys: np.ndarray | None = None):
    """Image positions of samples first .. first + count - 1 of ``samples`` per pixel (pixel ids
    ``pixel`` at integer coordinates xs, ys, as floats or integers), pixel-major: ``xs + x, ys + y`` of
    :func:`stratified_offsets`, the same bits, with the work per pixel and per sample number
    (the strata's start, each half of the hash) done once each, not once per sample.
    ``starts``: the pixels' :func:`strata_starts`, where the caller keeps them across its batches
    of samples (None: worked out here); ``keys``: the samples' :func:`block_keys`, where the caller
    keeps them for the samples' other random numbers (:class:`Samples`; None: worked out here)."""
    if samples == 1:
        return np.repeat(xs + 0.5, count), np.repeat(ys + 0.5, count)
    side = int(np.ceil(np.sqrt(samples)))
    strata_columns, strata_rows = _strata_table(samples, first, count)
    start = strata_starts(pixel, samples) if starts is None else starts
    # (start is in range: clip only skips the check)
    column, row = (np.take(table, start, axis=0, mode="clip").ravel() for table in (strata_columns, strata_rows))
    x, y = _jittered(block_keys(pixel_halves(pixel), first, count) if keys is None else keys, column, row, side)
    x.reshape(len(pixel), count)[...] += xs[:, None]
    y.reshape(len(pixel), count)[...] += ys[:, None]
    return x, y


@lru_cache(maxsize=256)
def _strata_table(samples: int, first: int, count: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`strata` of samples first .. first + count - 1 for every per-pixel start (cells x
    count; a pixel's strata are its start's row, gathered per pixel instead of worked out per
    sample), as the strata's columns and rows (floats), read-only: the same for every batch of
    these samples (one count: 1-D tables, whose gather is a plain 1-D take)."""
    side = int(np.ceil(np.sqrt(samples)))
    cells = side * side
    steps = np.arange(first, first + count) * _coprime_step(cells) % cells
    table = (np.arange(cells)[:, None] + steps) % cells
    if count == 1:
        table = table[:, 0]
    found = (table % side).astype(np.float64), (table // side).astype(np.float64)
    for part in found:
        part.flags.writeable = False
    return found


def strata_starts(pixel: np.ndarray, samples: int) -> np.ndarray | None:
    """Where each pixel's order of strata starts in :func:`stratified_positions` (None for one
    sample: the pixel centre), to keep across a tile's batches of samples."""
    if samples == 1:
        return None
    side = int(np.ceil(np.sqrt(samples)))
    return _strata_start(pixel, side * side, 0)


def _jittered(keys: np.ndarray, column: np.ndarray, row: np.ndarray, side: int):
    """Uniform positions (dimensions 1, 2 of ``keys``) in each sample's stratum (``column``, ``row``
    of a side x side grid, as floats)."""
    x, y = _from_keys(keys, 1), _from_keys(keys, 2)
    x += column
    y += row
    x /= side
    y /= side
    return x, y


def stratified_pair(pixel: np.ndarray, sample: np.ndarray, count: int, dimension: int):
    """Two numbers in [0, 1) per camera sample keyed by (pixel, sample), from dimensions
    ``dimension`` to ``dimension + 2``: sample k of a pixel's ``count`` in its own cell of a
    ceil(sqrt(count))-square grid, jittered inside it (a single sample: anywhere).  Each sample
    alone stays uniform (unbiased); a pixel's samples cover the square evenly (the lens
    aperture, the path tracer's light and scattering directions)."""
    side = int(np.ceil(np.sqrt(count)))
    cell = shuffled_strata(pixel, sample, side * side, dimension)
    jx, jy = uniforms(pixel, sample, (dimension + 1, dimension + 2))
    return (cell % side + jx) / side, (cell // side + jy) / side


def strata(pixel: np.ndarray, sample: np.ndarray, cells: int, dimension: int):
    """Which of ``cells`` strata sample k < ``cells`` of a pixel falls in: ``(k * step + start) mod
    cells``, the start per pixel (from ``dimension``), the step coprime to ``cells`` near the golden
    ratio times ``cells``, so that a pixel's first samples already spread over the strata."""
    return (sample.astype(np.int64) * _coprime_step(cells) + _strata_start(pixel, cells, dimension)) % cells


def _strata_start(pixel: np.ndarray, cells: int, dimension: int) -> np.ndarray:
    """The per-pixel start of :func:`strata`."""
    return (_from_keys(_sample_keys(pixel, None), dimension) * cells).astype(np.int64)


def shuffled_strata(pixel: np.ndarray, sample: np.ndarray, cells: int, dimension: int) -> np.ndarray:
    """Which of ``cells`` strata sample k < ``cells`` of a pixel falls in, under a random permutation
    of the strata of its own per (pixel, dimension): unlike :func:`strata`, the strata of two
    dimensions are unrelated, so stratifying several dimensions of one sample adds no correlation
    between them.

    The permutation: rounds of multiplication by an odd number, addition and xor-shift, each a
    bijection of the integers below the next power of two, keyed by a hash of (pixel, dimension);
    values that land beyond ``cells`` take more rounds ("cycle walking"), which keeps it a
    bijection of 0..cells-1 (on average under two rounds)."""
    bits = max(int(cells - 1).bit_length(), 1)
    mask = np.uint64((1 << bits) - 1)
    with np.errstate(over="ignore"):
        key = _mix(pixel.astype(np.uint64) * _GOLDEN + np.uint64(dimension) * _M1)
    odd_a = (key | np.uint64(1)) & mask
    odd_b = ((key >> np.uint64(21)) | np.uint64(1)) & mask
    offset = (key >> np.uint64(42)) & mask
    half, third = np.uint64(max(bits // 2, 1)), np.uint64(max(bits // 3, 1))
    index = sample.astype(np.uint64)
    todo = np.arange(len(index))
    while len(todo):
        i = index[todo]
        with np.errstate(over="ignore"):
            i = (i * odd_a[todo] + offset[todo]) & mask
            i ^= i >> half
            i = (i * odd_b[todo]) & mask
            i ^= i >> third
        index[todo] = i
        todo = todo[i >= np.uint64(cells)]
    return index.astype(np.int64)


def _coprime_step(cells: int) -> int:
    step = max(int(round(cells * 0.6180339887)), 1)
    while np.gcd(step, cells) != 1:
        step += 1
    return step

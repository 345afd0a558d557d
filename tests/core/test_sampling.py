"""The batched sample jitter of render_tile (sampling.stratified_positions) against the general one."""

import numpy as np
import pytest

from restframe_addon.core import sampling


@pytest.mark.parametrize("samples", [1, 2, 3, 5, 8, 9, 16, 17, 64])
@pytest.mark.parametrize("batch", ["whole", "split"])
def test_stratified_positions_are_the_pixel_corner_plus_stratified_offsets_bit_for_bit(samples, batch):
    """The per-pixel and per-sample-number shortcuts change no bit of any sample's position,
    whichever batch of a pixel's samples is asked for."""
    rng = np.random.default_rng(samples)
    xs, ys = rng.integers(0, 5000, 257), rng.integers(0, 3000, 257)
    pixel = ys * 5000 + xs
    first = 0 if batch == "whole" else samples // 3
    count = samples - first
    pix, smp = np.repeat(pixel, count), np.tile(np.arange(first, first + count), len(pixel))
    ox, oy = sampling.stratified_offsets(pix, smp, samples)
    px, py = sampling.stratified_positions(xs, ys, pixel, first, count, samples)
    assert np.array_equal(px, np.repeat(xs, count) + ox)
    assert np.array_equal(py, np.repeat(ys, count) + oy)
    # the strata's starts kept for a tile's pixels (render_tile's) and handed in for some of them
    part = slice(100, 200)
    starts = sampling.strata_starts(pixel, samples)
    kept = sampling.stratified_positions(xs[part], ys[part], pixel[part], first, count, samples,
                                         None if starts is None else starts[part])
    rows = slice(100 * count, 200 * count)
    assert np.array_equal(kept[0], px[rows]) and np.array_equal(kept[1], py[rows])


@pytest.mark.parametrize("side", [2, 3, 5])
def test_stratified_positions_put_a_square_counts_samples_one_in_each_stratum(side):
    samples = side * side
    xs, ys = np.arange(40) * 7, np.arange(40) * 3
    pixel = ys * 1000 + xs
    px, py = sampling.stratified_positions(xs, ys, pixel, 0, samples, samples)
    column = np.floor((px - np.repeat(xs, samples)) * side).astype(int)
    row = np.floor((py - np.repeat(ys, samples)) * side).astype(int)
    cells = (row * side + column).reshape(len(pixel), samples)
    assert np.array_equal(np.sort(cells, axis=1), np.tile(np.arange(samples), (len(pixel), 1)))
    assert len({tuple(c) for c in cells}) > 1  # the strata's order differs between pixels

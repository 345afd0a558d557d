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
    floats = sampling.stratified_positions(xs.astype(np.float64), ys.astype(np.float64), pixel, first, count, samples)
    assert np.array_equal(floats[0], px) and np.array_equal(floats[1], py)  # (render_tile's coordinates)
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


def test_samples_numbers_from_the_jitters_kept_hash_are_uniforms_bit_for_bit():
    """The (pixel, sample) hash worked out for a batch's jitter from the tile's kept pixel halves
    (render_tile's), handed to the jitter and carried by :class:`sampling.Samples` through gathers,
    gives every dimension's numbers bit for bit as hashing the pairs again."""
    rng = np.random.default_rng(7)
    xs, ys = rng.integers(0, 5000, 300), rng.integers(0, 3000, 300)
    pixel, samples, first, count = ys * 5000 + xs, 9, 3, 4
    pix, smp = np.repeat(pixel, count), np.tile(np.arange(first, first + count), len(pixel))
    halves = sampling.pixel_halves(pixel)
    part = slice(50, 250)
    keys = sampling.block_keys(halves[part], first, count)
    rows = slice(50 * count, 250 * count)
    ids = sampling.Samples(pix[rows], smp[rows], keys)
    assert np.array_equal(keys, sampling._sample_keys(pix[rows], smp[rows]))
    kept = sampling.stratified_positions(xs[part], ys[part], pixel[part], first, count, samples, keys=keys)
    fresh = sampling.stratified_positions(xs[part], ys[part], pixel[part], first, count, samples)
    assert all(np.array_equal(a, b) for a, b in zip(kept, fresh))
    index = rng.permutation(len(keys))[:333]
    for taken, (p, s) in [(ids, (pix[rows], smp[rows])), (ids.take(index), (pix[rows][index], smp[rows][index])),
                          (ids.take(slice(10, 90)), (pix[rows][10:90], smp[rows][10:90]))]:
        for got, want in zip(taken.uniforms((1000, 1001, 5)), sampling.uniforms(p, s, (1000, 1001, 5))):
            assert np.array_equal(got, want)
    taken = ids.take(index).take(slice(5, 50))  # a take of a take: gathered when read, the hash alone
    assert np.array_equal(taken.keys, keys[index][5:50]) and taken._pixel is None and taken._sample is None
    one = sampling.Samples(pix, np.broadcast_to(np.int64(3), pix.shape)).take(index)
    assert one.sample.strides == (0,) and np.array_equal(one.sample, np.full(len(index), 3))
    assert np.array_equal(one.keys, sampling._sample_keys(pix[index], np.full(len(index), 3)))


def test_a_jittered_render_hashes_each_samples_key_once(monkeypatch):
    """render_tile hands its jitter's (pixel, sample) hash to the shader, so a sun with an angle
    (the lamp's random numbers) seen directly and in a mirror (a bounce's) hashes no pair again:
    only the strata's per-pixel starts (sample None) are hashed."""
    import math

    from shapes import look_at_camera, quad, rotation_x

    from restframe_addon.core.render import render_image
    from restframe_addon.core.scene import Light, Material, Mesh, RenderSettings, Scene

    hashed = []
    original = sampling._sample_keys
    monkeypatch.setattr(sampling, "_sample_keys",
                        lambda pixel, sample: hashed.append(sample is None) or original(pixel, sample))
    sun = Light("sun", "SUN", (0, 0, 5.0), matrix=rotation_x(math.radians(30)), power=3.0, sun_angle=0.3)
    mirror = Material("mirror", base_color=(0.9, 0.9, 0.9), metallic=1.0, roughness=0.0)
    scene = Scene(camera=look_at_camera((0.0, -3.0, 2.0), (0, 0, 0), fov_half_tan=0.6),
                  meshes=[Mesh("floor", *quad((0, 0, 0), (1e3, 1e3)), material_indices=np.zeros(2, int)),
                          Mesh("mirror", *quad((0, 2.0, 1.0), (2.0, 2.0), normal_axis=1),
                               material_indices=np.ones(2, int))],
                  lights=[sun], materials=[Material("plastic", base_color=(0.6, 0.5, 0.4)), mirror])
    image = render_image(scene, RenderSettings(resolution=(12, 12), threads=1, samples=4))["Combined"]
    assert np.all(image[..., 0] > 0.0)
    assert hashed and all(hashed)

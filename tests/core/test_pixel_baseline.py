"""tools/pixel_baseline.py's comparison: bit for bit by default, the colour passes within
``--colour-rtol`` of each pixel's value when asked, every other pass bit for bit always."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

_TOOL = Path(__file__).parents[2] / "tools" / "pixel_baseline.py"
_SPEC = importlib.util.spec_from_file_location("pixel_baseline", _TOOL)
pixel_baseline = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(pixel_baseline)


def _image():
    combined = np.zeros((2, 2, 4), np.float32)
    combined[..., 0], combined[..., 3] = 2.0, 1.0  # a bright red channel, a black blue one
    return {"Combined": combined, "Depth": np.full((2, 2, 1), 3.0, np.float32)}


def test_identical_passes_compare_equal_at_any_tolerance():
    for rtol in (0.0, 1e-3):
        assert pixel_baseline.compare_passes(_image(), _image(), rtol) == ([], [])


def test_a_colour_change_passes_only_within_the_tolerance_of_the_pixels_largest_channel():
    changed = _image()
    changed["Combined"][0, 0, 2] = 2.0 * 1e-6  # the blue channel, 0 before: 1e-6 of the pixel's red
    assert pixel_baseline.colour_difference(changed["Combined"], _image()["Combined"]) == pytest.approx((2e-6, 1e-6))
    problems, within = pixel_baseline.compare_passes(changed, _image())  # default: bit for bit
    assert len(problems) == 1 and "Combined" in problems[0] and not within
    problems, within = pixel_baseline.compare_passes(changed, _image(), 2e-6)
    assert not problems and len(within) == 1 and "Combined" in within[0]
    assert pixel_baseline.compare_passes(changed, _image(), 5e-7)[0]  # beyond it: a problem again


def test_other_passes_and_black_pixels_stay_bit_for_bit_whatever_the_tolerance():
    depth = _image()
    depth["Depth"][1, 1, 0] = np.nextafter(np.float32(3.0), np.float32(4.0))
    assert pixel_baseline.compare_passes(depth, _image(), 1.0)[0]
    black = _image()
    black["Combined"][...] = 0.0
    lit = _image()
    lit["Combined"][...] = 0.0
    lit["Combined"][0, 1, 1] = 1e-30  # light where the reference is black: relative to nothing
    assert pixel_baseline.colour_difference(lit["Combined"], black["Combined"])[1] == np.inf
    assert pixel_baseline.compare_passes(lit, black, 1.0)[0]

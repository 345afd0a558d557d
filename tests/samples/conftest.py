"""Sample-scene tests: the committed sample_blends/*.blend rendered at low resolution through
Blender (bpy module) and the RESTFRAME engine, measured with sample_blends/samplemeasure.py."""

import sys
from pathlib import Path

import pytest

SAMPLES = Path(__file__).resolve().parents[2] / "sample_blends"
sys.path.insert(0, str(SAMPLES))


@pytest.fixture(scope="module")
def samples_addon():
    """The add-on registered (unless tests/blender's session fixture already did it), and
    unregistered after the module, so tests/blender can register it again in any test order."""
    import bpy

    import restframe_addon

    ours = not hasattr(bpy.types.Scene, "restframe")
    if ours:
        restframe_addon.register()
    yield
    if ours and hasattr(bpy.types.Scene, "restframe"):
        restframe_addon.unregister()


@pytest.fixture
def render(samples_addon, tmp_path):
    """render(stem, resolution, samples=1, **Scene.restframe overrides) -> (passes, camera info)."""
    import samplelib

    counter = iter(range(10 ** 6))

    def _render(stem, resolution, samples=1, **settings):
        blend = SAMPLES / f"{stem}.blend"
        assert blend.exists(), f"{blend} is missing: run the make_*.py scripts"
        return samplelib.render_blend(str(blend), tmp_path / f"{stem}-{next(counter)}.exr",
                                      resolution=resolution, samples=samples, **settings)

    return _render

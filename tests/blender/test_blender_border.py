"""The render border in pixels is exactly the region Blender itself renders (its rounding, not ours)."""

import bpy
import numpy as np
import pytest

from blender_helpers import add_camera, render_rgba
from restframe_addon.export.settings import border_region, full_resolution

RESOLUTIONS = (720, 1080, 1280, 1920, 2160, 3840)
EDGES = [k / 20 for k in range(21)]


class RegionRecorder(bpy.types.RenderEngine):
    """A render engine that only records the size of the result Blender hands it (its border)."""

    bl_idname = "RESTFRAME_TEST_REGION_RECORDER"
    bl_label = "Region recorder"
    seen: list = []

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)

    def render(self, depsgraph):
        result = self.begin_result(0, 0, 1 << 20, 1 << 20)  # clipped by Blender to the border
        RegionRecorder.seen.append((result.resolution_x, result.resolution_y))
        self.end_result(result)


@pytest.fixture
def recorder(scene):
    bpy.utils.register_class(RegionRecorder)
    add_camera(scene)
    scene.render.engine = RegionRecorder.bl_idname
    scene.render.use_border = True
    scene.render.use_crop_to_border = True
    yield scene
    scene.render.engine = 'RESTFRAME'
    bpy.utils.unregister_class(RegionRecorder)


def blender_size(scene):
    RegionRecorder.seen.clear()
    bpy.ops.render.render()
    (size,) = RegionRecorder.seen
    return size


@pytest.mark.parametrize("resolution", RESOLUTIONS)
def test_every_border_edge_matches_blender(recorder, resolution):
    """Each edge k/20 alone (the other edge of its axis at 0 or 1): Blender's result size gives it in
    pixels exactly, since size = max - min; the other axis is a thin strip to keep results small."""
    scene = recorder
    render = scene.render
    render.resolution_x = render.resolution_y = resolution
    ours, blenders = [], []
    for axis in "xy":
        other = "y" if axis == "x" else "x"
        setattr(render, f"border_min_{other}", 0.0)
        setattr(render, f"border_max_{other}", 0.05)
        for side, edge in [("max", e) for e in EDGES[1:]] + [("min", e) for e in EDGES[:-1]]:
            setattr(render, f"border_min_{axis}", edge if side == "min" else 0.0)
            setattr(render, f"border_max_{axis}", edge if side == "max" else 1.0)
            width, height = blender_size(scene)
            x0, y0, x1, y1 = border_region(scene, full_resolution(scene))
            blenders.append((axis, side, edge, width, height))
            ours.append((axis, side, edge, x1 - x0, y1 - y0))
    assert ours == blenders


def test_one_pixel_border_matches_blender(recorder):
    scene = recorder
    render = scene.render
    render.resolution_x, render.resolution_y = 1920, 1080
    for start in (0.1, 0.5, 0.7, 0.9):
        render.border_min_x, render.border_max_x = start, start + 1.0 / 1920
        render.border_min_y, render.border_max_y = start, start + 1.0 / 1080
        width, height = blender_size(scene)
        x0, y0, x1, y1 = border_region(scene, full_resolution(scene))
        assert (x1 - x0, y1 - y0) == (width, height) == (1, 1), start


def test_border_ending_at_0_7_and_0_9_is_filled_to_its_last_pixel(scene, tmp_path):
    """At 1920x1080 a border ending at 0.7 (x) and 0.9 (y) is 1344 and 972 pixels in Blender; a
    region one pixel short would leave the last column and top row of the cropped image black."""
    add_camera(scene)
    scene.world = bpy.data.worlds.new("Grey")  # a uniform, non-black background
    render = scene.render
    render.resolution_x, render.resolution_y = 1920, 1080
    render.use_border, render.use_crop_to_border = True, True
    render.border_min_x, render.border_max_x = 0.68, 0.7
    render.border_min_y, render.border_max_y = 0.87, 0.9
    rgba = render_rgba(scene, tmp_path / "border.exr")
    assert rgba.shape[:2] == (int(np.float32(0.9) * np.float32(1080)) - int(np.float32(0.87) * np.float32(1080)),
                              int(np.float32(0.7) * np.float32(1920)) - int(np.float32(0.68) * np.float32(1920)))
    assert rgba[0, 0, :3].min() > 0.0
    np.testing.assert_allclose(rgba[..., :3], np.broadcast_to(rgba[0, 0, :3], rgba[..., :3].shape), rtol=1e-6)

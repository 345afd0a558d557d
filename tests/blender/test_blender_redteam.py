"""A red team of the render engine from the user's side: odd input gets one clear message naming
the object, the file is unchanged and nothing incomplete is written."""

import math

import bpy
import numpy as np
import pytest

from blender_helpers import add_camera, add_plane, add_sun, principled, render_exr


@pytest.mark.parametrize("spoil, message", [
    (lambda: setattr(bpy.data.lights["Sun"], "energy", math.nan), "Sun: its power .* is not a finite number"),
    (lambda: setattr(bpy.data.lights["Sun"], "color", (1.0, math.nan, 1.0)), "Sun: its color"),
    (lambda: setattr(bpy.data.objects["Sun"], "rotation_euler", (math.nan, 0.0, 0.0)), "Sun: its world transform"),
    (lambda: setattr(bpy.data.objects["Camera"], "location", (0.0, math.nan, 10.0)), "Camera: its world transform"),
    (lambda: setattr(bpy.data.objects["Camera"], "scale", (0.0, 0.0, 0.0)), "Camera: its world transform"),
    (lambda: setattr(bpy.data.cameras["Camera"], "lens", math.nan), "Camera: its view frame"),
    (lambda: bpy.data.objects["Plane"].data.materials.append(principled("Paint", Roughness=math.nan)),
     "material Paint: its roughness"),
])
def test_a_nan_setting_stops_the_render_naming_the_object_and_writes_nothing(scene, tmp_path, spoil, message):
    add_camera(scene)
    add_plane(scene)
    add_sun(scene)
    spoil()
    path = tmp_path / "spoilt.exr"
    with pytest.raises(RuntimeError, match=message):
        render_exr(scene, path)
    assert not path.exists()

"""F12-equivalent renders through bpy.ops.render.render, read back from multilayer EXR."""

import math

import bpy
import numpy as np
import pytest

from blender_helpers import add_camera, add_plane, add_sun, read_exr, render_exr
from restframe_addon.engine import OBJECT_INDEX_PASS

AXIS = (7, 10)  # (row, column) of the pixel whose centre lies on the optical axis of a 21x15 image


def gamma(b):
    return 1.0 / math.sqrt((1.0 - b) * (1.0 + b))


def test_doppler_on_axis_of_approaching_plane(scene, tmp_path):
    """Looking straight at a plane approaching at 0.9c: D = gamma (1 + beta)."""
    add_camera(scene)
    plane = add_plane(scene, velocity=(0.0, 0.0, 0.9))
    plane.pass_index = 7
    add_sun(scene)
    layer = scene.view_layers[0]
    layer.use_pass_z = layer.use_pass_normal = layer.use_pass_object_index = True
    passes = render_exr(scene, tmp_path / "axis.exr")

    assert {"Combined", "Depth", "Normal", OBJECT_INDEX_PASS, "Doppler", "Emission Time", "Object Time"} <= set(passes)
    assert passes["Doppler"].shape == (15, 21, 1)
    assert passes["Doppler"][AXIS][0] == pytest.approx(math.sqrt((1 + 0.9) / (1 - 0.9)), abs=1e-6)
    # Light reaching the camera (z = 10) at t = 0 left the plane when it was at z = -90:
    # path length s = 100, emitted 100 / c = 10 s before the reference time.
    assert passes["Depth"][AXIS][0] == pytest.approx(100.0, rel=1e-6)
    assert passes["Emission Time"][AXIS][0] == pytest.approx(-10.0, rel=1e-6)
    # the plane's own clock at that event (proper time since it passed its origin event): -100 / gamma
    assert passes["Object Time"][AXIS][0] == pytest.approx(-100.0 / gamma(0.9) / 10.0, rel=1e-6)
    assert passes["Normal"][AXIS] == pytest.approx([0.0, 0.0, 1.0], abs=1e-6)
    assert passes[OBJECT_INDEX_PASS][AXIS][0] == 7
    assert passes["Combined"].shape == (15, 21, 4)
    assert np.all(passes["Combined"][..., 3] == 1.0)
    # the plane (4 units wide, seen 100 units away) covers a few pixels around the axis only
    hit = passes["Doppler"][..., 0] > 0
    assert hit[AXIS] and not hit[0, 0] and 0 < hit.sum() < hit.size / 4


def test_doppler_perpendicular_motion_is_one_over_gamma(scene, tmp_path):
    """A wide plane sliding across the view at 0.8c: on the axis ray D = 1/gamma = 0.6."""
    add_camera(scene)
    add_plane(scene, size=1000.0, velocity=(0.8, 0.0, 0.0))
    passes = render_exr(scene, tmp_path / "side.exr")
    assert passes["Doppler"][AXIS][0] == pytest.approx(0.6, abs=1e-6)
    # receding on the +x side of the image, approaching on the -x side
    row = passes["Doppler"][AXIS[0], :, 0]
    assert row[0] > 0.6 > row[-1]


def test_frame_clock_moves_the_observation_time(scene, tmp_path):
    """Frame 11 at 24 fps is t = 10/24 s after the reference frame 1 (docs/physics.md#units-and-clocks)."""
    add_camera(scene)
    add_plane(scene, velocity=(0.0, 0.0, 0.9))
    scene.render.fps, scene.render.fps_base = 24, 1.0
    scene.restframe.reference_frame = 1
    scene.frame_set(11)
    scene.view_layers[0].use_pass_z = True
    passes = render_exr(scene, tmp_path / "f11.exr")
    tau_obs = scene.restframe.light_speed * 10.0 / 24.0
    # plane at z = 0.9 tau; the camera at z = 10 receives at tau_obs light sent at tau_e:
    # 10 - 0.9 tau_e = tau_obs - tau_e
    tau_e = (tau_obs - 10.0) / 0.1
    assert passes["Emission Time"][AXIS][0] == pytest.approx(tau_e / scene.restframe.light_speed, rel=1e-6)
    assert passes["Depth"][AXIS][0] == pytest.approx(tau_obs - tau_e, rel=1e-6)


def test_border_render_fills_only_the_region_with_identical_values(scene, tmp_path):
    add_camera(scene)
    add_plane(scene, size=30.0, velocity=(0.3, 0.2, 0.5))
    full = render_exr(scene, tmp_path / "full.exr")["Doppler"]
    scene.render.use_border = True
    scene.render.border_min_x, scene.render.border_max_x = 0.2, 0.7
    scene.render.border_min_y, scene.render.border_max_y = 0.3, 0.9
    part = render_exr(scene, tmp_path / "part.exr")["Doppler"]
    x0, x1, y0, y1 = int(0.2 * 21), int(0.7 * 21), int(0.3 * 15), int(0.9 * 15)
    inside = np.zeros(part.shape[:2], dtype=bool)
    inside[y0:y1, x0:x1] = True
    assert np.count_nonzero(full[inside]) == inside.sum()
    np.testing.assert_array_equal(part[inside], full[inside])
    assert not part[~inside].any()


def test_render_result_keeps_user_data_unchanged(scene, tmp_path):
    add_camera(scene)
    plane = add_plane(scene, velocity=(0.0, 0.0, 0.5))
    before = (len(bpy.data.meshes), len(bpy.data.objects), len(bpy.data.materials), tuple(plane.location),
              len(plane.data.vertices))
    render_exr(scene, tmp_path / "x.exr")
    after = (len(bpy.data.meshes), len(bpy.data.objects), len(bpy.data.materials), tuple(plane.location),
             len(plane.data.vertices))
    assert before == after


def test_doppler_factor_display(scene, tmp_path):
    """FACTOR mode paints D as grey between the chosen black and white levels."""
    add_camera(scene)
    add_plane(scene, size=1000.0, velocity=(0.8, 0.0, 0.0))
    rf = scene.restframe
    rf.doppler_mode = 'FACTOR'
    rf.doppler_range_auto = False
    rf.doppler_range = (0.0, 1.2)
    passes = render_exr(scene, tmp_path / "factor.exr")
    grey = passes["Combined"][AXIS][:3]
    assert grey == pytest.approx([0.5, 0.5, 0.5], abs=1e-6)  # D = 0.6 half way from 0 to 1.2


def test_read_exr_round_trip(tmp_path):
    """The reader used by these tests returns rows bottom-up like Blender."""
    import OpenEXR

    data = np.arange(12, dtype=np.float32).reshape(3, 4)
    header = {"type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, {"ViewLayer.Doppler.X": data}) as exr:
        exr.write(str(tmp_path / "t.exr"))
    back = read_exr(tmp_path / "t.exr")["Doppler"][..., 0]
    np.testing.assert_array_equal(back, data[::-1])


def emissive_plane(scene, velocity):
    plane = add_plane(scene, size=1000.0, velocity=velocity)
    mat = bpy.data.materials.new("Glow")
    if bpy.app.version < (5, 0, 0):
        mat.use_nodes = True
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    bsdf.inputs["Emission Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    bsdf.inputs["Emission Strength"].default_value = 1.0
    plane.data.materials.append(mat)
    return plane


def test_spectral_mode_blue_shifts_an_approaching_white_emitter(scene, tmp_path):
    add_camera(scene)
    emissive_plane(scene, velocity=(0.0, 0.0, 0.3))
    scene.restframe.searchlight = False
    scene.restframe.doppler_mode = 'OFF'
    off = render_exr(scene, tmp_path / "off.exr")["Combined"][AXIS][:3]
    assert off == pytest.approx([1.0, 1.0, 1.0], rel=1e-4)  # colour unshifted
    scene.restframe.doppler_mode = 'SPECTRAL'
    scene.restframe.spectral_samples = 16
    shifted = render_exr(scene, tmp_path / "spectral.exr")["Combined"][AXIS][:3]
    assert shifted[2] > 1.2 * shifted[0]  # D = 1.36: bluer than white


def test_animation_render_writes_every_frame(scene, tmp_path):
    """Ctrl+F12 / blender -a: each frame rendered at its own time and written."""
    add_camera(scene)
    add_plane(scene, velocity=(0.0, 0.0, 0.5))
    scene.frame_start, scene.frame_end = 3, 4
    scene.render.image_settings.file_format = 'PNG'
    scene.render.filepath = str(tmp_path / "anim_")
    bpy.ops.render.render(animation=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["anim_0003.png", "anim_0004.png"]

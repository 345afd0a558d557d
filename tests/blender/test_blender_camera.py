"""Camera rays match Blender's own: at beta = 0 an object's outline equals Cycles' alpha."""

import math

import bpy
import numpy as np
import pytest

from blender_helpers import add_camera, render_rgba


def outline(scene, tmp_path, engine):
    scene.render.engine = engine
    scene.render.film_transparent = True
    if engine == 'CYCLES':
        scene.cycles.device = 'CPU'
        scene.cycles.samples = 16
        scene.cycles.use_denoising = False
        scene.cycles.filter_width = 0.01  # (almost) box coverage, like RESTframe's stratified samples
        scene.cycles.max_bounces = 0
    else:
        scene.restframe.samples = 16
    alpha = render_rgba(scene, tmp_path / f"{engine}.exr")[..., 3]
    return alpha > 0.5


def monkey_scene(scene):
    bpy.ops.mesh.primitive_monkey_add(size=2.0, location=(0.6, 0.3, 0.0), rotation=(0.3, 0.2, 0.4))
    bpy.ops.mesh.primitive_cube_add(size=0.8, location=(-1.6, -0.9, 0.5))


CAMERAS = {
    "perspective, shift": dict(res=(48, 32), data=dict(lens=40.0, shift_x=0.12, shift_y=-0.07)),
    "perspective, vertical fit, portrait, pixel aspect": dict(
        res=(30, 44), pixel_aspect=(1.0, 1.25), data=dict(lens=30.0, sensor_fit='VERTICAL', sensor_height=20.0)),
    "orthographic, shift": dict(res=(40, 30), data=dict(type='ORTHO', ortho_scale=5.0, shift_x=-0.1)),
    "equirectangular": dict(res=(64, 32), distance=3.0, data=dict(
        type='PANO', panorama_type='EQUIRECTANGULAR', latitude_min=-0.6, latitude_max=0.6,
        longitude_min=-1.2, longitude_max=1.2)),
    "fisheye equidistant": dict(res=(40, 40), distance=2.5, data=dict(
        type='PANO', panorama_type='FISHEYE_EQUIDISTANT', fisheye_fov=math.radians(120))),
    "fisheye equisolid": dict(res=(48, 32), distance=2.0, data=dict(
        type='PANO', panorama_type='FISHEYE_EQUISOLID', fisheye_lens=8.0, fisheye_fov=math.radians(170))),
}


@pytest.mark.parametrize("name", list(CAMERAS))
def test_outline_matches_cycles_at_rest(scene, tmp_path, name):
    config = CAMERAS[name]
    scene.render.resolution_x, scene.render.resolution_y = config["res"]
    scene.render.pixel_aspect_x, scene.render.pixel_aspect_y = config.get("pixel_aspect", (1.0, 1.0))
    distance = config.get("distance", 7.0)
    add_camera(scene, location=(0.3, -distance, 1.2), rotation=(math.radians(84), 0.0, math.radians(3)),
               **config["data"])
    # Cycles renders the area outside a fisheye's image circle opaque black: leave it out
    outside = (outline(scene, tmp_path, 'CYCLES') if config["data"].get("type") == 'PANO'
               else np.zeros(config["res"][::-1], dtype=bool))
    monkey_scene(scene)
    ours = outline(scene, tmp_path, 'RESTFRAME')
    cycles = outline(scene, tmp_path, 'CYCLES')
    compared = ~outside
    assert not ours[~compared].any()
    assert cycles[compared].sum() > 0.03 * cycles.size, "the objects must fill a fair part of the image"
    differ = np.count_nonzero(ours[compared] != cycles[compared])
    assert differ <= 0.01 * cycles.size, f"{differ} of {cycles.size} pixels differ"

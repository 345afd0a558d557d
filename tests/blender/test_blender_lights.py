"""Light node trees as Cycles reads them: the Emission node's colour and strength multiply the lamp's."""

import bpy
import numpy as np
import pytest

from blender_helpers import add_camera, add_plane, export_now, render_direct_light

SAMPLES = 16


def lit_plane(scene):
    """A white diffuse plane under a point lamp (no soft radius: no sampling noise), seen from above."""
    plane = add_plane(scene, "Floor", size=4.0)
    mat = bpy.data.materials.new("White")
    if bpy.app.version < (5, 0, 0):
        mat.use_nodes = True
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (0.8, 0.8, 0.8, 1.0)
    bsdf.inputs["Roughness"].default_value = 1.0
    bsdf.inputs["Specular IOR Level"].default_value = 0.0
    plane.data.materials.append(mat)
    lamp = bpy.data.lights.new("Lamp", 'POINT')
    lamp.energy, lamp.shadow_soft_size = 200.0, 0.0
    lamp.color = (1.0, 0.9, 0.8)
    obj = bpy.data.objects.new("Lamp", lamp)
    obj.location = (0.3, -0.2, 2.0)
    scene.collection.objects.link(obj)
    scene.world = None
    add_camera(scene, location=(0.0, 0.0, 5.0), type='ORTHO', ortho_scale=4.0)
    scene.render.resolution_x = scene.render.resolution_y = 24
    return lamp


def emission_tree(lamp, color, strength, connected=True):
    lamp.use_nodes = True
    nodes = lamp.node_tree.nodes
    emission = next(n for n in nodes if n.type == 'EMISSION')
    emission.inputs["Color"].default_value = (*color, 1.0)
    emission.inputs["Strength"].default_value = strength
    if not connected:
        for link in list(lamp.node_tree.links):
            lamp.node_tree.links.remove(link)


def render(scene, tmp_path, engine, name):
    return render_direct_light(scene, tmp_path / f"{name}-{engine}.exr", engine, SAMPLES)


@pytest.mark.parametrize("color, strength, connected", [
    ((1.0, 0.6, 0.3), 2.5, True),
    ((1.0, 1.0, 1.0), 0.4, True),
    ((1.0, 1.0, 1.0), 1.0, False),  # nothing feeds the Light Output: the lamp is dark
])
def test_light_node_tree_matches_cycles(scene, tmp_path, color, strength, connected):
    lamp = lit_plane(scene)
    plain = {engine: render(scene, tmp_path, engine, "plain") for engine in ('CYCLES', 'RESTFRAME')}
    emission_tree(lamp, color, strength, connected)
    noded = {engine: render(scene, tmp_path, engine, "noded") for engine in ('CYCLES', 'RESTFRAME')}
    expected = np.asarray(color) * strength if connected else np.zeros(3)
    # Cycles itself multiplies: the noded image is the plain one times colour x strength
    np.testing.assert_allclose(noded['CYCLES'].mean(axis=(0, 1)), plain['CYCLES'].mean(axis=(0, 1)) * expected,
                               rtol=0.01, atol=1e-6)
    np.testing.assert_allclose(noded['RESTFRAME'], noded['CYCLES'], rtol=0.02, atol=1e-4)
    out, _, _ = export_now(scene)
    (light,) = out.lights
    assert light.power == pytest.approx(200.0 * (strength if connected else 0.0))

"""Each supported surface shader on a lit plane at rest renders as Cycles renders it.

The plane fills the view of a camera overhead, lit by a sun or a point lamp (both without size,
so neither renderer samples the light) and nothing else (no world, Cycles with direct light only
and box pixels): the mean of the image is the plane's mean radiance.  Cycles' own noise is then
tiny: two seeds at 64 samples differ by at most 3e-6 of the mean, and RESTframe's 16 stratified
samples and Cycles' 64 jittered ones average the lamp's falloff and the metal's highlight over the
pixels to within 2.2e-4 (measured).  The tolerance, 1e-3 of the mean, is well below what a stray
specular layer adds (a Diffuse BSDF: 1.7-2.6% brighter, an Emission of strength 0: 0.05-0.09
against Cycles' exact 0).

Not compared here, because RESTframe's model differs from Cycles' on purpose or by a known gap
(not an export question): a dielectric Principled BSDF with a specular layer (Cycles dims the
diffuse layer under it by the layer's albedo, about 3.5% brighter here) and Cycles' multiscatter
GGX (the metal uses the single-scatter GGX distribution, as RESTframe does).
"""

import math

import bpy
import numpy as np
import pytest

from blender_helpers import add_camera, add_plane, principled, render_rgba

COLOR = (0.6, 0.5, 0.4, 1.0)
GLOW = (0.5, 0.8, 1.0, 1.0)


def ggx_principled(**inputs):
    """A material maker: Principled BSDF on GGX microfacets, base colour COLOR, roughness 0.5."""
    def make():
        mat = principled("Surface", COLOR[:3], roughness=0.5, **inputs)
        mat.node_tree.nodes["Principled BSDF"].distribution = 'GGX'
        return mat
    return make


def only(shader):
    """A material maker: nothing but the node ``shader(nodes)`` makes on the Surface (None: nothing)."""
    def make():
        mat = bpy.data.materials.new("Surface")
        if bpy.app.version < (5, 0, 0):
            mat.use_nodes = True
        nodes = mat.node_tree.nodes
        output = nodes["Material Output"]
        for node in list(nodes):
            if node != output:
                nodes.remove(node)
        if shader is not None:
            mat.node_tree.links.new(shader(nodes).outputs[0], output.inputs["Surface"])
        return mat
    return make


def diffuse(nodes):
    node = nodes.new("ShaderNodeBsdfDiffuse")
    node.inputs["Color"].default_value = COLOR
    return node


def emission(strength):
    def make(nodes):
        node = nodes.new("ShaderNodeEmission")
        node.inputs["Color"].default_value = GLOW
        node.inputs["Strength"].default_value = strength
        return node
    return make


SHADERS = {
    "Principled, no specular": ggx_principled(Specular_IOR_Level=0.0),
    "Principled metal": ggx_principled(Metallic=1.0),
    "Principled, no specular, emitting": ggx_principled(Specular_IOR_Level=0.0, Emission_Color=GLOW,
                                                        Emission_Strength=2.0),
    "Diffuse": only(diffuse),
    "Emission, strength 0": only(emission(0.0)),
    "Emission, strength 2": only(emission(2.0)),
    "nothing on Surface": only(None),
}


def lit_plane(scene, shader, lamp):
    scene.render.resolution_x = scene.render.resolution_y = 32
    scene.world = None
    add_camera(scene, location=(0.0, 0.0, 6.0))
    plane = add_plane(scene, "Plane", size=20.0)  # fills the view
    plane.data.materials.append(SHADERS[shader]())
    if lamp == 'SUN':
        light = bpy.data.lights.new("Sun", 'SUN')
        light.energy, light.angle = 3.0, 0.0
        obj = bpy.data.objects.new("Sun", light)
        obj.rotation_euler = (math.radians(10), 0.0, 0.0)  # its highlight in view
    else:
        light = bpy.data.lights.new("Lamp", 'POINT')
        light.energy, light.shadow_soft_size = 1000.0, 0.0
        obj = bpy.data.objects.new("Lamp", light)
        obj.location = (1.0, 0.5, 4.0)
    scene.collection.objects.link(obj)


def mean_radiance(scene, tmp_path, engine) -> np.ndarray:
    scene.render.engine = engine
    if engine == 'CYCLES':
        cycles = scene.cycles
        cycles.device = 'CPU'
        cycles.samples = 64
        cycles.use_adaptive_sampling = False
        cycles.use_denoising = False
        cycles.max_bounces = 0  # direct light only, as RESTframe's opaque surfaces
        cycles.filter_width = 0.01  # (almost) box pixels, like RESTframe's stratified samples
    else:
        scene.restframe.samples = 16
    return render_rgba(scene, tmp_path / f"{engine}.exr")[..., :3].reshape(-1, 3).mean(axis=0)


@pytest.mark.parametrize("lamp", ['SUN', 'POINT'])
@pytest.mark.parametrize("shader", list(SHADERS))
def test_shader_on_a_lit_plane_renders_as_in_cycles(scene, tmp_path, shader, lamp):
    lit_plane(scene, shader, lamp)
    ours = mean_radiance(scene, tmp_path, 'RESTFRAME')
    cycles = mean_radiance(scene, tmp_path, 'CYCLES')
    if shader in {"Emission, strength 0", "nothing on Surface"}:
        assert np.all(cycles == 0.0)
    else:
        assert np.all(cycles > 0.1)  # lit (or glowing): a real comparison
    np.testing.assert_allclose(ours, cycles, rtol=1e-3, atol=1e-6)

"""Blender features RESTframe does not render yet: one warning per feature, naming the objects."""

import bpy

from blender_helpers import add_camera, add_plane, export_now
from restframe_addon.export import features


def node_material(name):
    mat = bpy.data.materials.new(name)
    if bpy.app.version < (5, 0, 0):
        mat.use_nodes = True
    return mat


def with_material(obj, mat):
    obj.data.materials.append(mat)
    return obj


def unsupported_scene(scene):
    """One object per feature, named after it, and one plain object."""
    add_camera(scene)
    add_plane(scene, "Plain")
    add_plane(scene, "Catcher").is_shadow_catcher = True

    bumpy = node_material("Bumpy")
    bump = bumpy.node_tree.nodes.new("ShaderNodeBump")
    bumpy.node_tree.links.new(bump.outputs["Normal"], bumpy.node_tree.nodes["Principled BSDF"].inputs["Normal"])
    with_material(add_plane(scene, "Bumped"), bumpy)
    mapped = node_material("Mapped")  # a tangent-space Normal Map is rendered: no warning
    normal_map = mapped.node_tree.nodes.new("ShaderNodeNormalMap")
    mapped.node_tree.links.new(normal_map.outputs["Normal"], mapped.node_tree.nodes["Principled BSDF"].inputs["Normal"])
    with_material(add_plane(scene, "NormalMapped"), mapped)
    fog = node_material("Fog")
    nodes = fog.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    fog.node_tree.links.new(nodes.new("ShaderNodeVolumePrincipled").outputs[0],
                            nodes["Material Output"].inputs["Volume"])
    with_material(add_plane(scene, "VolumeOnly"), fog)
    volume = bpy.data.objects.new("VolumeObject", bpy.data.volumes.new("Cloud"))
    scene.collection.objects.link(volume)

    furry = add_plane(scene, "ParticleHair")
    furry.modifiers.new("Hair", 'PARTICLE_SYSTEM')
    furry.particle_systems[0].settings.type = 'HAIR'
    curves = bpy.data.objects.new("CurvesHair", bpy.data.hair_curves.new("Strands"))
    scene.collection.objects.link(curves)
    for i in range(3):  # many users of one feature: still one warning
        with_material(add_plane(scene, f"Bumped{i}", location=(i, 9, 0)), bumpy)


EXPECTED = {
    "shadow catcher": ["Catcher"],
    "bump map": ["Bumped", "Bumped0", "Bumped1", "Bumped2"],
    "volume": ["VolumeOnly", "VolumeObject"],
    "hair": ["ParticleHair", "CurvesHair"],
}


def test_each_unsupported_feature_is_warned_once_naming_its_objects(scene):
    unsupported_scene(scene)
    _, _, warnings = export_now(scene)
    for feature, names in EXPECTED.items():
        said = [w for w in warnings if features.UNSUPPORTED[feature] in w]
        assert len(said) == 1, (feature, warnings)
        listed = said[0][:-len(features.UNSUPPORTED[feature]) - 2].split(", ")
        assert sorted(listed) == sorted(names), (feature, said[0])
    assert not any("Plain" in w for w in warnings)
    assert len(warnings) == len(EXPECTED)


def test_the_detection_is_one_question_per_feature(scene):
    """What a later implementation asks: each object uses exactly its own feature."""
    unsupported_scene(scene)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    seen = {}
    for inst in depsgraph.object_instances:
        if not inst.is_instance:
            seen[inst.object.name] = features.object_features(inst.object)
    for feature, names in EXPECTED.items():
        for name in names:
            if name in seen:
                assert seen[name] == [feature], (name, seen[name])
    assert seen["Plain"] == [] and seen["NormalMapped"] == []

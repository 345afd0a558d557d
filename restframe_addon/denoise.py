"""Blender's own denoiser (OpenImageDenoise, the compositor's Denoise node) on RESTframe renders.

RESTframe writes no denoiser: it stores the Denoising Albedo and Denoising Normal passes
(``ViewLayer.restframe.denoising_store_passes``) that Blender's Denoise node takes beside the
noisy image, as with Cycles.
"""

from __future__ import annotations

import bpy


def use_denoiser(scene) -> None:
    """Denoise the scene's renders: every view layer stores the denoising data and the
    compositor runs Render Layers -> Denoise (image, albedo, normal) -> the output.

    Replaces the scene's own compositing set-up; meant for the command line, which never
    saves the file it renders.
    """
    for layer in scene.view_layers:
        layer.restframe.denoising_store_passes = True
    scene.render.use_compositing = True
    if bpy.app.version >= (5, 0, 0):  # the compositor is a node group from 5.0
        tree = bpy.data.node_groups.new("RESTframe Denoise", "CompositorNodeTree")
        tree.interface.new_socket("Image", in_out='OUTPUT', socket_type='NodeSocketColor')
        output = tree.nodes.new("NodeGroupOutput").inputs[0]
        scene.compositing_node_group = tree
    else:
        scene.use_nodes = True
        tree = scene.node_tree
        tree.nodes.clear()
        output = tree.nodes.new("CompositorNodeComposite").inputs["Image"]
    layers = tree.nodes.new("CompositorNodeRLayers")
    layers.scene = scene
    denoise = tree.nodes.new("CompositorNodeDenoise")
    tree.links.new(layers.outputs["Image"], denoise.inputs["Image"])
    tree.links.new(layers.outputs["Denoising Albedo"], denoise.inputs["Albedo"])
    tree.links.new(layers.outputs["Denoising Normal"], denoise.inputs["Normal"])
    tree.links.new(denoise.outputs["Image"], output)

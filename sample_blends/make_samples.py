"""Build the sample scenes deterministically:  tools/dev.sh sample_blends/make_samples.py

moving_sphere.blend: a gridded sphere approaching at 0.9 c, 40 degrees off the line
of sight, above a static gridded floor, lit by a sun.  At the reference frame (1)
the sphere is placed beside the camera, yet it is seen 20 units straight ahead,
where it was when the light now arriving left it; it is brightened and rotated
(searchlight effect, Terrell rotation).  Render it with
    tools/dev.sh -m restframe_addon render sample_blends/moving_sphere.blend -o out/moving_sphere.png
"""

import math
import os
import sys

import bpy
from mathutils import Vector

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
import restframe_addon  # noqa: E402


def gridded_material(name, grid_type, size):
    image = bpy.data.images.new(f"{name} Grid", size, size)
    image.generated_type = grid_type
    mat = bpy.data.materials.new(name)
    if bpy.app.version < (5, 0, 0):  # always on (and deprecated) from 5.0
        mat.use_nodes = True
    tree = mat.node_tree
    bsdf = tree.nodes["Principled BSDF"]
    bsdf.inputs["Roughness"].default_value = 0.6
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image = image
    tex.location = (-300, 300)
    tree.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    return mat


def build_moving_sphere():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.name = "Moving Sphere"
    scene.render.engine = 'RESTFRAME'
    scene.restframe.integrator = 'DIRECT'  # the samples show lamp-lit scenes, noise-free
    scene.render.resolution_x, scene.render.resolution_y = 320, 180
    scene.render.resolution_percentage = 100
    scene.render.fps = 24
    scene.frame_start, scene.frame_end, scene.frame_current = 1, 48, 1
    scene.restframe.light_speed = 10.0
    scene.restframe.reference_frame = 1
    scene.restframe.samples = 4

    world = bpy.data.worlds.new("Sky")
    if bpy.app.version < (5, 0, 0):
        world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.02, 0.03, 0.06, 1.0)
    scene.world = world

    cam_data = bpy.data.cameras.new("Camera")
    cam_data.lens = 35
    camera = bpy.data.objects.new("Camera", cam_data)
    camera.location = (0.0, -12.0, 3.0)
    camera.rotation_euler = (math.radians(82), 0.0, 0.0)
    scene.collection.objects.link(camera)
    scene.camera = camera

    sun_data = bpy.data.lights.new("Sun", 'SUN')
    sun_data.energy = 3.0
    sun = bpy.data.objects.new("Sun", sun_data)
    sun.rotation_euler = (math.radians(55), 0.0, math.radians(-25))
    scene.collection.objects.link(sun)

    bpy.ops.mesh.primitive_plane_add(size=60, location=(0.0, 10.0, 0.0))
    floor = bpy.context.object
    floor.name = "Floor"
    floor.data.materials.append(gridded_material("Floor", 'UV_GRID', 512))

    # Place the sphere so that at the reference time it is *seen* at `seen`: light left
    # it there s = |seen - camera| earlier (c = 1 in scene units per light_speed units).
    velocity = 0.9 * Vector((math.sin(math.radians(40)), -math.cos(math.radians(40)), 0.0))
    seen = Vector((0.0, 8.0, 1.6))
    placed = seen + velocity * (seen - camera.location).length
    bpy.ops.mesh.primitive_uv_sphere_add(segments=48, ring_count=24, radius=1.5, location=placed)
    sphere = bpy.context.object
    sphere.name = "Sphere"
    bpy.ops.object.shade_smooth()
    sphere.data.materials.append(gridded_material("Sphere", 'COLOR_GRID', 256))
    sphere.restframe.velocity = velocity
    sphere.pass_index = 1

    path = os.path.join(HERE, "moving_sphere.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path, compress=True)
    if os.path.exists(path + "1"):  # Blender's backup of the previous version
        os.remove(path + "1")
    print(f"wrote {path}")


if __name__ == "__main__":
    restframe_addon.register()
    build_moving_sphere()

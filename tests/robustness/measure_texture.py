"""Cost of a big image texture per rendered frame: seconds and peak memory (not a unit test).

    tools/dev.sh tests/robustness/measure_texture.py [SIZE] [FRAMES]

Builds a plane with a SIZE x SIZE 8-bit PNG base-colour texture (default 8192, saved to a
temporary folder once), renders FRAMES frames (default 3) at 48x32 with 1 sample, and prints
each frame's render time, then the process's peak resident memory.
"""

import os
import sys
import tempfile
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", ".."))
sys.path.insert(0, os.path.dirname(__file__))

import bpy  # noqa: E402

import restframe_addon  # noqa: E402
from big_grid import rss_mb  # noqa: E402


def main(size: int, frames: int) -> None:
    restframe_addon.register()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = 'RESTFRAME'
    scene.render.resolution_x, scene.render.resolution_y = 48, 32
    scene.restframe.samples = 1
    folder = tempfile.mkdtemp(prefix="restframe-texture-")
    path = os.path.join(folder, "big.png")
    image = bpy.data.images.new("Big", size, size)
    image.generated_type = 'COLOR_GRID'
    image.filepath_raw = path
    image.file_format = 'PNG'
    image.save()
    bpy.data.images.remove(image)
    image = bpy.data.images.load(path)
    bpy.ops.mesh.primitive_plane_add(size=4.0)
    plane = bpy.context.object
    mat = bpy.data.materials.new("Textured")
    if bpy.app.version < (5, 0, 0):
        mat.use_nodes = True
    tex = mat.node_tree.nodes.new("ShaderNodeTexImage")
    tex.image = image
    mat.node_tree.links.new(tex.outputs["Color"], mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"])
    plane.data.materials.append(mat)
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    cam.location = (0.0, 0.0, 6.0)
    scene.collection.objects.link(cam)
    scene.camera = cam
    print(f"{size}x{size} texture, after loading: peak {rss_mb():.0f} MB")
    for frame in range(1, frames + 1):
        scene.frame_set(frame)
        started = time.perf_counter()
        bpy.ops.render.render()
        print(f"frame {frame}: {time.perf_counter() - started:.2f} s, peak {rss_mb():.0f} MB", flush=True)


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 8192, int(sys.argv[2]) if len(sys.argv) > 2 else 3)

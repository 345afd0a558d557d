"""Run in a fresh process by test_blender_package.py: install the built zip as a user would, render.

    BLENDER_USER_RESOURCES=<empty dir> python install_and_render.py EXTENSION.zip OUT.exr

The host Python's own embreex is hidden, so the render can only work through the
wheel the extension bundles (as inside a real Blender, which has no embreex).
Prints one JSON line with what it found.
"""

import importlib.abc
import importlib.machinery
import json
import os
import sys

import bpy

zip_path, out_path = sys.argv[1], sys.argv[2]
site = os.path.join(bpy.utils.user_resource('EXTENSIONS'), ".local", "lib",
                    f"python{sys.version_info.major}.{sys.version_info.minor}", "site-packages")


class ExtensionWheelsOnly(importlib.abc.MetaPathFinder):
    """Import embreex only from the extensions' wheel directory."""

    def find_spec(self, name, path=None, target=None):
        if name != "embreex":
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, [site])
        if spec is None:
            raise ModuleNotFoundError("embreex is not installed from the extension's wheels")
        return spec


sys.meta_path.insert(0, ExtensionWheelsOnly())

result = bpy.ops.extensions.package_install_files(filepath=zip_path, repo='user_default', enable_on_install=True)
module = sys.modules.get("bl_ext.user_default.restframe")

scene = bpy.context.scene  # (no factory reset: it would also reset the enabled extensions)
for obj in list(scene.objects):
    bpy.data.objects.remove(obj)
scene.render.engine = 'RESTFRAME'
scene.render.resolution_x, scene.render.resolution_y = 21, 15
scene.restframe.samples = 1
camera = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
camera.location = (0.0, 0.0, 10.0)
scene.collection.objects.link(camera)
scene.camera = camera
mesh = bpy.data.meshes.new("Plane")
mesh.from_pydata([(-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0)], [], [(0, 1, 2, 3)])
plane = bpy.data.objects.new("Plane", mesh)
plane.restframe.velocity = (0.0, 0.0, 0.9)
scene.collection.objects.link(plane)
settings = scene.render.image_settings
if hasattr(settings, "media_type"):  # 5.0
    settings.media_type = 'MULTI_LAYER_IMAGE'
else:
    settings.file_format = 'OPEN_EXR_MULTILAYER'
settings.color_depth = '32'
scene.render.filepath = out_path
bpy.ops.render.render(write_still=True)

import embreex  # noqa: E402  (already imported by the render, from the wheel)

# The command line's own modules (it writes files, starts worker processes, talks to Dask):
# the extension as Blender loads and renders it must not need them.
command_line_modules = sorted(
    name for name in sys.modules
    if name.split(".")[0] in {"dask", "distributed"}
    or (name.startswith("bl_ext.user_default.restframe.") and name.rsplit(".", 1)[-1] in {"__main__", "distributed"}))

print(json.dumps({
    "install": sorted(result),
    "module": module.__file__ if module else None,
    "embreex": embreex.__file__,
    "site": site,
    "command_line_modules": command_line_modules,
}))
if bpy.app.version < (4, 3, 0):  # bpy 4.2 as a module crashes in its exit handlers (see tests/blender/conftest.py)
    sys.stdout.flush()
    os._exit(0)

"""Scene building and EXR reading shared by the Blender-layer tests."""

from __future__ import annotations

import math
import warnings

import bpy
import numpy as np
import OpenEXR

from restframe_addon import export
from restframe_addon.headless import configure_output
from restframe_addon.exr import read_passes as read_exr


def add_camera(scene, location=(0.0, 0.0, 10.0), rotation=(0.0, 0.0, 0.0), **data):
    cam = bpy.data.cameras.new("Camera")
    for key, value in data.items():
        setattr(cam, key, value)
    obj = bpy.data.objects.new("Camera", cam)
    obj.location = location
    obj.rotation_euler = rotation
    scene.collection.objects.link(obj)
    scene.camera = obj
    return obj


def add_plane(scene, name="Plane", size=4.0, location=(0.0, 0.0, 0.0), velocity=(0.0, 0.0, 0.0)):
    half = size / 2
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([(-half, -half, 0), (half, -half, 0), (half, half, 0), (-half, half, 0)], [], [(0, 1, 2, 3)])
    obj = bpy.data.objects.new(name, mesh)
    obj.location = location
    obj.restframe.velocity = velocity
    scene.collection.objects.link(obj)
    return obj


def add_sun(scene, strength=2.0, rotation=(math.radians(20), 0.0, 0.0)):
    light = bpy.data.lights.new("Sun", 'SUN')
    light.energy = strength
    obj = bpy.data.objects.new("Sun", light)
    obj.rotation_euler = rotation
    scene.collection.objects.link(obj)
    return obj


def principled(name, color=None, metallic=None, roughness=None, **inputs):
    """A new material whose Principled BSDF has this base colour (RGB), metallic, roughness and
    other ``inputs`` (by socket name, ``_`` for a space; they come last), Blender's defaults for
    what is not given."""
    m = bpy.data.materials.new(name)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        m.use_nodes = True
    bsdf = m.node_tree.nodes["Principled BSDF"]
    given = {"Base Color": None if color is None else (*color, 1.0), "Metallic": metallic, "Roughness": roughness}
    given.update((key.replace("_", " "), value) for key, value in inputs.items())
    for key, value in given.items():
        if value is not None:
            bsdf.inputs[key].default_value = value
    return m


def use_multilayer_exr(scene, path):
    """The CLI's own output set-up for a 32-bit multilayer EXR at ``path``."""
    configure_output(scene, str(path))
    scene.render.filepath = str(path)


def evaluated(scene):
    return bpy.context.evaluated_depsgraph_get()


def export_now(scene, **kwargs):
    """export.export_scene on the evaluated depsgraph, collecting its warnings."""
    warnings = []
    kwargs.setdefault("warn", warnings.append)
    out, settings = export.export_scene(evaluated(scene), **kwargs)
    return out, settings, warnings


def render_exr(scene, path) -> dict[str, np.ndarray]:
    """An F12 render written as a multilayer EXR (what the user gets), read back."""
    use_multilayer_exr(scene, path)
    bpy.ops.render.render(write_still=True)
    return read_exr(path)


def render_rgba(scene, path) -> np.ndarray:
    """An F12 render saved as a plain RGBA EXR (single part), read back (H, W, 4), row 0 = bottom.

    (Blender 5.0 cannot write a multi-part EXR when the pixel aspect is not 1.)
    """
    settings = scene.render.image_settings
    if hasattr(settings, "media_type"):
        settings.media_type = 'IMAGE'
    settings.file_format = 'OPEN_EXR'
    settings.color_mode = 'RGBA'
    settings.color_depth = '32'
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    with OpenEXR.File(str(path)) as exr:
        channels = exr.parts[0].channels
        rgba = channels["RGBA"].pixels if "RGBA" in channels else np.stack(
            [channels[c].pixels for c in "RGBA"], axis=-1)
    return np.asarray(rgba, dtype=np.float64)[::-1]


def render_eyes(scene, path) -> list[np.ndarray]:
    """An F12 render of a stereo pair saved as one plain RGBA EXR per eye (``<path>_L.exr``,
    ``_R``), read back: [left, right], each (H, W, 4), row 0 = bottom."""
    settings = scene.render.image_settings
    settings.file_format, settings.color_mode, settings.color_depth = 'OPEN_EXR', 'RGBA', '32'
    settings.views_format = 'INDIVIDUAL'
    scene.render.filepath = f"{path}.exr"
    bpy.ops.render.render(write_still=True)
    eyes = []
    for eye in ("L", "R"):
        with OpenEXR.File(f"{path}_{eye}.exr") as exr:
            channels = exr.parts[0].channels
            rgba = channels["RGBA"].pixels if "RGBA" in channels else np.stack(
                [channels[c].pixels for c in "RGBA"], axis=-1)
        eyes.append(np.asarray(rgba, dtype=np.float64)[::-1])
    return eyes


def render_direct_light(scene, path, engine, samples) -> np.ndarray:
    """RGB of an F12 render with Cycles (CPU, direct light only, no denoising, box-like pixels) or
    RESTframe at the same samples: the set-up of the tests that compare the two on lit surfaces."""
    scene.render.engine = engine
    if engine == 'CYCLES':
        scene.cycles.device = 'CPU'
        scene.cycles.samples = samples
        scene.cycles.use_denoising = False
        scene.cycles.filter_width = 0.01
        scene.cycles.max_bounces = 0
    else:
        scene.restframe.samples = samples
    return render_rgba(scene, path)[..., :3]

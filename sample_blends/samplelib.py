"""Shared pieces of the sample scenes: building them with bpy, rendering them headless and
measuring what they show.  Used by the make_*.py scripts, render_gallery.py and tests/samples.

Imaging time.  The paper images every experiment at "the time when event [0, 0, 0, 0] arrives
at the imaging plate".  Our scenes put each moving assembly's pivot at the world origin at the
reference time (frame 1; docs/physics.md#rest-shapes: at the reference frame every pivot is where it was placed),
the camera at distance L from the origin, and the speed of light at L scene units per second.
The light leaving the origin event then reaches the camera after L / c = 1 s: frame 25 at 24 fps.
Every sample .blend is saved at that frame (IMAGING_FRAME), so F12 shows the paper's imaging time.
"""

from __future__ import annotations

import math
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)

from restframe_addon.headless import configure_output  # noqa: E402 (after the path set-up)
from restframe_addon.exr import read_passes  # noqa: E402

FPS = 24
REFERENCE_FRAME = 1
IMAGING_FRAME = REFERENCE_FRAME + FPS  # t_obs = 1 s after the reference time


def gamma(b: float) -> float:
    return 1.0 / math.sqrt((1.0 - b) * (1.0 + b))


# --------------------------------------------------------------------------- building (bpy)
def ensure_registered():
    import bpy

    import restframe_addon

    if not hasattr(bpy.types.Scene, "restframe"):
        restframe_addon.register()


def new_scene(name: str, camera_distance: float, resolution=(256, 256), samples=4):
    """An empty RESTframe scene whose rendered frame is the origin event's arrival (see above)."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.name = name
    scene.render.engine = 'RESTFRAME'
    scene.restframe.integrator = 'DIRECT'  # the samples show lamp-lit scenes, noise-free
    scene.render.resolution_x, scene.render.resolution_y = resolution
    scene.render.resolution_percentage = 100
    scene.render.fps, scene.render.fps_base = FPS, 1.0
    scene.view_settings.view_transform = 'Standard'
    scene.frame_start, scene.frame_end = REFERENCE_FRAME, IMAGING_FRAME
    scene.frame_current = IMAGING_FRAME
    rf = scene.restframe
    rf.light_speed = float(camera_distance)  # L units per second: the origin's light arrives at t = 1 s
    rf.reference_frame = REFERENCE_FRAME
    rf.samples = samples
    return scene


def set_world(scene, color):
    import bpy

    world = bpy.data.worlds.new("World")
    if bpy.app.version < (5, 0, 0):
        world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (*color, 1.0)
    scene.world = world


def add_camera(scene, location, rotation_deg, angle_deg=None, lens=None):
    import bpy

    cam = bpy.data.cameras.new("Camera")
    if angle_deg is not None:
        cam.sensor_fit = 'AUTO'
        cam.angle = math.radians(angle_deg)
    if lens is not None:
        cam.lens = lens
    cam.clip_start, cam.clip_end = 0.01, 10000.0
    obj = bpy.data.objects.new("Camera", cam)
    obj.location = location
    obj.rotation_euler = tuple(math.radians(a) for a in rotation_deg)
    scene.collection.objects.link(obj)
    scene.camera = obj
    return obj


def material(name, color=(0.8, 0.8, 0.8), roughness=0.5, metallic=0.0, transmission=0.0,
             ior=1.5, emission=None, emission_strength=1.0, texture=None):
    """A Principled BSDF material; ``texture`` = (generated type, size) for a generated grid image."""
    import bpy

    mat = bpy.data.materials.new(name)
    if bpy.app.version < (5, 0, 0):
        mat.use_nodes = True
    tree = mat.node_tree
    bsdf = tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (*color, 1.0)
    bsdf.inputs["Roughness"].default_value = roughness
    bsdf.inputs["Metallic"].default_value = metallic
    bsdf.inputs["Transmission Weight"].default_value = transmission
    bsdf.inputs["IOR"].default_value = ior
    if emission is not None:
        bsdf.inputs["Emission Color"].default_value = (*emission, 1.0)
        bsdf.inputs["Emission Strength"].default_value = emission_strength
    if texture is not None:
        kind, size = texture
        image = bpy.data.images.new(f"{name} Grid", size, size)
        image.generated_type = kind
        tex = tree.nodes.new("ShaderNodeTexImage")
        tex.image = image
        tex.location = (-300, 300)
        tree.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    mat.diffuse_color = (*color, 1.0)
    return mat


def mesh_object(scene, name, vertices, faces, materials=(), face_materials=None, location=(0, 0, 0),
                velocity=(0.0, 0.0, 0.0), pass_index=0, uvs=False):
    """A mesh object from vertex and face lists (vertices relative to ``location``, its pivot)."""
    import bpy

    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([tuple(v) for v in vertices], [], [tuple(f) for f in faces])
    for mat in materials:
        mesh.materials.append(mat)
    if face_materials is not None:
        mesh.polygons.foreach_set("material_index", list(face_materials))
    if uvs:
        # planar UVs from x, y over the bounding box (for grid textures)
        verts = np.asarray(vertices, dtype=float)
        lo, hi = verts[:, :2].min(axis=0), verts[:, :2].max(axis=0)
        layer = mesh.uv_layers.new(name="UVMap")
        for loop in mesh.loops:
            xy = (verts[loop.vertex_index, :2] - lo) / np.maximum(hi - lo, 1e-12)
            layer.data[loop.index].uv = tuple(xy)
    mesh.update()
    obj = bpy.data.objects.new(name, mesh)
    obj.location = location
    obj.restframe.velocity = velocity
    obj.pass_index = pass_index
    scene.collection.objects.link(obj)
    return obj


def box(center, size):
    """Vertices and quad faces (outward: -x, +x, -y, +y, -z, +z) of an axis-aligned box."""
    cx, cy, cz = center
    hx, hy, hz = (s / 2 for s in size)
    v = [(cx + sx * hx, cy + sy * hy, cz + sz * hz) for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]
    # index = 4*(sx>0) + 2*(sy>0) + (sz>0)
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    return v, faces


def boxes(centers, size):
    verts, faces = [], []
    for c in centers:
        v, f = box(c, size)
        base = len(verts)
        verts += v
        faces += [tuple(base + i for i in face) for face in f]
    return verts, faces


def add_light(scene, name, kind, location, power, velocity=(0.0, 0.0, 0.0), parent=None,
              rotation_deg=(0.0, 0.0, 0.0), color=(1.0, 1.0, 1.0), radius=0.0):
    import bpy

    data = bpy.data.lights.new(name, kind)
    data.energy = power
    data.color = color
    if kind in {'POINT', 'SPOT'}:
        data.shadow_soft_size = radius
    obj = bpy.data.objects.new(name, data)
    obj.location = location
    obj.rotation_euler = tuple(math.radians(a) for a in rotation_deg)
    obj.restframe.velocity = velocity
    if parent is not None:
        obj.parent = parent  # location is relative to the parent (identity parent inverse)
    scene.collection.objects.link(obj)
    return obj


def save(path):
    import bpy

    bpy.ops.wm.save_as_mainfile(filepath=path, compress=True)
    if os.path.exists(path + "1"):  # Blender's backup of the previous version
        os.remove(path + "1")
    print(f"wrote {os.path.relpath(path, ROOT)}")


# --------------------------------------------------------------------------- rendering (bpy)
def render_blend(blend, exr_path, resolution=None, samples=None, prepare=None, **settings):
    """Open a sample .blend, override resolution / samples / Scene.restframe settings, render
    its saved frame (the imaging frame) to a multilayer EXR.  Returns (passes, camera info).
    ``prepare(scene)`` may change the scene further before the render (e.g. stop an object)."""
    import bpy

    ensure_registered()
    bpy.ops.wm.open_mainfile(filepath=os.path.abspath(blend), load_ui=False)
    scene = bpy.context.scene
    if resolution is not None:
        scene.render.resolution_x, scene.render.resolution_y = resolution
    if samples is not None:
        scene.restframe.samples = samples
    for key, value in settings.items():
        setattr(scene.restframe, key, value)
    if prepare is not None:
        prepare(scene)
    layer = scene.view_layers[0]
    layer.use_pass_normal = layer.use_pass_object_index = layer.use_pass_z = True
    configure_output(scene, str(exr_path))  # the CLI's 32-bit multilayer EXR set-up
    scene.render.filepath = str(exr_path)
    scene.frame_set(scene.frame_current)
    bpy.ops.render.render(write_still=True)
    passes = read_passes(exr_path, bottom_up=False)
    if "IndexOB" in passes and "Object Index" not in passes:
        passes["Object Index"] = passes["IndexOB"]
    return passes, camera_info(scene)


def camera_info(scene) -> dict:
    """What pixel_directions needs: world rotation and the image plane (perspective cameras)."""
    cam = scene.camera
    matrix = np.array(cam.matrix_world, dtype=np.float64)
    rotation = matrix[:3, :3] / np.linalg.norm(matrix[:3, :3], axis=0)
    frame = np.array([tuple(v) for v in cam.data.view_frame(scene=scene)], dtype=np.float64)
    frame = frame[:, :2] / -frame[:, 2:3]  # corners on the plane z = -1
    return {"rotation": rotation, "position": matrix[:3, 3].copy(),
            "x_range": (frame[:, 0].min(), frame[:, 0].max()), "y_range": (frame[:, 1].min(), frame[:, 1].max()),
            "resolution": (scene.render.resolution_x, scene.render.resolution_y)}


# --------------------------------------------------------------------------- measuring (numpy)
def pixel_directions(info) -> np.ndarray:
    """(H, W, 3) unit world directions of the pixel-centre camera rays, row 0 = top."""
    width, height = info["resolution"]
    (x0, x1), (y0, y1) = info["x_range"], info["y_range"]
    u = x0 + (np.arange(width) + 0.5) / width * (x1 - x0)
    v = y1 - (np.arange(height) + 0.5) / height * (y1 - y0)  # row 0 = top
    uu, vv = np.meshgrid(u, v)
    d = np.stack([uu, vv, -np.ones_like(uu)], axis=-1)
    d = d @ info["rotation"].T
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def doppler_predicted(directions, beta) -> np.ndarray:
    """D = 1 / (gamma (1 + beta . d)) for camera rays d (camera into the scene), observer at rest."""
    beta = np.asarray(beta, dtype=np.float64)
    b = float(np.linalg.norm(beta))
    return 1.0 / (gamma(b) * (1.0 + directions @ beta))


def hit_mask(passes) -> np.ndarray:
    return passes["Doppler"][..., 0] > 0


def doppler_range(passes) -> tuple[float, float]:
    d = passes["Doppler"][..., 0]
    d = d[d > 0]
    return float(d.min()), float(d.max())


def outline_circle_fit(mask, directions):
    """Fit a circle on the sky (a cone about an axis) to the outline of ``mask``.

    Outline = hit pixels with a missed 4-neighbour.  Directions on a circle of the unit sphere
    lie on a plane n . d = const: fit that plane (smallest singular vector of the centred
    directions).  Returns (angular radius rad, rms angular residual rad, number of outline pixels).
    """
    m = np.pad(mask, 1)
    inner = m[1:-1, 1:-1] & m[:-2, 1:-1] & m[2:, 1:-1] & m[1:-1, :-2] & m[1:-1, 2:]
    edge = mask & ~inner
    pts = directions[edge]
    centre = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - centre)
    n = vt[2]
    if n @ centre < 0:
        n = -n
    cos_r = float(np.clip(pts @ n, -1, 1).mean())
    angles = np.arccos(np.clip(pts @ n, -1.0, 1.0))
    radius = float(angles.mean())
    return radius, float(np.sqrt(np.mean((angles - radius) ** 2))), int(edge.sum()), n, cos_r


def pixel_angle(info) -> float:
    """Angular size of one pixel at the image centre (rad)."""
    (x0, x1) = info["x_range"]
    return (x1 - x0) / info["resolution"][0]


# --------------------------------------------------------------------------- images
def srgb(linear: np.ndarray) -> np.ndarray:
    """Scene-linear -> display (Blender's 'Standard' view transform), clipped to [0, 1]."""
    x = np.clip(linear, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def save_png(path, display_rgb, colors=256):
    """Save a display-referred (H, W, 3) image in [0, 1] as a palette PNG (PNG-8)."""
    from PIL import Image

    img = Image.fromarray(np.round(np.clip(display_rgb, 0, 1) * 255).astype(np.uint8), "RGB")
    if colors:
        img = img.quantize(colors=colors, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    img.save(path, optimize=True)
    return img

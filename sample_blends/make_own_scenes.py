"""Our own scenes, showing what the paper could not:
    tools/dev.sh sample_blends/make_own_scenes.py

    sphere_outline.blend   a gridded sphere (radius 1.5) crossing the view at 0.9c, 12 units below
                           the camera: contracted to 0.44 of its width along the motion, yet its
                           outline on the sky stays a circle (Penrose-Terrell)
    terrell_cube.blend     a 2-unit cube crossing the view at 0.9c, seen from 40 units with a narrow
                           9 degree lens: its trailing face (red) turns toward the camera, as if the
                           cube were rotated by asin(0.9) = 64 degrees (Terrell rotation)
    mirror.blend           a red glowing ball passing a static mirror at 0.8c: the reflection shows
                           the ball where it was when the longer, reflected light path left it
    glass_bars.blend       a static glass ball in front of a row of bars moving sideways at 0.9c
    spectral_*.blend       a colour-grid panel lit by a lamp riding with it, moving along the line
                           of sight at 0, 0.3c, 0.6c, 0.9c toward and away; SPECTRAL colour with
                           searchlight and exposure normalisation (the README strip, issue 5)
Imaging time everywhere: the pivot's reference event reaches the camera (samplelib docstring).
The sphere and the cube are lit by a sun moving with them, and their scenes normalise the exposure
(seen across the motion D ~ 1/gamma, so the searchlight dims them ~30 times).
"""

import math
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import samplelib as lib  # noqa: E402

SPECTRAL_SPEEDS = {  # file stem -> velocity along +Z (toward the camera)
    "spectral_away_0.9c": -0.9, "spectral_away_0.6c": -0.6, "spectral_away_0.3c": -0.3,
    "spectral_rest": 0.0,
    "spectral_toward_0.3c": 0.3, "spectral_toward_0.6c": 0.6, "spectral_toward_0.9c": 0.9,
}


def uv_sphere(name, radius, location, mat, velocity=(0.0, 0.0, 0.0), pass_index=0, segments=48, rings=24):
    import bpy

    bpy.ops.mesh.primitive_uv_sphere_add(segments=segments, ring_count=rings, radius=radius, location=location)
    obj = bpy.context.object
    obj.name = name
    bpy.ops.object.shade_smooth()
    obj.data.materials.append(mat)
    obj.restframe.velocity = velocity
    obj.pass_index = pass_index
    return obj


def floor(scene, size, z=0.0, center=(0.0, 0.0)):
    h = size / 2
    cx, cy = center
    return lib.mesh_object(scene, "Floor", [(cx - h, cy - h, z), (cx + h, cy - h, z), (cx + h, cy + h, z), (cx - h, cy + h, z)],
                           [(0, 1, 2, 3)], materials=[lib.material("Floor", roughness=0.7, texture=('UV_GRID', 256))],
                           pass_index=9, uvs=True)


def build_sphere_outline():
    scene = lib.new_scene("Sphere outline", 12.0, resolution=(255, 255), samples=4)
    lib.set_world(scene, (0.01, 0.012, 0.02))
    lib.add_camera(scene, (0.0, 0.0, 12.0), (0.0, 0.0, 0.0), angle_deg=30.0)
    scene.restframe.normalize_exposure = True  # seen from the side at 0.9c: D ~ 0.4, D^4 ~ 0.03
    # the sun rides with the sphere, so the sphere is lit in its own frame as it would be at rest
    lib.add_light(scene, "Sun", 'SUN', (0, 0, 20), power=3.0, rotation_deg=(15.0, -45.0, 0.0), velocity=(0.9, 0.0, 0.0))
    uv_sphere("Sphere", 1.5, (0.0, 0.0, 0.0), lib.material("Sphere", roughness=0.6, texture=('COLOR_GRID', 256)),
              velocity=(0.9, 0.0, 0.0), pass_index=1)
    lib.save(os.path.join(lib.HERE, "sphere_outline.blend"))


CUBE_FACES = ["-x trailing", "+x leading", "-y", "+y", "-z", "+z top"]


def build_terrell_cube():
    scene = lib.new_scene("Terrell cube", 40.0, resolution=(255, 255), samples=4)
    lib.set_world(scene, (0.01, 0.012, 0.02))
    lib.add_camera(scene, (0.0, 0.0, 40.0), (0.0, 0.0, 0.0), angle_deg=9.0)
    scene.restframe.normalize_exposure = True
    lib.add_light(scene, "Sun", 'SUN', (0, 0, 50), power=4.0, rotation_deg=(-30.0, -40.0, 0.0), velocity=(0.9, 0.0, 0.0))
    mats = [lib.material("Trailing", (0.8, 0.08, 0.05)), lib.material("Leading", (0.05, 0.15, 0.8)),
            lib.material("Side", (0.8, 0.7, 0.1)), lib.material("Top", roughness=0.6, texture=('UV_GRID', 128))]
    verts, faces = lib.box((0.0, 0.0, -1.0), (2.0, 2.0, 2.0))
    lib.mesh_object(scene, "Cube", verts, faces, materials=mats, face_materials=[0, 1, 2, 2, 2, 3],
                    velocity=(0.9, 0.0, 0.0), pass_index=1, uvs=True)
    lib.save(os.path.join(lib.HERE, "terrell_cube.blend"))


MIRROR_Y = 6.0
MIRROR_CAMERA = (0.0, -12.0, 2.0)
MIRROR_BALL = (0.0, 0.0, 2.0)
MIRROR_BETA = 0.8


def build_mirror():
    scene = lib.new_scene("Mirror", 12.0, resolution=(320, 180), samples=4)
    lib.set_world(scene, (0.02, 0.025, 0.04))
    lib.add_camera(scene, MIRROR_CAMERA, (90.0, 0.0, 0.0), angle_deg=70.0)
    lib.add_light(scene, "Sun", 'SUN', (0, 0, 20), power=2.0, rotation_deg=(40.0, 0.0, 30.0))
    floor(scene, 40.0, center=(0.0, 0.0))
    lib.mesh_object(scene, "Mirror", [(-11, MIRROR_Y, 0.2), (11, MIRROR_Y, 0.2), (11, MIRROR_Y, 5.0), (-11, MIRROR_Y, 5.0)],
                    [(0, 1, 2, 3)], materials=[lib.material("Mirror", (0.95, 0.95, 0.95), roughness=0.0, metallic=1.0)],
                    pass_index=2)
    uv_sphere("Ball", 0.6, MIRROR_BALL, lib.material("Glow", (0.0, 0.0, 0.0), emission=(1.0, 0.05, 0.02), emission_strength=40.0),
              velocity=(MIRROR_BETA, 0.0, 0.0), pass_index=1)
    lib.save(os.path.join(lib.HERE, "mirror.blend"))


def build_glass_bars():
    camera = (0.0, -10.0, 1.5)
    scene = lib.new_scene("Glass and bars", math.dist(camera, (0.0, 3.0, 0.0)), resolution=(320, 180), samples=8)
    lib.set_world(scene, (0.02, 0.025, 0.04))
    lib.add_camera(scene, camera, (90.0, 0.0, 0.0), angle_deg=55.0)
    lib.add_light(scene, "Sun", 'SUN', (0, 0, 20), power=3.0, rotation_deg=(40.0, 0.0, -30.0))
    floor(scene, 40.0, center=(0.0, 5.0))
    uv_sphere("Glass", 1.3, (0.0, -3.0, 1.5), lib.material("Glass", (1.0, 1.0, 1.0), roughness=0.0, transmission=1.0, ior=1.5),
              pass_index=2)
    verts, faces = lib.boxes([(x, 0.0, 1.5) for x in range(-8, 9, 2)], (0.4, 0.4, 3.0))
    lib.mesh_object(scene, "Bars", verts, faces, materials=[lib.material("Bars", (0.9, 0.45, 0.08))],
                    location=(0.0, 3.0, 0.0), velocity=(0.9, 0.0, 0.0), pass_index=1)
    lib.save(os.path.join(lib.HERE, "glass_bars.blend"))


def build_spectral(stem, beta):
    scene = lib.new_scene(f"Spectral {beta:+.1f}c", 10.0, resolution=(129, 129), samples=4)
    lib.set_world(scene, (0.0, 0.0, 0.0))
    rf = scene.restframe
    rf.doppler_mode = 'SPECTRAL'
    rf.searchlight = True
    rf.normalize_exposure = True
    rf.spectral_samples = 32
    lib.add_camera(scene, (0.0, 0.0, 10.0), (0.0, 0.0, 0.0), angle_deg=30.0)
    velocity = (0.0, 0.0, beta)
    h = 2.0
    panel = lib.mesh_object(scene, "Panel", [(-h, -h, 0), (h, -h, 0), (h, h, 0), (-h, h, 0)], [(0, 1, 2, 3)],
                            materials=[lib.material("Panel", roughness=0.9, texture=('COLOR_GRID', 256))],
                            velocity=velocity, pass_index=1, uvs=True)
    lib.add_light(scene, "Lamp", 'POINT', (0.0, 0.0, 3.0), power=600.0, velocity=velocity, parent=panel)
    lib.save(os.path.join(lib.HERE, stem + ".blend"))


def build_all():
    lib.ensure_registered()
    build_sphere_outline()
    build_terrell_cube()
    build_mirror()
    build_glass_bars()
    for stem, beta in SPECTRAL_SPEEDS.items():
        build_spectral(stem, beta)


if __name__ == "__main__":
    build_all()

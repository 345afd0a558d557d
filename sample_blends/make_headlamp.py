"""Paper experiment 1 (section 3.2.1, figures 4-8), the headlamp effect:
    tools/dev.sh sample_blends/make_headlamp.py

A 2 x 2 array of point lights 1.5 units in front of a diffuse 10 x 10 plane, all moving together
along the viewing axis (the lights are parented to the plane, so their distance from it is fixed
in the common rest frame, as in the paper).  The camera looks down the -Z axis from z = 20 at the
plane, which is perpendicular to the view.  Five files: at rest, toward the camera (+Z) at 0.5c and
0.9c, away (-Z) at 0.5c and 0.9c.  Imaging time = the origin event's arrival (samplelib docstring):
the axis ray sees the plane's centre as it was at the reference time, so every difference between
the five images comes from relativistic imaging, not from a changed configuration.
"""

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import samplelib as lib  # noqa: E402

CAMERA_DISTANCE = 20.0
LIGHT_HEIGHT = 1.5
LIGHT_OFFSET = 2.0
VARIANTS = {  # file stem -> velocity along +Z (toward the camera)
    "headlamp_rest": 0.0,
    "headlamp_toward_0.5c": 0.5,
    "headlamp_toward_0.9c": 0.9,
    "headlamp_away_0.5c": -0.5,
    "headlamp_away_0.9c": -0.9,
}


def build(stem, beta):
    scene = lib.new_scene(f"Headlamp {beta:+.1f}c", CAMERA_DISTANCE, resolution=(255, 255), samples=4)
    lib.set_world(scene, (0.0, 0.0, 0.0))
    scene.restframe.normalize_exposure = True  # 0.9c toward is ~360x brighter than at rest (D^4)
    lib.add_camera(scene, (0.0, 0.0, CAMERA_DISTANCE), (0.0, 0.0, 0.0), angle_deg=40.0)
    velocity = (0.0, 0.0, beta)
    half = 5.0
    plane = lib.mesh_object(scene, "Plane", [(-half, -half, 0), (half, -half, 0), (half, half, 0), (-half, half, 0)],
                            [(0, 1, 2, 3)], materials=[lib.material("Diffuse", (0.8, 0.8, 0.8), roughness=1.0)],
                            velocity=velocity, pass_index=1)
    for i, (sx, sy) in enumerate([(-1, -1), (1, -1), (-1, 1), (1, 1)]):
        lib.add_light(scene, f"Lamp {i + 1}", 'POINT', (sx * LIGHT_OFFSET, sy * LIGHT_OFFSET, LIGHT_HEIGHT),
                      power=60.0, velocity=velocity, parent=plane, radius=0.0)
    lib.save(os.path.join(lib.HERE, stem + ".blend"))


def build_all():
    lib.ensure_registered()
    for stem, beta in VARIANTS.items():
        build(stem, beta)


if __name__ == "__main__":
    build_all()

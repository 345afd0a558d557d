"""Paper experiment 2 (section 3.2.2, figures 9-11), multiple frame intersection:
    tools/dev.sh sample_blends/make_bars.py

An 11 x 11 array of bars (0.6 x 0.6 x 4, long axis along Z, top faces at z = 0) on a 2-unit grid
in the X-Y plane of their rest frames; the camera sits on the +Z axis at z = 40 and looks down at
the array.  Each row (constant y) is one mesh object, so a row is a rigid body whose bars keep
their 2-unit spacing in the row's rest frame; its pivot is the row's centre on the X-Y plane, and
its pass index is the row number + 1 (bottom row = 1).
    bars_rest.blend      figure 9:  nothing moves
    bars_sideways.blend  figure 10: rows move along +X at 0.0c (bottom) ... 0.9c in steps of 0.1c,
                                    top row 0.99c
    bars_toward.blend    figure 11: rows move along +Z (toward the camera): middle row 0.95c,
                                    then 0.9c, 0.7c, 0.5c, 0.3c, 0.0c outward
Imaging time: the origin event's arrival (samplelib docstring).  A sun at rest in the world frame
lights the bars, so moving rows are lit by aberrated sunlight.  This experiment is about geometry
(which frame's surface each ray meets first), so the searchlight intensity change is off: with it
the rows approaching at 0.9c and 0.95c (D^4 up to ~1500) would be white.
"""

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import samplelib as lib  # noqa: E402

CAMERA_DISTANCE = 40.0
PITCH = 2.0
N = 11
SIDEWAYS = [0.1 * i for i in range(10)] + [0.99]
TOWARD = [0.0, 0.3, 0.5, 0.7, 0.9, 0.95, 0.9, 0.7, 0.5, 0.3, 0.0]


def row_velocities(kind):
    if kind == "rest":
        return [(0.0, 0.0, 0.0)] * N
    if kind == "sideways":
        return [(b, 0.0, 0.0) for b in SIDEWAYS]
    return [(0.0, 0.0, b) for b in TOWARD]


def build(kind):
    scene = lib.new_scene(f"Bars {kind}", CAMERA_DISTANCE, resolution=(255, 255), samples=4)
    lib.set_world(scene, (0.01, 0.012, 0.02))
    scene.restframe.searchlight = False
    lib.add_camera(scene, (0.0, 0.0, CAMERA_DISTANCE), (0.0, 0.0, 0.0), angle_deg=36.0)
    lib.add_light(scene, "Sun", 'SUN', (0, 0, 50), power=3.0, rotation_deg=(35.0, 0.0, 30.0))
    mats = [lib.material("Bar side", (0.75, 0.72, 0.65), roughness=0.8),
            lib.material("Bar top", (0.9, 0.35, 0.1), roughness=0.8)]
    offsets = [(i - N // 2) * PITCH for i in range(N)]
    for row, velocity in enumerate(row_velocities(kind)):
        y = offsets[row]
        verts, faces = lib.boxes([(x, 0.0, -2.0) for x in offsets], (0.6, 0.6, 4.0))
        face_mats = [1 if k % 6 == 5 else 0 for k in range(len(faces))]  # the +Z face of each bar
        lib.mesh_object(scene, f"Row {row + 1}", verts, faces, materials=mats, face_materials=face_mats,
                        location=(0.0, y, 0.0), velocity=velocity, pass_index=row + 1)
    lib.save(os.path.join(lib.HERE, f"bars_{kind}.blend"))


def build_all():
    lib.ensure_registered()
    for kind in ("rest", "sideways", "toward"):
        build(kind)


if __name__ == "__main__":
    build_all()

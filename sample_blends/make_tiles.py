"""Paper experiment 3 (section 3.2.3, figures 12-15), the relativistic Doppler effect:
    tools/dev.sh sample_blends/make_tiles.py

A flat array of 61 x 31 square tiles (0.42 wide on a 0.5 pitch, so void shows between them) in the
X-Y plane of its rest frame, pivot at its centre (the origin).  The camera looks down the -Z axis
from z = 20 with a 20.5 degree square field of view: its corner rays are 14.33 degrees off the
axis, the angle at which approach at 0.9c gives D = 1 / (gamma (1 - 0.9 cos 14.33 deg)) = 3.407,
the paper's lowest factor for that run (the only statement of its field of view the paper makes).
The array covers the whole field in all three runs, so the range of D over the image is set by the
field of view alone.  Imaging time: the origin event's arrival (samplelib docstring).
Display: Doppler factor as grey (FACTOR mode), normalised to each frame's own range (figures 12,
14), and the same quantised to 15 levels (figures 13, 15: the *_q15 files).
    tiles_toward_0.9c      velocity (0, 0, 0.9): toward the camera
    tiles_sideways_0.8c    velocity (0.8, 0, 0)
    tiles_sideways_0.9c    velocity (0.9, 0, 0)
"""

import math
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import samplelib as lib  # noqa: E402

CAMERA_DISTANCE = 20.0
FIELD_OF_VIEW = 20.5  # degrees, square image
PITCH, TILE = 0.5, 0.42
NX, NY = 61, 31
VARIANTS = {
    "tiles_toward_0.9c": (0.0, 0.0, 0.9),
    "tiles_sideways_0.8c": (0.8, 0.0, 0.0),
    "tiles_sideways_0.9c": (0.9, 0.0, 0.0),
}


def tile_geometry():
    verts, faces = [], []
    h = TILE / 2
    for j in range(NY):
        for i in range(NX):
            x, y = (i - NX // 2) * PITCH, (j - NY // 2) * PITCH
            base = len(verts)
            verts += [(x - h, y - h, 0.0), (x + h, y - h, 0.0), (x + h, y + h, 0.0), (x - h, y + h, 0.0)]
            faces.append((base, base + 1, base + 2, base + 3))
    return verts, faces


def build(stem, velocity, levels):
    scene = lib.new_scene(f"Tiles {stem}", CAMERA_DISTANCE, resolution=(255, 255), samples=1)
    lib.set_world(scene, (0.02, 0.05, 0.12))  # the paper pseudo-colours the void
    rf = scene.restframe
    rf.doppler_mode = 'FACTOR'
    rf.doppler_range_auto = True
    rf.doppler_levels = levels
    lib.add_camera(scene, (0.0, 0.0, CAMERA_DISTANCE), (0.0, 0.0, 0.0), angle_deg=FIELD_OF_VIEW)
    verts, faces = tile_geometry()
    lib.mesh_object(scene, "Tiles", verts, faces, materials=[lib.material("Tile", (0.8, 0.8, 0.8))],
                    velocity=velocity, pass_index=1)
    suffix = "_q15" if levels else ""
    lib.save(os.path.join(lib.HERE, stem + suffix + ".blend"))


def corner_angle_deg():
    half = math.tan(math.radians(FIELD_OF_VIEW / 2))
    return math.degrees(math.atan(half * math.sqrt(2)))


def build_all():
    lib.ensure_registered()
    for stem, velocity in VARIANTS.items():
        build(stem, velocity, 0)
    for stem in ("tiles_toward_0.9c", "tiles_sideways_0.8c"):
        build(stem, VARIANTS[stem], 15)


if __name__ == "__main__":
    build_all()

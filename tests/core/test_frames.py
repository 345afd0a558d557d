"""Building rest frames: a large mesh goes to embree in pieces (issue 9, Esc during the build)."""

import numpy as np
import pytest
from shapes import look_at_camera

from restframe_addon.core import frames
from restframe_addon.core.frames import build_frames
from restframe_addon.core.motion import Trajectory
from restframe_addon.core.scene import Mesh, Scene
from restframe_addon.core.tracer import occluded, trace_nearest

CELLS = 40  # the grid has CELLS x CELLS unit squares, two triangles each (3200)
PIECE = 64  # triangles per embree geometry in these tests: 50 pieces


def grid(cells=CELLS):
    """A flat grid on z = 0 with unit cells from (0, 0): the triangles of cell (i, j) are
    2 (j cells + i) and the one after, [a, b, c] below its diagonal and [a, c, d] above."""
    xs = np.arange(cells + 1, dtype=np.float64)
    x, y = np.meshgrid(xs, xs, indexing="xy")
    vertices = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    a = (np.arange(cells)[None, :] + (cells + 1) * np.arange(cells)[:, None]).ravel()
    b, c, d = a + 1, a + cells + 2, a + cells + 1
    triangles = np.stack([np.column_stack([a, b, c]), np.column_stack([a, c, d])], axis=1).reshape(-1, 3)
    return vertices, triangles


def grid_scene(mesh=None, **mesh_options):
    vertices, triangles = mesh or grid()
    camera = look_at_camera((CELLS / 2, CELLS / 2, 10.0), (CELLS / 2, CELLS / 2, 0.0))
    return Scene(camera=camera, meshes=[Mesh("grid", vertices, triangles, **mesh_options)])


@pytest.mark.parametrize("shuffled", [False, True], ids=["grid order", "shuffled"])
def test_a_mesh_in_many_pieces_traces_the_analytic_triangle_and_barycentrics(monkeypatch, shuffled):
    monkeypatch.setattr(frames, "_PIECE_TRIANGLES", PIECE)
    vertices, triangles = grid()
    order = np.arange(len(triangles))  # order[k]: the grid triangle stored k-th
    if shuffled:  # each piece then uses vertices from all over the mesh
        rng = np.random.default_rng(3)
        order = rng.permutation(len(triangles))
        renumber = rng.permutation(len(vertices))
        moved = np.empty_like(vertices)
        moved[renumber] = vertices
        vertices, triangles = moved, renumber[triangles[order]]
    frame_set = build_frames(grid_scene((vertices, triangles)))
    geometry = frame_set.frames[frame_set.world].geometry
    assert len(geometry.piece_start) == CELLS * CELLS * 2 // PIECE

    rng = np.random.default_rng(9)
    n = 2000
    cell = rng.integers(0, CELLS, size=(n, 2))
    fraction = rng.uniform(0.05, 0.95, size=(n, 2))
    fraction[np.abs(fraction[:, 0] - fraction[:, 1]) < 0.05] += [0.05, -0.05]  # off the diagonals
    height = rng.uniform(1.0, 5.0, n)
    x0 = np.column_stack([cell + fraction, height])
    d = np.tile([0.0, 0.0, -1.0], (n, 1))
    hits = trace_nearest(frame_set, frame_set.world, np.zeros(n), x0, d, 0.0, np.inf)

    fx, fy = fraction.T
    upper = fy > fx  # the second triangle of the cell, [a, c, d]
    assert np.array_equal(order[hits.prim], 2 * (cell[:, 1] * CELLS + cell[:, 0]) + upper)
    # position = (1 - u - v) v0 + u v1 + v v2
    assert np.allclose(hits.u, np.where(upper, fx, fx - fy), atol=1e-5)
    assert np.allclose(hits.v, np.where(upper, fy - fx, fy), atol=1e-5)
    assert np.allclose(hits.s, height, rtol=1e-6)


def test_a_mesh_in_many_pieces_occludes_where_it_is(monkeypatch):
    monkeypatch.setattr(frames, "_PIECE_TRIANGLES", PIECE)
    frame_set = build_frames(grid_scene())
    x = np.linspace(-4.5, CELLS + 4.5, 200)
    x0 = np.column_stack([x, np.full_like(x, CELLS - 0.3), np.ones_like(x)])  # over the last pieces
    d = np.tile([0.0, 0.0, -1.0], (len(x), 1))
    blocked = occluded(frame_set, frame_set.world, np.zeros(len(x)), x0, d, 0.0, 2.0)
    assert np.array_equal(blocked, (x > 0) & (x < CELLS))


def straight_line(velocity=(0.3, 0.0, 0.0)):
    tau = np.linspace(-50.0, 50.0, 5)
    return Trajectory(tau, np.outer(tau, velocity), name="grid")


@pytest.mark.parametrize("motion", [{}, {"angular_velocity": (0.0, 0.0, 1.0)}, {"trajectory": straight_line()}],
                         ids=["inertial", "spinning", "animated"])
def test_esc_during_the_build_stops_after_the_piece_in_hand(monkeypatch, motion):
    monkeypatch.setattr(frames, "_PIECE_TRIANGLES", PIECE)
    built = []

    def counted_mesh(*args):
        built.append(len(args[2]))
        return triangle_mesh(*args)

    triangle_mesh = frames.TriangleMesh
    monkeypatch.setattr(frames, "TriangleMesh", counted_mesh)
    frame_set = build_frames(grid_scene(**motion), should_stop=lambda: len(built) >= 3)
    assert built == [PIECE] * 3  # of 50
    assert not any(frame.has_geometry for frame in frame_set.frames)

    built.clear()
    frame_set = build_frames(grid_scene(**motion))
    assert sum(built) == CELLS * CELLS * 2
    assert any(frame.has_geometry for frame in frame_set.frames)

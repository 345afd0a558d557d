"""Building rest frames: a large mesh goes to embree in pieces (issue 9, Esc during the build),
handed over directly or through embreex (issue 20), with the culling clusters."""

import sys
import threading

import numpy as np
import pytest
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh
from shapes import look_at_camera, uv_sphere

from restframe_addon.core import embree_direct, frames, rows, tracer
from restframe_addon.core.frames import build_frames
from restframe_addon.core.motion import Trajectory
from restframe_addon.core.scene import Mesh, Scene, Velocity
from restframe_addon.core.tracer import Hits, frames_hit, occluded, trace_nearest

CELLS = 40  # the grid has CELLS x CELLS unit squares, two triangles each (3200)
PIECE = 64  # triangles per embree geometry in these tests: 50 pieces


def in_pieces(monkeypatch):
    """Meshes handed to embree in pieces of ``PIECE`` triangles, directly and through embreex."""
    monkeypatch.setattr(frames, "_PIECE_TRIANGLES", PIECE)
    monkeypatch.setattr(frames, "_DIRECT_PIECE_TRIANGLES", PIECE)


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
    in_pieces(monkeypatch)
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
    in_pieces(monkeypatch)
    frame_set = build_frames(grid_scene())
    x = np.linspace(-4.5, CELLS + 4.5, 200)
    x0 = np.column_stack([x, np.full_like(x, CELLS - 0.3), np.ones_like(x)])  # over the last pieces
    d = np.tile([0.0, 0.0, -1.0], (len(x), 1))
    blocked = occluded(frame_set, frame_set.world, np.zeros(len(x)), x0, d, 0.0, 2.0)
    assert np.array_equal(blocked, (x > 0) & (x < CELLS))


def test_embree_builds_the_bvh_without_holding_the_gil():
    """The engine polls Esc from its main thread while the build runs in a worker: a Python
    thread must go on running while embree builds.  With a long switch interval a thread runs
    during one call only if the call lets go of the GIL (embreex's own commit does not)."""
    vertices, triangles = uv_sphere((0.0, 0.0, 0.0), 1.0, 512, 256)
    device = frames._embree_device()
    scene = rtcore_scene.EmbreeScene(device)
    assert embree_direct.attach(scene, device, vertices.astype(np.float32), triangles)
    ticks, running, done = [0], threading.Event(), threading.Event()

    def tick():
        running.set()
        while not done.is_set():
            ticks[0] += 1

    interval = sys.getswitchinterval()
    sys.setswitchinterval(0.5)
    try:
        ticker = threading.Thread(target=tick)
        ticker.start()
        running.wait()
        before = ticks[0]
        embree_direct.commit(scene)
        during = ticks[0] - before
        done.set()
        ticker.join()
    finally:
        sys.setswitchinterval(interval)
    assert during > 0 and scene.is_committed
    hit = scene.run(np.array([[0.0, 0.0, -3.0]], np.float32), np.array([[0.0, 0.0, 1.0]], np.float32), output=1)
    assert hit["primID"][0] >= 0 and abs(hit["tfar"][0] - 2.0) < 1e-3


def straight_line(velocity=(0.3, 0.0, 0.0)):
    tau = np.linspace(-50.0, 50.0, 5)
    return Trajectory(tau, np.outer(tau, velocity), name="grid")


@pytest.mark.parametrize("motion", [{}, {"angular_velocity": (0.0, 0.0, 1.0)}, {"trajectory": straight_line()}],
                         ids=["inertial", "spinning", "animated"])
def test_esc_during_the_build_stops_after_the_piece_in_hand(monkeypatch, motion):
    in_pieces(monkeypatch)
    built = []

    def counted_piece(scene, vertices, triangles, *args):
        built.append(len(triangles))
        return attach_piece(scene, vertices, triangles, *args)

    attach_piece = frames._attach_piece
    monkeypatch.setattr(frames, "_attach_piece", counted_piece)
    frame_set = build_frames(grid_scene(**motion), should_stop=lambda: len(built) >= 3)
    assert built == [PIECE] * 3  # of 50
    assert not any(frame.has_geometry for frame in frame_set.frames)

    built.clear()
    frame_set = build_frames(grid_scene(**motion))
    assert sum(built) == CELLS * CELLS * 2
    assert any(frame.has_geometry for frame in frame_set.frames)


def sphere_hits(frame_set, n=3000, seed=5):
    """Nearest hits of rays from random points around the scene aimed near the origin."""
    rng = np.random.default_rng(seed)
    x0 = rng.normal(size=(n, 3)) * 4.0
    d = rng.normal(size=(n, 3)) * 0.3 + SPHERE_CENTRE - x0
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return trace_nearest(frame_set, frame_set.camera, np.zeros(n), x0, d, 0.0, np.inf)


SPHERE_CENTRE = (0.2, -0.1, 0.3)


def shuffled_sphere():
    vertices, triangles = uv_sphere(SPHERE_CENTRE, 1.0, 48, 24)
    rng = np.random.default_rng(11)
    renumber = rng.permutation(len(vertices))
    moved = np.empty_like(vertices)
    moved[renumber] = vertices
    return moved, renumber[triangles[rng.permutation(len(triangles))]]


def test_triangles_handed_to_embree_directly_hit_exactly_as_through_embreex(monkeypatch):
    """The direct route (one memory copy per buffer) fills embree's buffers as embreex's own
    TriangleMesh does: every hit, its triangle and barycentrics are the same, whether the mesh
    goes in one piece (the direct route's own) or in many."""
    monkeypatch.setattr(frames, "_PIECE_TRIANGLES", PIECE)
    scene = grid_scene(shuffled_sphere())
    meshes = []
    monkeypatch.setattr(frames, "TriangleMesh", lambda *args: meshes.append(TriangleMesh(*args)))
    whole = build_frames(scene)
    assert len(whole.frames[whole.world].geometry.piece_start) == 1
    direct = sphere_hits(whole)
    monkeypatch.setattr(frames, "_DIRECT_PIECE_TRIANGLES", PIECE)
    direct_in_pieces = sphere_hits(build_frames(scene))
    assert not meshes and embree_direct._library  # proved and used on this platform
    monkeypatch.setattr(embree_direct, "shared_vertices", lambda *args: None)
    through_embreex = sphere_hits(build_frames(scene))
    assert len(meshes) == -(-len(scene.meshes[0].triangles) // PIECE)
    assert np.count_nonzero(direct.frame >= 0) > 1000
    for name in ("frame", "prim", "s", "u", "v"):
        np.testing.assert_array_equal(getattr(direct, name), getattr(through_embreex, name), err_msg=name)
        np.testing.assert_array_equal(getattr(direct, name), getattr(direct_in_pieces, name), err_msg=name)


@pytest.mark.parametrize("loose", [False, True], ids=["every vertex used", "a loose vertex far out"])
def test_a_large_meshs_index_and_vertex_sides_side_by_side_build_what_one_thread_builds(monkeypatch, loose):
    """Over ``_CHUNK`` triangles the used-vertex mask and embree's index buffer are made on the
    build's threads beside the bounds, radius, anchor and float32 vertices (worked out as if
    every vertex were used) and the copies of the corner normals and UVs: the same geometry and
    hits as one thread's steps in turn, the bounds those of the used vertices where a loose one
    lies far out."""
    monkeypatch.setattr(frames, "_CHUNK", 1000)
    vertices, triangles = shuffled_sphere()
    assert len(triangles) > frames._CHUNK
    if loose:
        vertices = np.concatenate([vertices, [[50.0, -40.0, 30.0]]])
    rng = np.random.default_rng(3)
    corners = {"corner_normals": rng.normal(size=(len(triangles), 3, 3)), "corner_uvs": rng.random((len(triangles), 3, 2))}
    scene = grid_scene((vertices, triangles), **corners)
    sides = []
    side_by_side = frames._side_by_side
    monkeypatch.setattr(frames, "_side_by_side", lambda work, arguments, *a: sides.append(len(arguments))
                        or side_by_side(work, arguments, *a))
    beside = build_frames(scene)
    assert sides == [3]
    monkeypatch.setattr(frames, "_CHUNK", 10**9)
    alone = build_frames(scene)
    assert sides == [3]
    a, b = (f.frames[f.world].geometry for f in (beside, alone))
    for name in ("lo", "hi", "anchor", "radius", "triangles", "corner_normals", "corner_uvs"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    for name, given in corners.items():  # the geometry's own copies
        np.testing.assert_array_equal(getattr(a, name), given)
        assert not np.may_share_memory(getattr(a, name), given)
    assert (a.hi < 2.0).all() and a.radius < 2.0  # (the loose vertex left out)
    hits, plain = sphere_hits(beside), sphere_hits(alone)
    assert np.count_nonzero(hits.frame >= 0) > 1000
    for name in ("frame", "prim", "s", "u", "v"):
        np.testing.assert_array_equal(getattr(hits, name), getattr(plain, name), err_msg=name)


def test_without_a_proved_embree_library_the_build_goes_through_embreex(monkeypatch):
    monkeypatch.setattr(embree_direct, "_library", None)
    monkeypatch.setattr(embree_direct, "_loaded_embree", lambda: None)
    meshes = []
    monkeypatch.setattr(frames, "TriangleMesh", lambda *args: meshes.append(TriangleMesh(*args)))
    hits = sphere_hits(build_frames(grid_scene(shuffled_sphere())))
    assert embree_direct._library is False and len(meshes) == 1
    assert np.count_nonzero(hits.frame >= 0) > 1000


def plain_clusters(vertices, triangles, depth=4):
    """The clusters as first written, on (n, 3, 3) corner arrays: median splits of the centroids
    along the longest axis, then each group's corner box."""
    tri = vertices[triangles]
    centroids = tri.mean(axis=1)
    groups = [np.arange(len(triangles))]
    for _ in range(depth):
        split = []
        for group in groups:
            if len(group) < 64:
                split.append(group)
                continue
            c = centroids[group]
            axis = int(np.argmax(c.max(axis=0) - c.min(axis=0)))
            order = np.argpartition(c[:, axis], len(group) // 2)
            split += [group[order[: len(group) // 2]], group[order[len(group) // 2:]]]
        groups = split
    spheres = []
    for group in groups:
        points = tri[group].reshape(-1, 3)
        lo, hi = points.min(axis=0), points.max(axis=0)
        span = hi - lo  # its length term by term (np.linalg.norm's BLAS dot rounds by the address's alignment)
        spheres.append([*(0.5 * (lo + hi)), 0.5 * float(np.sqrt(span[0] * span[0] + span[1] * span[1] + span[2] * span[2]))])
    return np.array(spheres)


@pytest.mark.parametrize("chunk", [frames._CHUNK, 700], ids=["one thread", "threads"])
@pytest.mark.parametrize("mesh", ["sphere", "grid", "random", "random with ties", "few"])
def test_culling_clusters_hold_every_triangle_and_match_the_plain_computation(mesh, chunk, monkeypatch):
    """On the calling thread (these meshes are small) and, in chunks of 700 triangles, on the build's threads."""
    monkeypatch.setattr(frames, "_CHUNK", chunk)
    rng = np.random.default_rng(2)
    if mesh == "sphere":
        vertices, triangles = shuffled_sphere()
    elif mesh == "grid":
        vertices, triangles = grid()
    elif mesh == "few":
        vertices, triangles = uv_sphere((1.0, 2.0, 3.0), 0.5, 6, 4)
    else:
        vertices = rng.normal(size=(3000, 3)) * [1.0, 4.0, 0.3] + [5.0, 0.0, -2.0]
        if mesh == "random with ties":
            vertices = np.round(vertices * 2.0) / 2.0
        triangles = rng.integers(0, len(vertices), size=(5000, 3))
    clusters = frames._clusters(vertices, triangles)
    np.testing.assert_array_equal(clusters, plain_clusters(vertices, triangles))
    # every triangle (all three corners) lies in one of the spheres
    corners = vertices[triangles]
    inside = np.linalg.norm(corners[:, :, None, :] - clusters[None, None, :, :3], axis=-1) <= clusters[:, 3] * (1 + 1e-12)
    assert inside.all(axis=1).any(axis=1).all()


def test_body_boxes_hold_each_body_at_every_time_of_every_frame():
    """Every vertex of every body, at many times of its own frame, mapped into each frame (bodies
    moving along an axis, obliquely, near c, and a spinning one): inside its body box there,
    which moves uniformly (plain numpy here: the box's centre at the vertex event's time); the
    boxes of every source frame worked out at once are those of each on its own, to rounding."""
    meshes = [Mesh("oblique", *uv_sphere((1.0, 2.0, 0.5), 0.7, 8, 4), velocity=Velocity((0.5, -0.4, 0.3)), pivot=(1.0, 2.0, 0.5)),
              Mesh("along", *uv_sphere((-3.0, 0.0, 0.0), 1.0, 8, 4), velocity=Velocity((0.9, 0.0, 0.0))),
              Mesh("fast", *uv_sphere((0.0, 4.0, 1.0), 0.5, 8, 4), velocity=Velocity((0.0, 0.6, -0.79))),
              Mesh("spinning", *uv_sphere((0.0, -3.0, 0.0), 0.8, 8, 4), pivot=(0.0, -3.0, 0.0),
                   angular_velocity=(0.0, 0.0, 0.5)),
              Mesh("still", *uv_sphere((4.0, 0.0, 0.0), 0.5, 8, 4))]
    frame_set = build_frames(Scene(camera=grid_scene().camera, meshes=meshes))
    times = np.linspace(-20.0, 20.0, 9)
    sources = list(range(len(frame_set.frames)))
    stacked = frame_set.body_boxes_of(sources)  # every source frame's boxes in one pass
    together = [tuple(a[i] for a in stacked) for i in range(len(sources))]
    each = [frame_set.body_boxes(src) for src in sources]
    for both in zip(together, each):
        for a, b in zip(*both):
            np.testing.assert_allclose(a, b, rtol=1e-14, atol=1e-14)
    for src, (t_box, x_box, velocity, half) in zip(sources + sources, together + each):
        for slot, k in enumerate(frame_set.geometry):
            frame = frame_set.frames[k]
            used = frame.geometry.vertices[np.unique(frame.geometry.triangles)]
            for tau in times:
                local = used if frame.spin is None else used @ frame.pose(np.array([tau]))[0].T
                t, x = frame_set.map(k, src).events(np.full(len(used), tau), local + frame.offset)
                centre = x_box[slot] + np.outer(t - t_box[slot], velocity[slot])
                assert np.all(np.abs(x - centre) <= half[slot] * (1 + 1e-12) + 1e-12), (src, k, tau)


def test_the_clusters_of_small_meshes_worked_out_together_are_each_mesh_own(monkeypatch):
    """Meshes of one size (whose groups are split at once, row by row), of other sizes (odd, too
    few to split, exactly the smallest split) and with ties, in one pass: each mesh's clusters
    are those of the plain computation; and build_frames gives each small frame its own."""
    rng = np.random.default_rng(4)
    meshes = []
    for count in (132, 132, 132, 63, 64, 65, 200, 1001):
        vertices = rng.normal(size=(count, 3)) * rng.uniform(0.2, 3.0, 3)
        if count == 200:
            vertices = np.round(vertices)
        meshes.append((vertices, rng.integers(0, count, size=(count, 3))))
    together = frames._clusters_of(meshes)
    assert len(together) == len(meshes)
    for (vertices, triangles), clusters in zip(meshes, together):
        np.testing.assert_array_equal(clusters, plain_clusters(vertices, triangles))
    passes = []
    clusters_of = frames._clusters_of
    monkeypatch.setattr(frames, "_clusters_of", lambda meshes, *args: passes.append(len(meshes)) or clusters_of(meshes, *args))
    rows = [Mesh(f"row {i}", *uv_sphere((3.0 * i, 0.0, 0.0), 1.0, 12, 6), velocity=Velocity((0.1 * i, 0.0, 0.0)))
            for i in range(5)]
    frame_set = build_frames(Scene(camera=grid_scene().camera, meshes=rows))
    assert passes == [5]
    for k in frame_set.geometry:
        geometry = frame_set.frames[k].geometry
        np.testing.assert_array_equal(geometry.clusters, plain_clusters(geometry.vertices, geometry.triangles))


def test_a_lone_mesh_gets_no_culling_clusters_and_several_frames_do():
    """The tracer culls by clusters only between frames: a scene of one geometry frame skips them."""
    lone = build_frames(grid_scene(shuffled_sphere(), velocity=Velocity((0.3, 0.0, 0.0))))
    assert [frame.geometry.clusters for frame in lone.frames if frame.has_geometry] == [None]
    ball = Mesh("ball", *uv_sphere((5.0, 0.0, 0.0), 1.0, 16, 8), velocity=Velocity((0.0, 0.2, 0.0)))
    pair = build_frames(Scene(camera=grid_scene().camera, meshes=[Mesh("sphere", *shuffled_sphere()), ball]))
    built = [frame.geometry for frame in pair.frames if frame.has_geometry]
    assert len(built) == 2
    for geometry in built:
        np.testing.assert_array_equal(geometry.clusters, plain_clusters(geometry.vertices, geometry.triangles))
        assert not geometry.clusters.flags.writeable


@pytest.mark.parametrize("cones", ["where they pay", "always"])
def test_culling_by_clusters_never_hides_a_hit(monkeypatch, cones):
    """Camera rays through several moving bodies (one in many pieces): the hits with the
    culling (body boxes, and the clusters' cones where they pay or for every frame) are the
    hits without it, and the culling did skip rays."""
    in_pieces(monkeypatch)
    meshes = [Mesh("big", *shuffled_sphere(), velocity=Velocity((0.5, 0.2, 0.0)))]
    for i, beta in enumerate((-0.3, 0.35, 0.1)):
        centre = (2.5 * (i - 1), 1.5, 0.8 * (i - 1))
        meshes.append(Mesh(f"ball {i}", *uv_sphere(centre, 0.6, 24, 12), velocity=Velocity((0.0, 0.0, beta)),
                           pivot=centre))
    scene = Scene(camera=look_at_camera((0.0, -7.0, 0.5), (0.0, 0.0, 0.0)), meshes=meshes)
    frame_set = build_frames(scene)
    assert len(frame_set.geometry) == 4
    px, pz = np.meshgrid(np.linspace(-0.6, 0.6, 200), np.linspace(-0.8, 0.8, 100))  # pixels, row by row
    d = np.column_stack([px.ravel(), np.ones(px.size), pz.ravel()])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    x0 = np.broadcast_to(np.array([0.0, -7.0, 0.5]), d.shape)  # one shared origin, as a camera's
    tau0 = np.broadcast_to(np.array(0.0), (len(d),))
    if cones == "always":
        monkeypatch.setattr(tracer, "_cones_pay", lambda frame_set, src, ks, cache: [True] * len(ks))

    skipped = []

    def counted_cull(frame_set, src, ks, *args):
        kept, culled = cull(frame_set, src, ks, *args)
        skipped.append(len(d) * (len(ks) - len(kept)) + sum(0 if rays is None else len(d) - len(rays)
                                                           for rays in culled))
        return kept, culled

    cull = tracer._cull_bundle
    monkeypatch.setattr(tracer, "_cull_bundle", counted_cull)
    culled = trace_nearest(frame_set, frame_set.camera, tau0, x0, d, 0.05, np.inf)
    assert sum(skipped) > len(d)  # rays were skipped
    monkeypatch.setattr(tracer, "_cull_bundle", lambda frame_set, src, ks, *args: (list(ks), [None] * len(ks)))
    full = trace_nearest(frame_set, frame_set.camera, tau0, x0, d, 0.05, np.inf)
    assert len(np.unique(full.frame)) == 5  # every body is hit, and the background
    for name in ("frame", "prim", "s", "u", "v"):
        np.testing.assert_array_equal(getattr(culled, name), getattr(full, name), err_msg=name)


def test_face_normals_are_the_triangles_unit_normals_and_the_hits_normals():
    """Worked out per hit (not for every triangle at build time): the unit normal of each asked-for
    triangle (plain numpy here, 0 for a degenerate one), and bit for bit the geometric normal the
    tracer gives a hit."""
    vertices, triangles = shuffled_sphere()
    triangles = np.vstack([triangles, [[0, 0, 1]]])  # a degenerate triangle
    geometry = build_frames(grid_scene((vertices, triangles))).frames[0].geometry
    prim = np.array([len(triangles) - 1, 0, 5, 5, 17, len(triangles) - 2])
    corners = vertices[triangles[prim]]
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    length = np.linalg.norm(cross, axis=1, keepdims=True)
    expected = np.where(length > 0, cross / np.where(length > 0, length, 1.0), 0.0)
    normals = geometry.face_normals(prim)
    np.testing.assert_allclose(normals, expected, rtol=0, atol=1e-12)
    assert not normals[0].any()
    frame = build_frames(grid_scene((vertices, triangles))).frames[0]
    _, ng, _ = tracer.hit_geometry(frame, prim, np.full(len(prim), 0.2), np.full(len(prim), 0.3))
    np.testing.assert_array_equal(ng, geometry.face_normals(prim))


@pytest.mark.parametrize("dtype", [np.int32, np.int64])
def test_frames_hit_lists_each_hit_frame_once_in_order(dtype):
    """frames_hit against a plain reference: misses only, one frame (with and without misses), several."""
    rng = np.random.default_rng(5)
    cases = [[], [-1, -1], [3, 3, 3], [-1, 3, -1, 3], [0, -1], [2, 0, -1, 5, 2], rng.integers(-1, 7, 500)]
    for frame in cases:
        frame = np.asarray(frame, dtype=dtype)
        n = len(frame)
        hits = Hits(frame, np.zeros(n), np.zeros(n), np.ones(n), np.zeros(n, dtype=np.int32), np.zeros(n),
                    np.zeros(n), np.zeros((n, 3)), np.zeros(n))
        assert frames_hit(hits).tolist() == sorted({int(k) for k in frame if k >= 0})


def test_hit_geometry_from_a_threads_triangle_rows_is_bit_for_bit_the_per_hit_geometry():
    """A render thread's cache keeps each small mesh's triangle rows (first corner, edges, unit
    normal) for one gather per hit: the same bits as working them out for the hits, for flat and
    smooth meshes, the hits' arrays still the caller's own to turn."""
    vertices, triangles = shuffled_sphere()
    rng = np.random.default_rng(3)
    prim = rng.integers(0, len(triangles), 5000)
    u = rng.random(len(prim), dtype=np.float32) * 0.5
    v = rng.random(len(prim), dtype=np.float32) * 0.5
    smooth = vertices[triangles] - SPHERE_CENTRE
    for options in ({}, {"corner_normals": smooth / np.linalg.norm(smooth, axis=2, keepdims=True)}):
        frame = build_frames(grid_scene((vertices, triangles), **options)).frames[0]
        cache = tracer.TraceCache()
        per_hit = tracer.hit_geometry(frame, prim, u, v)
        if options:  # the corners' normals weighted as rows (the products and sums, axis by axis)
            cn, wu, wv = frame.geometry.corner_normals[prim], u.astype(np.float64), v.astype(np.float64)
            weighted = rows.add_scaled(rows.add_scaled(rows.scale(cn[:, 0], 1.0 - wu - wv), wu, cn[:, 1]), wv, cn[:, 2])
            np.testing.assert_array_equal(per_hit[2], rows.normalized(weighted))
        for _ in range(2):  # the rows made, then kept
            kept = tracer.hit_geometry(frame, prim, u, v, cache=cache)
            for a, b in zip(per_hit, kept):
                np.testing.assert_array_equal(a, b)
            kept[1][:] = 0.0  # the caller's own arrays: the kept rows are not touched
        assert len(cache._hit_tables) == 1


def test_a_flat_meshs_hits_share_its_one_normal_as_a_broadcast_row_turned_as_the_per_hit_normals():
    """A thread's cache finds that a flat mesh's triangles have one normal: its hits get it as one
    read-only broadcast row (the same bits as the per-hit normals), which stays one row when the
    hits are all in front or all behind and becomes the per-hit turned rows when they are on both
    sides; a curved mesh's normals stay per hit."""
    from restframe_addon.core import passes

    vertices, triangles = grid()
    rng = np.random.default_rng(4)
    prim = rng.integers(0, len(triangles), 3000)
    u, v = (rng.random(len(prim), dtype=np.float32) * 0.5 for _ in range(2))
    frame = build_frames(grid_scene((vertices, triangles))).frames[0]
    per_hit = tracer.hit_geometry(frame, prim, u, v)
    kept = tracer.hit_geometry(frame, prim, u, v, cache=tracer.TraceCache())
    assert rows.is_broadcast(kept[1]) and kept[2] is kept[1] and not per_hit[1].strides[0] == 0
    for a, b in zip(per_hit, kept):
        np.testing.assert_array_equal(a, b)
    d = rng.normal(size=(len(prim), 3))
    for sides in (-np.abs(d[:, 2:]), np.abs(d[:, 2:]), d[:, 2:]):  # front, back, both
        d_k = np.hstack([d[:, :2], sides])
        expected = passes._turned_to_viewer(per_hit[1].copy(), per_hit[1].copy(), d_k)
        turned = passes._turned_to_viewer(kept[1], kept[1], d_k)
        assert turned[1] is turned[0] and rows.is_broadcast(turned[0]) == (len(np.unique(turned[2])) == 1)
        for a, b in zip(expected[:3], turned[:3]):
            np.testing.assert_array_equal(a, b)
        # the cosines with the view, from the turn's dot products: those the shader would make itself
        assert (turned[3] is None) == (not rows.is_broadcast(turned[0]))
        flat = per_hit[1].copy()  # per-hit flat normals (ns is ng): the cosines |ng . d_k|
        flat_turned = passes._turned_to_viewer(flat, flat, d_k)
        assert flat_turned[3] is not None
        for normals, cos_view in ((expected[1], expected[3]), (turned[1], turned[3]), flat_turned[1::2]):
            if cos_view is not None:
                np.testing.assert_array_equal(cos_view, rows.dot(normals, -d_k))
    # smooth shading normals: the cosines of the turned ones, those turned away replaced by ng's
    ns = rows.normalized(per_hit[1] + rng.normal(scale=0.6, size=(len(prim), 3)))
    ng_turned, ns_turned, back, cos_view = passes._turned_to_viewer(per_hit[1].copy(), ns, d_k)
    assert back.any() and not back.all() and (ns_turned == ng_turned).all(axis=1).any()
    np.testing.assert_array_equal(cos_view, rows.dot(ns_turned, -d_k))
    sphere = build_frames(grid_scene(shuffled_sphere())).frames[0]
    assert not rows.is_broadcast(tracer.hit_geometry(sphere, prim % 50, u, v, cache=tracer.TraceCache())[1])


def test_hit_uvs_from_a_threads_uv_tables_are_bit_for_bit_the_per_hit_uvs():
    """A thread's cache keeps a small mesh's corner UVs as 1-D tables (one gather per corner and
    component into contiguous columns): the same bits as interpolating the gathered corner rows,
    for float32 (the tracer's) and float64 barycentrics; one table per mesh, made once."""
    from restframe_addon.core.shading import hit_uv

    vertices, triangles = shuffled_sphere()
    rng = np.random.default_rng(6)
    corner_uvs = rng.random((len(triangles), 3, 2)) * 3.0 - 1.0
    frame = build_frames(grid_scene((vertices, triangles), corner_uvs=corner_uvs)).frames[0]
    prim = rng.integers(0, len(triangles), 4000).astype(np.int32)
    cache = tracer.TraceCache()
    for dtype in (np.float32, np.float64):
        u, v = (rng.random(len(prim)).astype(dtype) * 0.5 for _ in range(2))
        kept = hit_uv(frame, prim, u, v, cache)
        np.testing.assert_array_equal(kept, hit_uv(frame, prim, u, v))
        assert kept.dtype == np.float64 and kept[:, 0].flags.c_contiguous
    assert len(cache._uv_tables) == 1
    assert hit_uv(build_frames(grid_scene((vertices, triangles))).frames[0], prim, u, v, cache) is None


def test_a_uv_table_every_triangle_shares_is_one_number_with_the_same_bits():
    """A small mesh's corner whose U (or V) every triangle shares (a quad's: two triangles from one
    corner) is kept as that number, multiplied in without a gather: the same bits as the gathered
    corner rows (a corner of 0 too, whose products are signed zeros; 0.0 and -0.0 are not one number)."""
    from restframe_addon.core.shading import hit_uv

    vertices, triangles = shuffled_sphere()
    rng = np.random.default_rng(7)
    corner_uvs = rng.random((len(triangles), 3, 2)) * 3.0 - 1.0
    corner_uvs[:, 0] = (0.0, 0.75)  # both components of the first corner shared
    corner_uvs[:, 2, 1] = -1.25  # the last corner's V shared
    corner_uvs[:, 1, 1] = np.where(np.arange(len(triangles)) % 2, 0.0, -0.0)  # equal, not the same bits
    frame = build_frames(grid_scene((vertices, triangles), corner_uvs=corner_uvs)).frames[0]
    cache = tracer.TraceCache()
    prim = rng.integers(0, len(triangles), 4000).astype(np.int32)
    u, v = (rng.random(len(prim)).astype(np.float32) * 0.5 for _ in range(2))
    kept = hit_uv(frame, prim, u, v, cache)
    shared = [[isinstance(table, float) for table in component] for component in cache.uv_table(frame.geometry)]
    assert shared == [[True, False, False], [True, False, True]]
    assert kept.tobytes() == np.ascontiguousarray(hit_uv(frame, prim, u, v)).tobytes()


def test_padded_vertices_are_the_float64_offsets_rounded_once_in_embrees_layout():
    vertices = np.random.default_rng(3).normal(size=(1001, 3)) * 1e3
    anchor = np.array([0.1, -2.5, 7.0])
    padded = embree_direct.padded_vertices(vertices, anchor)
    assert padded.dtype == np.float32 and padded.shape == (1001, 4) and padded.flags.c_contiguous
    np.testing.assert_array_equal(padded[:, :3], (vertices - anchor).astype(np.float32))
    assert not padded[:, 3].any()
    assert embree_direct._padded(padded) is padded  # laid out already: not copied again


@pytest.mark.parametrize("dtype", [np.int32, np.int64])
def test_a_lone_meshs_arrays_are_copied_once_and_never_shared_with_the_scene(monkeypatch, dtype):
    """A body of one mesh keeps the per-triangle arrays its build made (no second copy: the
    object numbers, the clocks, triangles converted to int64), and copies those that are still
    the scene's (int64 triangles, int32 material numbers): changing the scene later changes no
    geometry."""
    v, t = uv_sphere((0.0, 0.0, 0.0), 1.0, 8, 4)
    triangles, materials = t.astype(dtype), np.zeros(len(t), dtype=np.int32)
    scene = Scene(camera=look_at_camera((0, -4, 0), (0, 0, 0)),
                  meshes=[Mesh("ball", v, triangles, material_indices=materials, velocity=Velocity((0.5, 0, 0)))])
    parts = []
    made = frames._mesh_part
    monkeypatch.setattr(frames, "_mesh_part", lambda *args, **kwargs: parts.append(made(*args, **kwargs)) or parts[-1])
    geometry = build_frames(scene).frames[-1].geometry
    (part,) = parts
    assert geometry.tri_object_index is part["object_index"] and geometry.tri_clock is part["clock"]
    assert np.shares_memory(geometry.triangles, part["triangles"]) == (dtype == np.int32)
    assert not np.shares_memory(geometry.triangles, triangles) and not np.shares_memory(geometry.tri_material, materials)
    np.testing.assert_array_equal(geometry.triangles, t)
    triangles[:] = 0
    materials[:] = 1
    np.testing.assert_array_equal(geometry.triangles, t)
    assert not geometry.tri_material.any()


def test_a_bodys_clock_at_hits_is_the_same_with_one_clock_for_all_triangles_as_gathered():
    """A lone mesh's triangles share one clock (``Geometry.clock``): the object clock at hits is
    the same bits as the gather from the per-triangle clocks; several meshes in a frame gather."""
    v, t = uv_sphere((0.0, 0.0, 0.0), 1.0, 8, 4)
    camera = look_at_camera((0, -4, 0), (0, 0, 0))
    lone = build_frames(Scene(camera=camera, meshes=[Mesh("ball", v, t, velocity=Velocity((0.5, 0.2, 0)),
                                                          pivot=(0.3, -0.2, 0.1))])).frames[-1]
    assert lone.geometry.clock is not None and np.all(lone.geometry.tri_clock == lone.geometry.clock)
    rng = np.random.default_rng(5)
    prim, tau = rng.integers(0, len(t), 100), rng.normal(size=100)
    gathered = tau + lone.clock_offset + lone.geometry.tri_clock[prim]
    assert lone.object_clock(tau, prim).tobytes() == gathered.tobytes()
    two = build_frames(Scene(camera=camera, meshes=[Mesh("a", v, t), Mesh("b", v + 3.0, t)])).frames[-1]
    assert two.geometry.clock is None


def test_precision_warnings_name_each_part_rounded_badly_about_the_frames_anchor():
    """Each part's bounds come from the frame's joined vertices at once: the warning names the parts,
    and only those, whose float32 rounding about the anchor exceeds 1e-3 of their size (a small card
    far out between two near objects), with the worst rounding, as a part-by-part reference finds."""
    rng = np.random.default_rng(7)
    parts = [{"vertices": 5.0 * rng.normal(size=(30, 3))},
             {"vertices": (2e3, -1e3, 4e2) + 1e-3 * rng.normal(size=(4, 3))},  # the small card, far out
             {"vertices": 1.0 + rng.normal(size=(12, 3))},
             {"vertices": (-3e2, 0.0, 0.0) + 1e-3 * rng.normal(size=(6, 3))}]
    names = ["near", "card", "ball", "pebble"]
    geometry = type("Frame", (), {"vertices": np.concatenate([p["vertices"] for p in parts]),
                                  "anchor": np.zeros(3), "extent": 5e3})()
    reference = {}
    for name, part in zip(names, parts):
        lo, hi = part["vertices"].min(axis=0), part["vertices"].max(axis=0)
        rounding = np.abs(np.concatenate([lo, hi])).max() * 2.0**-24
        if rounding > 1e-3 * (hi - lo).max():
            reference[name] = rounding
    assert sorted(reference) == ["card", "pebble"]
    warnings = frames._precision_warnings(names, parts, geometry)
    assert len(warnings) == 1 and warnings[0].startswith("card, pebble: too far from the other objects")
    assert f"rounded by up to {max(reference.values()):.2g} scene units" in warnings[0]
    near = [parts[0], parts[2]]
    geometry.vertices = np.concatenate([p["vertices"] for p in near])
    assert frames._precision_warnings(["near", "ball"], near, geometry) == []

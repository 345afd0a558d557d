"""Small analytic test scenes built without Blender."""

import numpy as np

from restframe_addon.core.scene import Camera, Light, Material, Mesh, RenderSettings, Scene, Velocity


def uv_sphere(center=(0.0, 0.0, 0.0), radius=1.0, segments=64, rings=32):
    """A closed UV sphere: (vertices, triangles)."""
    theta = np.linspace(0.0, np.pi, rings + 1)
    phi = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
    t, p = np.meshgrid(theta[1:-1], phi, indexing="ij")
    body = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    vertices = np.concatenate([[[0, 0, 1]], body, [[0, 0, -1]]]) * radius + np.asarray(center)
    ring = lambda i: 1 + i * segments + np.arange(segments)
    nxt = lambda a: np.roll(a, -1)
    tris = [np.stack([np.zeros(segments, int), ring(0), nxt(ring(0))], 1)]
    for i in range(rings - 2):
        a, b = ring(i), ring(i + 1)
        tris += [np.stack([a, b, nxt(b)], 1), np.stack([a, nxt(b), nxt(a)], 1)]
    last = len(vertices) - 1
    tris.append(np.stack([np.full(segments, last), nxt(ring(rings - 2)), ring(rings - 2)], 1))
    return vertices, np.concatenate(tris)


def quad(center=(0.0, 0.0, 0.0), size=(1.0, 1.0), normal_axis=2):
    """An axis-aligned rectangle facing +axis: (vertices, triangles)."""
    a, b = [i for i in range(3) if i != normal_axis]
    v = np.zeros((4, 3))
    v[:, a] = np.array([-1, 1, 1, -1]) * size[0] / 2
    v[:, b] = np.array([-1, -1, 1, 1]) * size[1] / 2
    v += np.asarray(center, dtype=float)
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def box(center=(0.0, 0.0, 0.0), size=(1.0, 1.0, 1.0)):
    """An axis-aligned box: (vertices, triangles), outward winding."""
    c = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
    v = c * np.asarray(size) + np.asarray(center, dtype=float)
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    t = [[f[0], f[1], f[2]] for f in faces] + [[f[0], f[2], f[3]] for f in faces]
    return v, np.array(t)


def look_at_camera(position, target, up=(0.0, 0.0, 1.0), fov_half_tan=0.5, aspect=1.0, velocity=Velocity()):
    """A perspective camera at ``position`` looking at ``target`` (Blender camera axes)."""
    position, target = np.asarray(position, float), np.asarray(target, float)
    forward = target - position
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, up)
    if np.linalg.norm(right) < 1e-9:
        right = np.cross(forward, (0.0, 1.0, 0.0))
    right /= np.linalg.norm(right)
    cam_up = np.cross(right, forward)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, cam_up, -forward, position
    x, y = fov_half_tan, fov_half_tan / aspect
    frame = np.array([[x, y, -1.0], [x, -y, -1.0], [-x, -y, -1.0], [-x, y, -1.0]])
    return Camera(matrix=m, frame=frame, clip_start=1e-3, clip_end=1e9, velocity=velocity)

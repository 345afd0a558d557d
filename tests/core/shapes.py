"""Small analytic test scenes built without Blender."""

import math
from dataclasses import dataclass

import numpy as np

from restframe_addon.core.scene import Camera, Velocity


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


@dataclass
class HyperbolicBall:
    """A Born-rigid ball (rest radius ``radius``) whose centre turns around at world time 0 with
    uniform proper acceleration 1/alpha along x: ``x = x0 - alpha + sqrt(alpha^2 + t^2)``, at
    (y0, z0); beyond |t| > t_end it moves on inertially along its tangent.

    Exact, without inertial segments, as a reference for the tracer: every simultaneity slice of
    the centre passes through the event (t = 0, x = x0 - alpha), so an event's slice, and its
    offset from the centre in the centre's rest frame there, are closed form.
    """

    alpha: float
    radius: float
    x0: float = 0.0
    y0: float = 0.0
    z0: float = 0.0
    t_end: float = np.inf

    def centre(self, t):
        """Centre positions (n, 3) at world times t (n,)."""
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        edge = np.clip(t, -self.t_end, self.t_end)
        x = self.x0 - self.alpha + np.sqrt(self.alpha**2 + edge**2) + self.velocity(edge) * (t - edge)
        return np.column_stack([x, np.full_like(t, self.y0), np.full_like(t, self.z0)])

    def velocity(self, t):
        """The centre's velocity (along x) at world times t."""
        edge = np.clip(np.asarray(t, dtype=np.float64), -self.t_end, self.t_end)
        return edge / np.sqrt(self.alpha**2 + edge**2)

    def rest_offset(self, t, x):
        """Offsets (n, 3) of events from the centre, in its rest frame on the events' slices."""
        t, x = np.atleast_1d(np.asarray(t, dtype=np.float64)), np.atleast_2d(np.asarray(x, dtype=np.float64))
        out = x - [0.0, self.y0, self.z0]
        from_apex = x[:, 0] - (self.x0 - self.alpha)
        with np.errstate(invalid="ignore"):  # outside the wedge |t| < x - apex: far from the ball
            out[:, 0] = np.sqrt(from_apex**2 - t**2) - self.alpha
        out[~np.isfinite(out[:, 0]), 0] = np.inf
        if np.isfinite(self.t_end):
            for edge in (-self.t_end, self.t_end):  # beyond the end slices: the inertial rest frame
                (centre,), beta = self.centre(edge), float(self.velocity(edge))
                beyond = np.sign(edge) * ((t - edge) - beta * (x[:, 0] - centre[0])) > 0
                gamma = 1.0 / math.sqrt(1.0 - beta * beta)
                out[beyond, 0] = gamma * ((x[beyond, 0] - centre[0]) - beta * (t[beyond] - edge))
        return out

    def margin(self, t, x):
        """How far events lie outside the ball, in its rest frame (negative inside)."""
        return np.linalg.norm(self.rest_offset(t, x), axis=1) - self.radius

    def surface_event(self, t_centre, normal):
        """World time (n,) and position (n, 3) of the body points ``radius * normal`` (rest frame;
        on the surface for unit normals) on the slices of the centre's world times t_centre."""
        t_centre, normal = np.atleast_1d(t_centre), np.atleast_2d(normal)
        beta = self.velocity(t_centre)
        gamma = 1.0 / np.sqrt(1.0 - beta * beta)
        offset = self.radius * normal
        offset[:, 0] *= gamma  # the boost back from the centre's rest frame
        return t_centre + beta * offset[:, 0], self.centre(t_centre) + offset

    def deepest(self, tau0, x0, d, s_lo, s_hi, step=1e-3):
        """Smallest margin along each backward ray ``(tau0 - s, x0 + s d)``, s in [s_lo, s_hi], sampled
        every ``step`` where the ray is within ``radius`` of the centre line (the ball never leaves
        that cylinder: it moves along x); inf where it never is."""
        n = len(d)
        s_lo, s_hi = np.broadcast_to(s_lo, (n,)), np.broadcast_to(s_hi, (n,))
        out = np.full(n, np.inf)
        for i in range(n):
            p, q = x0[i, 1:] - (self.y0, self.z0), d[i, 1:]
            a, b, c = q @ q, p @ q, p @ p - self.radius**2
            if a == 0.0:  # along x: inside the cylinder throughout, or never
                lo, hi = (s_lo[i], s_hi[i]) if c <= 0.0 else (np.inf, -np.inf)
            elif b * b - a * c >= 0.0:
                root = math.sqrt(b * b - a * c)
                lo, hi = max(s_lo[i], (-b - root) / a), min(s_hi[i], (-b + root) / a)
            else:
                continue
            if lo > hi:
                continue
            s = np.append(np.arange(lo, hi, step), hi)
            out[i] = self.margin(tau0[i] - s, x0[i] + s[:, None] * d[i]).min()
        return out


def rotation_x(angle):
    """The rotation by ``angle`` (radians) about +X (a lamp's matrix: its -Z axis tilted towards +Y)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])

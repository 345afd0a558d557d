"""Emissive triangles as lights: choosing one by its power, a point on it, and its densities.

An :class:`EmitterTable` holds the emissive triangles of one rest frame (an emitter is
static there, so its retarded position is its position).  It draws a triangle with
probability proportional to area x emission luminance and a point uniformly on it:
the density per unit area is then ``luminance / sum(area x luminance)`` on every
triangle.  :func:`solid_angle_pdf` turns it into a density per unit solid angle seen
from a point of the same frame; :func:`~.world.frame_pdf` carries that into another
frame (``p_k = p_j D^2``, D = nu_k / nu_j).
"""

from __future__ import annotations

import numpy as np

from . import rows
from .shading import _POINT_INTENSITY_PER_WATT, _cone_sample, _orthonormal_basis, _spot_falloff
from .world import LUMINANCE_RGB


class EmitterTable:
    """The emissive triangles of one frame.

    ``vertices`` (m, 3, 3): the corners of each triangle in its rest frame;
    ``emission`` (m, 3): emitted radiance (RGB, strength included);
    ``prims`` (m,): each triangle's index in its frame's geometry, handed back by :meth:`sample`.
    Triangles with no area or no luminance are never drawn.
    """

    def __init__(self, vertices, emission, prims=None):
        vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3, 3)
        emission = np.asarray(emission, dtype=np.float64).reshape(-1, 3)
        if len(emission) != len(vertices):
            raise ValueError(f"EmitterTable: {len(vertices)} triangles but {len(emission)} emissions")
        self.origin = vertices[:, 0]
        self.edge1 = vertices[:, 1] - vertices[:, 0]
        self.edge2 = vertices[:, 2] - vertices[:, 0]
        normal = rows.cross(self.edge1, self.edge2)
        self.area = 0.5 * rows.norm(normal)
        self.normal = rows.normalized(normal)
        self.emission = emission
        self.prims = np.arange(len(vertices)) if prims is None else np.asarray(prims, dtype=np.int64)
        weight = self.area * np.maximum(emission @ LUMINANCE_RGB, 0.0)
        self.total = float(weight.sum())
        self.is_empty = not self.total > 0.0
        self._weight = weight
        self._cdf = np.cumsum(weight) / self.total if not self.is_empty else np.zeros(len(weight))
        if len(self._cdf) and not self.is_empty:
            self._cdf[-1] = 1.0

    @property
    def probability(self) -> np.ndarray:
        """Probability of drawing each triangle (m,)."""
        return self._weight / self.total if not self.is_empty else np.zeros(len(self._weight))

    def pdf_area(self, index):
        """Density per unit area of points drawn on triangles ``index`` (table rows)."""
        if self.is_empty:
            return np.zeros(len(index))
        return np.where(self.area[index] > 0.0, self._weight[index] / self.total / np.maximum(self.area[index], 1e-300),
                        0.0)

    def sample(self, u_choice, u1, u2):
        """Points on the emitters: (index (n,) table rows, point (n, 3), normal (n, 3), pdf per area (n,)).

        ``u_choice`` picks the triangle (searching the power CDF); (u1, u2) a uniform point on
        it (the square-root map of the unit square onto the triangle).  Use ``prims[index]``
        for the geometry's triangle, ``emission[index]`` for its radiance.
        """
        if self.is_empty:
            raise ValueError("EmitterTable: no emissive triangle to sample (check is_empty first)")
        index = np.minimum(np.searchsorted(self._cdf, u_choice, side="right"), len(self._cdf) - 1)
        root = np.sqrt(u1)
        b1 = root * (1.0 - u2)  # barycentric weights of the second and third corners
        b2 = root * u2
        point = rows.add_scaled(rows.add_scaled(self.origin[index], b1, self.edge1[index]), b2, self.edge2[index])
        return index, point, self.normal[index], self.pdf_area(index)


def solid_angle_pdf(pdf_area, origin, point, normal):
    """A density per unit area on an emitter as a density per unit solid angle seen from origin.

    Returns (direction (n, 3) from origin to point, distance (n,), pdf (n,)):
    ``pdf = pdf_area r^2 / |cos(normal, direction)|`` (0 for points seen edge-on).  All in one frame.
    """
    delta = point - origin
    distance = rows.norm(delta)
    direction = rows.scale(delta, 1.0 / np.maximum(distance, 1e-300))
    cos_emitter = np.abs(rows.dot(normal, direction))
    pdf = np.where(cos_emitter > 0.0, pdf_area * distance**2 / np.maximum(cos_emitter, 1e-300), 0.0)
    return direction, distance, pdf


class LampShape:
    """The emitting shape of a lamp with an extent, in its rest frame, as the path tracer both
    samples it (next-event estimation) and finds it with bounce rays (as Cycles: visible to
    camera and bounce rays, weighed by multiple importance sampling):

    * a point or spot lamp with a radius R is a sphere of uniform radiance ``I / (pi R^2)``
      (intensity ``I = P / (4 pi)`` per watt, times the spot's falloff), drawn uniformly in the
      cone of directions it fills;
    * an area lamp is a one-sided rectangle or ellipse of radiance ``P / (pi A)`` emitting along its
      -Z, drawn uniformly by area;
    * a sun with an angle is a disc of directions of radiance ``S / Omega`` (``Omega`` its solid
      angle) of the power :func:`~.shading.prepare_lights` gives it, ``S / (pi sin^2 h)`` of
      Blender's strength ``S`` (Cycles'), drawn uniformly in it.

    All per unit of the lamp's colour x power, in the lamp's frame, where the lamp is static;
    ``centre`` (n, 3) is its position there as seen from each point ``x`` (a keyed lamp's
    momentary rest frame differs per point).  :meth:`hit` is the single place of each shape's
    radiance and density: the samples of :meth:`sample` are evaluated by it too.
    """

    def __init__(self, light, axes):
        self.kind = light.kind
        self.axes = np.asarray(axes, dtype=np.float64)
        self.use_mis = bool(light.use_mis)
        self.visibility = int(light.visibility)
        self.is_sun = light.kind == "SUN"
        if self.is_sun:
            half = 0.5 * light.sun_angle
            self.cos_half = np.cos(half)
            self.solid_angle = 2.0 * np.pi * (2.0 * np.sin(0.5 * half) ** 2)  # 2 pi (1 - cos half)
        elif light.kind == "AREA":
            self.size = np.asarray(light.area_size, dtype=np.float64)
            self.elliptic = light.area_shape in ("DISK", "ELLIPSE")
            self.area = float(self.size[0] * self.size[1] * (np.pi / 4.0 if self.elliptic else 1.0))
        else:
            self.radius = float(light.radius)
            self.radiance_per_watt = _POINT_INTENSITY_PER_WATT / (np.pi * self.radius**2)
            self.spot = (light.spot_size, light.spot_blend) if light.kind == "SPOT" else None

    @staticmethod
    def of(light, axes):
        """The shape of a lamp, or None for a delta lamp (a point without radius, a sharp sun)."""
        if light.kind == "SUN":
            return LampShape(light, axes) if light.sun_angle > 0.0 else None
        if light.kind == "AREA":
            return LampShape(light, axes) if light.area_size[0] * light.area_size[1] > 0.0 else None
        return LampShape(light, axes) if light.radius > 0.0 else None

    def sample(self, centre, x, u1, u2):
        """Unit directions (n, 3) from points x toward the lamp, drawn with :meth:`hit`'s density."""
        x_axis, y_axis, z_axis = self.axes[:, 0], self.axes[:, 1], self.axes[:, 2]
        if self.is_sun:
            return _cone_sample(z_axis, np.arccos(self.cos_half), u1, u2)
        if self.kind == "AREA":
            if self.elliptic:
                radius, angle = np.sqrt(u1), 2.0 * np.pi * u2
                a, b = 0.5 * radius * np.cos(angle), 0.5 * radius * np.sin(angle)
            else:
                a, b = u1 - 0.5, u2 - 0.5
            point = rows.add_scaled(rows.add_scaled(centre, a * self.size[0], x_axis), b * self.size[1], y_axis)
            return rows.normalized(point - x)
        delta = centre - x
        distance2 = np.maximum(rows.dot(delta, delta), 1e-300)
        axes = rows.scale(delta, 1.0 / np.sqrt(distance2))
        sin2 = np.minimum(self.radius**2 / distance2, 1.0)
        one_minus_cos = sin2 / (1.0 + np.sqrt(1.0 - sin2))  # of the cone the sphere fills
        t1, t2 = _orthonormal_basis(axes)
        cos_t = 1.0 - u1 * one_minus_cos
        sin_t = np.sqrt(np.maximum(1.0 - cos_t * cos_t, 0.0))
        phi = 2.0 * np.pi * u2
        out = rows.scale(t1, sin_t * np.cos(phi))  # (t1 sin cos phi + t2 sin sin phi) + axis cos, in place
        out += rows.scale(t2, sin_t * np.sin(phi))
        out += rows.scale(axes, cos_t)
        return out

    def hit(self, centre, x, d):
        """Where rays from x along unit d (n, 3) meet the lamp: (path length (n,), inf for the sun
        or a miss; density per unit solid angle with which :meth:`sample` draws d, 0 for a miss;
        radiance per unit of colour x power (n,), 0 for a miss).  Rays from inside a sphere
        lamp, or onto an area lamp's back, miss it."""
        n = len(d)
        length, pdf, radiance = np.full(n, np.inf), np.zeros(n), np.zeros(n)
        z_axis = self.axes[:, 2]
        if self.is_sun:
            inside = d @ z_axis >= self.cos_half
            pdf[inside] = radiance[inside] = 1.0 / self.solid_angle
            return length, pdf, radiance
        if self.kind == "AREA":
            toward = d @ z_axis  # > 0: the ray meets the emitting (-Z) face
            offset = centre - x
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (offset @ z_axis) / toward
            ok = (toward > 0.0) & (t > 0.0)
            local = rows.add_scaled(-offset, np.where(ok, t, 0.0), d)  # hit point - centre
            a = (local @ self.axes[:, 0]) / self.size[0]
            b = (local @ self.axes[:, 1]) / self.size[1]
            ok &= (a * a + b * b <= 0.25) if self.elliptic else (np.abs(a) <= 0.5) & (np.abs(b) <= 0.5)
            length[ok] = t[ok]
            pdf[ok] = t[ok] ** 2 / (self.area * toward[ok])
            radiance[ok] = 1.0 / (np.pi * self.area)
            return length, pdf, radiance
        offset = centre - x
        distance2 = rows.dot(offset, offset)
        along = rows.dot(offset, d)
        radius2 = self.radius**2
        across2 = np.maximum(distance2 - along * along, 0.0)
        ok = (distance2 > radius2) & (along > 0.0) & (across2 <= radius2)
        length[ok] = along[ok] - np.sqrt(radius2 - across2[ok])
        sin2 = radius2 / distance2[ok]
        one_minus_cos = sin2 / (1.0 + np.sqrt(1.0 - sin2))  # of the cone the sphere fills
        pdf[ok] = 1.0 / (2.0 * np.pi * one_minus_cos)
        radiance[ok] = self.radiance_per_watt
        if self.spot is not None:
            radiance[ok] *= _spot_falloff(d[ok] @ z_axis, *self.spot)
        return length, pdf, radiance

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

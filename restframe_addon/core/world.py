"""The world as a light source at rest in the world frame S, and its sampling from moving frames.

A world is looked up, and sampled, by *backward* ray directions ``d`` of S: the direction
a ray leaving a surface travels to reach the sky, so ``radiance(d)`` is the light that
arrives from there.  Two kinds, with one interface (``radiance``, ``sample``, ``pdf``,
``is_black``):

* :class:`UniformWorld` -- the Background node's colour x strength.
* :class:`EnvironmentWorld` -- an equirectangular image (Environment Texture) x strength,
  rotated by a Mapping node, importance-sampled by a piecewise-constant density over
  cells whose radiance it bounds (a bright sun gives no fireflies).

Blender's equirectangular convention (Cycles' ``direction_to_equirectangular``), for a
direction t in texture space: ``u = 1/2 - atan2(t_y, t_x) / (2 pi)``, ``v = 1/2 +
asin(t_z) / pi``; +X is the image centre, +Z the top (v = 1).  Images are (H, W, C)
float arrays with row 0 at v = 0 (the bottom, as Blender stores pixels).

Moving receivers: a surface at rest in S' sees the world aberrated.  With ``D = nu_S' /
nu_S`` the Doppler factor of the light between the frames, radiance is ``L D^4``
(frequency-integrated) and solid angles map as ``dOmega_S / dOmega_S' = D^2``, so a
direction drawn in S with density p_S has density ``p_S D^2`` in S'
(``docs/physics-world.md`` derives both).  Frame maps are anything with ``rays(d) ->
(d', w)`` (:class:`~.lorentz.Boost`, :class:`~.frames.FrameMap`): ``w = s'/s``.
"""

from __future__ import annotations

import numpy as np

from . import mis, rows
from .bsdf import sample_diffuse

LUMINANCE_RGB = np.array([0.2126, 0.7152, 0.0722])  # Rec. 709, Blender's scene-linear default
INTERPOLATIONS = ("Linear", "Closest")
_IDENTITY = np.eye(3)
_FOUR_PI = 4.0 * np.pi
_MAP_COLUMNS = 1024  # least columns of a Linear environment's sampling map (Cycles' default map is 1024 wide)


# ---------------------------------------------------------------------------- mapping
def euler_rotation(euler) -> np.ndarray:
    """Blender's XYZ Euler rotation (radians) as a 3x3 matrix: R = Rz Ry Rx."""
    rx, ry, rz = (float(a) for a in euler)
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    return np.array([
        [cy * cz, sy * sx * cz - cx * sz, sy * cx * cz + sx * sz],
        [cy * sz, sy * sx * sz + cx * cz, sy * cx * sz - sx * cz],
        [-sy, cy * sx, cy * cx],
    ])


def mapping_rotation(euler, vector_type: str = "POINT") -> np.ndarray:
    """The matrix M taking a world direction to the texture direction looked up, for a Mapping
    node with this rotation (no location or scale): R for Point / Vector / Normal, R^T for Texture."""
    rotation = euler_rotation(euler)
    if vector_type == "TEXTURE":
        return rotation.T
    if vector_type in ("POINT", "VECTOR", "NORMAL"):
        return rotation
    raise ValueError(f"Mapping node: vector type {vector_type!r} is not one of POINT, TEXTURE, VECTOR, NORMAL")


def direction_to_equirectangular(t):
    """Image coordinates (u, v) in [0, 1) x [0, 1] of unit texture-space directions t (n, 3)."""
    u = 0.5 - np.arctan2(t[:, 1], t[:, 0]) / (2.0 * np.pi)
    v = 0.5 + np.arcsin(np.clip(t[:, 2], -1.0, 1.0)) / np.pi
    return u % 1.0, v


def equirectangular_to_direction(u, v):
    """Unit texture-space directions (n, 3) of image coordinates (u, v)."""
    phi = np.pi * (1.0 - 2.0 * u)
    z = -np.cos(np.pi * v)
    return _polar(z, phi)


def _polar(z, phi):
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    out = np.empty((len(z), 3))
    out[:, 0] = r * np.cos(phi)
    out[:, 1] = r * np.sin(phi)
    out[:, 2] = z
    return out


def image_lookup(texels: Texels, u, v, interpolation: str = "Linear", channels: int | None = None,
                 columns: bool = False):
    """Colours (n, C) of an (H, W, C) image, laid out once as its :class:`Texels`, at (u, v),
    repeating in both directions as Cycles' environment lookups: bilinear between pixel centres,
    or the nearest pixel (Closest); ``channels``: only the first so many; ``columns``: into an
    array whose columns are contiguous (written 2.5x faster, for more work column by column).
    Gathers whole pixels (np.take of rows) and blends one channel at a time (see :mod:`.rows`), in
    place: a fresh temporary of every step costs more than the step (page faults)."""
    h, w, pixels = texels.height, texels.width, texels.pixels
    stride = w + 1
    channels = texels.channels if channels is None else min(channels, texels.channels)
    out = np.empty((channels, len(u)) if columns else (len(u), channels), np.result_type(pixels, np.float64))
    out = out.T if columns else out
    if interpolation == "Closest":
        index = _wrap(np.floor(v * h).astype(np.int64), h) * stride + _wrap(np.floor(u * w).astype(np.int64), w)
        found = np.take(pixels, index, axis=0, mode="clip")
        for c in range(channels):
            out[:, c] = found[:, c]
            if texels.scale != 1.0:
                out[:, c] *= texels.scale
        return out
    fx, fy = u * w, v * h
    fx -= 0.5
    fy -= 0.5
    x0, y0 = np.floor(fx), np.floor(fy)
    fx -= x0  # the fractions from the pixel centre below
    fy -= y0
    if texels.colour:
        fx, fy = fx.astype(pixels.dtype, copy=False), fy.astype(pixels.dtype, copy=False)
    corner = _wrap(y0.astype(np.int64), h)
    corner *= stride
    corner += _wrap(x0.astype(np.int64), w)
    # the pixels at (x0, y0), (x1, y0), (x0, y1), (x1, y1): one index into four views
    views = (pixels, pixels[1:], pixels[stride:], pixels[stride + 1:])
    gx, gy = 1 - fx, 1 - fy
    weight00 = gx * gy
    gy *= fx
    gx *= fy
    fx *= fy
    weights = (weight00, gy, gx, fx)
    found = np.empty((len(u), pixels.shape[1]), dtype=pixels.dtype)
    # the blend in the weights' and pixels' precision (float32 weights and image: float32), one
    # contiguous row per channel (twice as fast as the output's strided columns)
    blend = np.empty((channels, len(u)), np.result_type(fx, pixels))
    term = np.empty(len(u), dtype=blend.dtype)
    scaled = np.empty(len(u)) if texels.scale != 1.0 else None
    for i, (view, weight) in enumerate(zip(views, weights)):
        np.take(view, corner, axis=0, out=found, mode="clip")  # in range: clip only skips the check
        for c in range(channels):
            pixel = found[:, c]
            if texels.scale != 1.0:  # the scaled pixel in float64, as in a scaled image
                pixel = np.multiply(pixel, texels.scale, out=scaled, dtype=np.float64)
            if i == 0:
                np.multiply(weight, pixel, out=blend[c])
            else:
                np.multiply(weight, pixel, out=term)
                blend[c] += term
    for c in range(channels):
        out[:, c] = blend[c]
    return out


class Texels:
    """An (H, W, C) image laid out for :func:`image_lookup`: its pixels as the rows of one array,
    with one more row and column repeating the first ones, so that the four pixels of a bilinear
    lookup are rows i, i + 1, i + W + 1 and i + W + 2 of the repeat-wrapped first one (one index,
    four views); an RGB image's pixels padded with a fourth channel of 0 (np.take copies rows of
    16 or 32 bytes 2-2.5x faster than rows of 12 or 24).

    ``colour``: a colour image (a base colour), blended in its pixels' own precision: a float32
    image (as Blender's) in float32, twice as fast as in float64, to a few float32 steps of the
    brightest of the four pixels (tests/core/test_world.py); images that steer rays (normal maps,
    cut-out alpha) and float64 ones blend in float64."""

    def __init__(self, image, colour: bool = False, scale: float = 1.0):
        """``scale``: multiplies every looked-up pixel (in float64, as a scaled image would), so
        that an environment's strength needs no scaled copy of its image."""
        image = np.asarray(image)
        self.colour = colour
        self.scale = float(scale)
        self.height, self.width, self.channels = image.shape
        padded = _layout(image)
        self.pixels = padded.reshape(-1, padded.shape[2])


def texel_image(image) -> np.ndarray:
    """The (H, W, C) image as a view into its :class:`Texels` layout (read-only): a Texels of it
    copies nothing, and a scene that holds the view holds each image once (pickled by
    :func:`texel_state`, so that a worker process gets the layout, not a second copy)."""
    image = np.asarray(image)
    padded = _layout(image)
    padded.flags.writeable = False
    return padded[:-1, :-1, :image.shape[2]]


def texel_state(image):
    """What pickles an image of a scene: the layout buffer of a :func:`texel_image` view (once,
    however many fields hold it) and the image's shape, else the image itself;
    :func:`from_texel_state` undoes it."""
    if image is None or _padded_of(np.asarray(image)) is None:
        return image
    return _TexelState(image.base, image.shape)


def from_texel_state(state):
    if not isinstance(state, _TexelState):
        return state
    state.buffer.flags.writeable = False
    height, width, channels = state.shape
    padded = state.buffer.reshape(height + 1, width + 1, 4 if channels == 3 else channels)
    return padded[:-1, :-1, :channels]


class _TexelState:
    def __init__(self, buffer, shape):
        self.buffer, self.shape = buffer, shape


def _layout(image: np.ndarray) -> np.ndarray:
    """The :class:`Texels` layout of ``image``: the one it is a view into (no copy), else made anew."""
    padded = _padded_of(image)
    return _padded(image) if padded is None else padded


def _padded(image) -> np.ndarray:
    """The (H + 1, W + 1, C or 4) layout of :class:`Texels`, made anew."""
    height, width, channels = image.shape
    padded = np.zeros((height + 1, width + 1, 4 if channels == 3 else channels), image.dtype)
    padded[:-1, :-1, :channels] = image
    padded[-1, :-1, :channels] = image[0]
    padded[:, -1] = padded[:, 0]
    return padded


def _padded_of(image: np.ndarray):
    """The layout buffer that ``image`` is the (H, W, C) corner of, with the border rows of
    :class:`Texels` in place (as :func:`texel_image` made it), or None."""
    owner = image.base  # the padded layout, or the flat buffer it is a view of (as unpickled)
    if not isinstance(owner, np.ndarray) or image.ndim != 3 or owner.flags.writeable \
            or not owner.flags.c_contiguous:
        return None
    height, width, channels = image.shape
    shape = (height + 1, width + 1, 4 if channels == 3 else channels)
    if owner.size != shape[0] * shape[1] * shape[2] or owner.dtype != image.dtype:
        return None
    padded = owner.reshape(shape)
    if padded.strides != image.strides or padded.ctypes.data != image.ctypes.data:
        return None
    if not (np.array_equal(padded[-1, :-1], padded[0, :-1]) and np.array_equal(padded[:, -1], padded[:, 0])):
        return None
    return padded


def _wrap(index, size: int):
    """``index % size`` (repeat) in place, by a bit mask when size is a power of two (as fast as an add)."""
    if (size & (size - 1)) == 0:
        return np.bitwise_and(index, size - 1, out=index)
    return np.remainder(index, size, out=index)


# ---------------------------------------------------------------------------- worlds
_LUMINANCE_ROWS = 64  # image rows per band of the sampling map's luminance


class UniformWorld:
    """The same radiance ``color * strength`` (RGB) from every direction of S."""

    def __init__(self, color, strength: float = 1.0):
        self.radiance_rgb = np.asarray(color, dtype=np.float64)[:3] * float(strength)
        self.is_black = not bool(np.any(self.radiance_rgb > 0.0))

    def radiance(self, d):
        return np.broadcast_to(self.radiance_rgb, (len(d), 3))

    def sample(self, u1, u2):
        """Uniform directions on the sphere: (d (n, 3), pdf 1 / (4 pi) per unit solid angle)."""
        return _polar(1.0 - 2.0 * u1, 2.0 * np.pi * u2), np.full(len(u1), 1.0 / _FOUR_PI)

    def pdf(self, d):
        return np.full(len(d), 1.0 / _FOUR_PI)


class EnvironmentWorld:
    """An equirectangular environment image at rest in S, importance-sampled by luminance.

    ``image`` (H, W, 3 or 4) linear float radiance (alpha ignored), ``strength`` the
    Background strength, ``mapping`` the 3x3 rotation taking world directions to texture
    directions (:func:`mapping_rotation`), ``interpolation`` Blender's Linear or Closest.

    Sampling: the sphere is cut into cells uniform in (phi, cos theta) of texture space
    whose corners are the pixel edges (Closest) or lie on the bilinear lookup's patches
    between pixel centres (Linear: each patch split so the map has at least
    ``_MAP_COLUMNS`` columns), so the looked-up radiance inside a cell lies between its corner
    values.  A cell is chosen with probability proportional to its solid angle x the mean
    luminance of its corners, then a point uniformly in its solid angle: the density is
    constant per cell, and radiance / pdf stays within a factor 4 of the mean however bright
    a pixel, close to 1 where the corners of the fine cells are close.
    """

    def __init__(self, image, strength: float = 1.0, mapping=None, interpolation: str = "Linear",
                 name: str = "World"):
        image = np.asarray(image)
        if not np.issubdtype(image.dtype, np.floating):
            image = image.astype(np.float64)
        if image.ndim != 3 or image.shape[2] < 3 or image.shape[0] < 1 or image.shape[1] < 1:
            raise ValueError(f"{name}: the environment image must be (height, width, 3 or 4), got {image.shape}")
        rgb = image[..., :3]
        if not np.all(np.isfinite(rgb)):
            raise ValueError(f"{name}: the environment image has NaN or infinite pixels")
        if interpolation not in INTERPOLATIONS:
            raise ValueError(f"{name}: environment interpolation {interpolation!r} is not supported "
                             f"(use one of {', '.join(INTERPOLATIONS)})")
        mapping = _IDENTITY if mapping is None else np.asarray(mapping, dtype=np.float64)
        if mapping.shape != (3, 3) or not np.allclose(mapping @ mapping.T, np.eye(3), atol=1e-9) \
                or np.linalg.det(mapping) < 0.0:
            raise ValueError(f"{name}: the environment mapping must be a rotation (no scale, shear or mirror)")
        # the radiance max(pixel, 0) x strength: the image's own layout (a texel_image: no copy) scaled
        # per lookup, a clamped copy only where a pixel is negative
        strength = float(strength)
        self._texels = Texels(np.maximum(rgb, 0.0) if np.any(np.signbit(rgb)) else rgb, scale=strength)
        self.mapping = mapping
        self._unmapping = mapping if mapping is _IDENTITY else mapping.T  # texture -> world directions
        self.interpolation = interpolation
        h, w = rgb.shape[:2]
        luminance = np.empty((h, w))
        for start in range(0, h, _LUMINANCE_ROWS):  # in bands: no float64 copy of the whole image
            band = slice(start, start + _LUMINANCE_ROWS)
            luminance[band] = (np.maximum(rgb[band].astype(np.float64), 0.0) * strength) @ LUMINANCE_RGB
        if interpolation == "Linear":
            # cell rows between pixel-centre rows, the two caps wrapping as Cycles' lookup does, each
            # split into ``split`` x ``split`` sub-cells: the bilinear radiance inside a cell lies
            # between its corner values, which are close on a fine grid (a pdf as fine as the pixels
            # leaves radiance / pdf anywhere in 0..4x its mean across a bright pixel's cells)
            split = max(1, -(-_MAP_COLUMNS // w))
            coarse_v = np.concatenate([[0.0], (np.arange(h) + 0.5) / h, [1.0]])
            v_edges = np.append((coarse_v[:-1, None] + np.diff(coarse_v)[:, None] * (np.arange(split) / split)).ravel(),
                                1.0)
            self._u_offset = 0.5 / w
            # (each map-sized array dropped once used: an 8192x4096 map's are 256 MiB each)
            corners = _refined_lattice(luminance, v_edges, split)
            del luminance
            corner_rows = corners[:-1] + corners[1:]
            del corners
            weight = corner_rows[:, :-1] + corner_rows[:, 1:]
            del corner_rows
            weight *= 0.25  # the mean of the cell's corners
        else:
            v_edges = np.arange(h + 1) / h
            weight = luminance
            self._u_offset = 0.0
        self._columns = weight.shape[1]
        self._z_edges = -np.cos(np.pi * v_edges)
        self._v_edges = v_edges
        w = self._columns
        cell_omega = (2.0 * np.pi / w) * np.diff(self._z_edges)[:, None]
        weight *= cell_omega  # the cell's luminance x its solid angle
        total = float(weight.sum())
        self.is_black = not total > 0.0
        if self.is_black:
            weight = cell_omega * np.ones(w)  # keeps the tables well formed; the pdf is 0
            total = float(weight.sum())
        row_weight = weight.sum(axis=1)
        self._row_cdf = np.cumsum(row_weight) / total
        self._row_cdf[-1] = 1.0
        self._row_probability = row_weight / total
        # a cell's density per unit solid angle: its row's probability / its solid angle x its
        # column's probability in the row, the difference of the row's column cdf, which is what
        # the sampler gives it (no table of densities: the cdf is the one (rows, columns) table,
        # float64, built in place in the weights: an 8192x4096 map's is 256 MiB)
        self._row_density = np.zeros(len(row_weight)) if self.is_black else self._row_probability / cell_omega[:, 0]
        column_cdf = np.cumsum(weight, axis=1, out=weight)
        with np.errstate(invalid="ignore", divide="ignore"):
            column_cdf /= row_weight[:, None]
        column_cdf[row_weight <= 0.0] = np.arange(1, w + 1) / w
        column_cdf[:, -1] = 1.0
        self._column_cdf = column_cdf.ravel()

    def radiance(self, d):
        """Radiance (n, 3) arriving from backward world directions d."""
        u, v = direction_to_equirectangular(_rotate(self.mapping, d))
        return image_lookup(self._texels, u, v, self.interpolation)

    def _cell(self, t):
        w = self._columns
        u, v = direction_to_equirectangular(t)
        column = np.floor((u - self._u_offset) * w).astype(np.int64) % w
        row = np.clip(np.searchsorted(self._v_edges, v, side="right") - 1, 0, len(self._v_edges) - 2)
        return row, column

    def _column_span(self, row, column):
        """The column cdf before and at each cell (row, column): the column's start in its row's
        cdf and its probability there."""
        cell = row * self._columns + column
        start = np.where(column > 0, self._column_cdf[np.maximum(cell - 1, 0)], 0.0)
        return start, self._column_cdf[cell] - start

    def pdf(self, d):
        """Density per unit solid angle of world directions d under :meth:`sample`."""
        row, column = self._cell(_rotate(self.mapping, d))
        return self._row_density[row] * self._column_span(row, column)[1]

    def sample(self, u1, u2):
        """Directions of S drawn by the image's luminance: (d (n, 3), pdf (n,) per unit solid angle).

        u1 picks the cell row and, rescaled, cos(theta) inside it; u2 likewise the column
        and phi: strata of (u1, u2) stay compact on the sphere.
        """
        w = self._columns
        rows_count = len(self._row_probability)
        row = np.minimum(np.searchsorted(self._row_cdf, u1, side="right"), rows_count - 1)
        row_start = np.where(row > 0, self._row_cdf[np.maximum(row - 1, 0)], 0.0)
        along_z = np.clip((u1 - row_start) / self._row_probability[row], 0.0, 1.0)
        column = np.minimum(_search_within_rows(self._column_cdf, row, w, u2), w - 1)
        column_start, column_probability = self._column_span(row, column)
        along_phi = np.clip((u2 - column_start) / column_probability, 0.0, 1.0)
        z = self._z_edges[row] + along_z * (self._z_edges[row + 1] - self._z_edges[row])
        u = self._u_offset + (column + along_phi) / w
        t = _polar(z, np.pi * (1.0 - 2.0 * u))
        return _rotate(self._unmapping, t), self._row_density[row] * column_probability


def _refined_lattice(values, v_edges, split: int):
    """The bilinear lookup of :func:`image_lookup` (Linear) of an (H, W) image at rows ``v_edges``
    and columns ``u = (j / split + 1/2) / W``, j = 0 .. W split: the pixel centres and ``split - 1``
    points between neighbours.  On this lattice bilinear interpolation is one linear
    interpolation along v, then one along u (a general lookup per corner takes longer than the
    rest of the sampling map)."""
    h, w = values.shape
    y = v_edges * h - 0.5
    y0 = np.floor(y)
    fy = (y - y0)[:, None]
    y0 = y0.astype(np.int64)
    along_v = _blend(values[y0 % h], values[(y0 + 1) % h], fy)
    j = np.arange(w * split + 1)
    x0, fx = j // split, (j % split) / split
    lower = along_v[:, x0 % w]
    upper = along_v[:, (x0 + 1) % w]
    del along_v
    return _blend(lower, upper, fx)


def _blend(lower, upper, fraction):
    """``(1 - fraction) lower + fraction upper``, in place in ``lower`` and ``upper`` (fresh arrays
    the size of a sampling map cost more in memory than the arithmetic)."""
    lower *= 1.0 - fraction
    upper *= fraction
    lower += upper
    return lower


def _rotate(matrix, d):
    """Rows ``matrix @ d_i``, column by column (an (n, 3) @ (3, 3) product is slow in numpy)."""
    if matrix is _IDENTITY:
        return d
    out = np.empty((len(d), 3))
    for i in range(3):
        out[:, i] = d[:, 0] * matrix[i, 0] + d[:, 1] * matrix[i, 1] + d[:, 2] * matrix[i, 2]
    return out


def _search_within_rows(table, row, width, key):
    """Per key, the first column of its row of ``table`` (rows of ``width`` sorted entries, flat)
    whose entry exceeds the key: a binary search vectorised over keys.  numpy's searchsorted
    over the whole flat table costs a cache miss per step on large images (10x slower)."""
    lo = row * width
    hi = lo + width
    for _ in range(int(np.ceil(np.log2(width + 1)))):
        active = lo < hi
        mid = (lo + hi) >> 1
        right = table[np.minimum(mid, len(table) - 1)] <= key
        lo = np.where(active & right, mid + 1, lo)
        hi = np.where(active & ~right, mid, hi)
    return lo - row * width


# ---------------------------------------------------------------------------- moving receivers
def frame_pdf(pdf_world, doppler):
    """Density per unit solid angle in the receiving frame S' of a direction drawn in S with
    density ``pdf_world``: ``p_S' = p_S D^2`` (dOmega_S / dOmega_S' = D^2), D = nu_S' / nu_S."""
    return pdf_world * doppler * doppler


def sample_in_frame(world, to_frame, u1, u2):
    """World directions drawn in S, seen from a frame S' (``to_frame`` maps S to S').

    Returns (d', pdf', radiance, doppler): backward directions in S', their density per
    unit solid angle of S', the world's radiance there in S (RGB) and D = nu_S' / nu_S
    (radiance received in S' is ``radiance * D^4``).
    """
    d, pdf = world.sample(u1, u2)
    d_frame, doppler = to_frame.rays(d)  # w = s_S' / s_S = nu_S' / nu_S = D
    return d_frame, frame_pdf(pdf, doppler), world.radiance(d), doppler


def look_up_from_frame(world, to_world, d_frame):
    """The world seen along backward directions d' of a frame S' (``to_world`` maps S' to S).

    Returns (radiance, pdf', doppler): radiance in S (RGB) and D = nu_S' / nu_S as in
    :func:`sample_in_frame`, and the density with which :func:`sample_in_frame` draws d'
    (for multiple importance sampling against a BSDF's own sampling).
    """
    d, w = to_world.rays(d_frame)  # w = s_S / s_S' = 1 / D
    doppler = 1.0 / w
    return world.radiance(d), frame_pdf(world.pdf(d), doppler), doppler


def sphere_integral_estimate(world, to_frame, u1, u2):
    """One-sample estimates (n, 3) of the radiance received in S' integrated over all of its
    directions, ``integral of L D^4 dOmega'`` (4 pi gamma^2 (1 + b^2/3) L for a uniform world),
    by world sampling carried into S'."""
    _, pdf, radiance, doppler = sample_in_frame(world, to_frame, u1, u2)
    return rows.scale(radiance, doppler**4 / pdf)


def lambertian_radiance_estimate(world, to_world, to_frame, normal, u):
    """One-sample estimates (n, 3) of the radiance leaving a white Lambertian surface at rest
    in S', lit by the world only (no occluders): ``(1/pi) integral of L D^4 cos dOmega'`` over
    its hemisphere about ``normal`` (n, 3), frame S'.

    Combines a cosine-weighted BSDF sample (u[0], u[1]) and a world sample (u[2], u[3]) by
    the power heuristic, the way a path tracer's next-event estimation does.
    """
    d_bsdf, pdf_bsdf = sample_diffuse(normal, u[0], u[1])
    radiance, pdf_world, doppler = look_up_from_frame(world, to_world, d_bsdf)
    cos_bsdf = np.maximum(rows.dot(normal, d_bsdf), 0.0)
    weight = mis.power_heuristic(pdf_bsdf, pdf_world) * cos_bsdf / np.pi * doppler**4
    estimate = rows.scale(radiance, np.where(pdf_bsdf > 0.0, weight / np.maximum(pdf_bsdf, 1e-300), 0.0))
    d_world, pdf_world, radiance, doppler = sample_in_frame(world, to_frame, u[2], u[3])
    cos_world = np.maximum(rows.dot(normal, d_world), 0.0)
    weight = mis.power_heuristic(pdf_world, cos_world / np.pi) * cos_world / np.pi * doppler**4
    return estimate + rows.scale(radiance, np.where(pdf_world > 0.0, weight / np.maximum(pdf_world, 1e-300), 0.0))

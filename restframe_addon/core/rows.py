"""Row-wise 3-vector arithmetic on (n, 3) arrays, written one axis at a time.

numpy runs its inner loop along the last axis, so an (n, 3) array broadcast against an
(n, 1) or (3,) operand loops three elements at a time: 4-10x slower than the same
arithmetic on whole columns (``np.cross`` and ``einsum`` are slower still).  These helpers
keep the (n, 3) layout that embree and the rest of the code use, and do the work column by
column (strided but long inner loops).
"""

from __future__ import annotations

import numpy as np

_ONES = np.ones(3)


def take(a, index) -> np.ndarray:
    """The rows of ``a`` at ``index`` (integer indices or a boolean mask over the rows; a slice:
    a view of them).

    numpy's fancy indexing of an (n, 3) array copies three elements at a time: ``take`` and
    ``compress`` along the first axis do the same 3-4x faster (1-D arrays alike for masks).  Of an
    array with contiguous columns (``scale(..., columns=True)``), column by column into the same
    layout (numpy would copy the whole array into rows first: 2.5x slower).
    """
    if isinstance(index, slice):
        return a[index]
    index = np.asarray(index)
    mask = index.dtype == bool
    if is_broadcast(a):  # one row for all: the same row for the selected ones, no gather
        return broadcast(a[:1], np.count_nonzero(index) if mask else len(index))
    if a.ndim == 2 and 1 < a.shape[1] <= 4 and not a.flags.c_contiguous and a.flags.f_contiguous:
        out = np.empty((a.shape[1], np.count_nonzero(index) if mask else len(index)), dtype=a.dtype).T
        for c in range(a.shape[1]):
            if mask:
                np.compress(index, a[:, c], out=out[:, c])
            else:
                np.take(a[:, c], index, out=out[:, c])
        return out
    return np.compress(index, a, axis=0) if mask else np.take(a, index, axis=0)


def put(a, index, new) -> None:
    """``a[index] = new`` for rows of an (n, C) array at integer indices: numpy's fancy assignment
    copies them one element at a time, np.put of whole rows (a C-contiguous array's rows viewed as
    one item each) 3x faster."""
    if not a.flags.c_contiguous:
        a[index] = new
        return
    row = np.dtype((np.void, a.shape[1] * a.itemsize))
    np.put(a.view(row)[:, 0], index, c_contiguous(new, a.dtype).view(row)[:, 0])


def put_selection(a, sel, new) -> None:
    """``a[sel] = new`` for rows ``sel`` (a slice or indices, as :func:`selection` gives) of an array
    (``new`` may have contiguous columns)."""
    if isinstance(sel, slice):
        assign(a[sel], new)
    else:
        put(a, sel, new)


def c_contiguous(a, dtype=None) -> np.ndarray:
    """``np.ascontiguousarray(a, dtype)`` of (n, C) rows (see :func:`assign`)."""
    a = np.asarray(a)
    if a.flags.c_contiguous:
        return a if dtype is None else np.ascontiguousarray(a, dtype=dtype)
    out = np.empty(a.shape, dtype=a.dtype if dtype is None else dtype)
    assign(out, a)
    return out


def assign(out, a) -> None:
    """``out[...] = a`` for (n, C) rows, column by column between arrays of different layouts
    (numpy copies a column-major (n, 3) array into rows three elements at a time, 6x slower)."""
    if a.ndim != 2 or a.shape[1] > 4 or a.flags.c_contiguous == out.flags.c_contiguous:
        out[...] = a
        return
    for axis in range(a.shape[1]):
        out[:, axis] = a[:, axis]


def clipped(a, lo, hi) -> np.ndarray:
    """``np.clip(a, lo, hi)``, or ``a`` itself when it lies in [lo, hi] (two reductions cost a
    third of the clip)."""
    a = np.asarray(a)
    return a if a.size and a.min() >= lo and a.max() <= hi else np.clip(a, lo, hi)


def selection(mask, within=slice(None)):
    """The rows of ``within`` (a slice of all, or indices) where ``mask`` holds: the slice itself
    while that is all of them (views instead of gathers), None when none."""
    if not len(mask):
        return None
    if mask.all():
        return within
    index = np.flatnonzero(mask)
    if not len(index):
        return None
    return index if isinstance(within, slice) else within[index]


def broadcast(first, n: int) -> np.ndarray:
    """The one row of ``first`` (a (1,) or (1, C) array) as n rows: a read-only view, zero row
    stride, made directly (np.broadcast_to costs 3.5 us a call, which counts for every bundle of
    a few rays)."""
    first = np.ascontiguousarray(first)
    view = np.ndarray((n,) + first.shape[1:], first.dtype, first, strides=(0,) + first.strides[1:])
    view.flags.writeable = False
    return view


def filled(row, n: int) -> np.ndarray:
    """A new (n, C) array of one row (C,) in every row, filled column by column (numpy's
    broadcast of a row loops C elements at a time: 3.5x slower)."""
    out = np.empty((n, len(row)), dtype=np.asarray(row).dtype)
    for c in range(len(row)):
        out[:, c] = row[c]
    return out


def is_broadcast(a) -> bool:
    """Whether ``a`` is one row (or number) repeated, as :func:`broadcast` (or np.broadcast_to)
    makes it: read-only, zero first stride."""
    return isinstance(a, np.ndarray) and a.ndim >= 1 and a.strides[0] == 0 and not a.flags.writeable


def dot(a, b) -> np.ndarray:
    """Row-wise dot products: (n, 3) with (n, 3), or (n, 3) with one (3,) vector.  Of rows with
    a :func:`broadcast` row, column by column: ``(a0 b0 + a1 b1) + a2 b2``, the same products and
    sums as the product's rows summed by the matrix-vector product (numpy would loop over the
    broadcast product three elements at a time: 2.4x slower)."""
    a = np.asarray(a)
    b = np.asarray(b)
    if b.ndim == 1:
        return a @ b
    if is_broadcast(a) != is_broadcast(b) and a.shape[1] == 3:
        row, columns = (a[0], b) if is_broadcast(a) else (b[0], a)
        out = np.multiply(columns[:, 0], row[0])
        term = np.multiply(columns[:, 1], row[1])
        out += term
        out += np.multiply(columns[:, 2], row[2], out=term)
        return out
    return (a * b) @ _ONES


def norm(a) -> np.ndarray:
    return np.sqrt(dot(a, a))


def scale(a, s, columns: bool = False, out=None) -> np.ndarray:
    """Each row of a (n, C) times its own scalar s (n,): column by column for few columns;
    ``columns``: into an array whose columns are contiguous (for more work column by column);
    ``out``: into this array (a itself: in place, no new array)."""
    a = np.asarray(a)
    if a.shape[1] > 4:  # long rows (spectra): numpy's broadcast is fast there
        return np.multiply(a, s[:, None], out=out)
    dtype = np.result_type(a, s)
    if out is None:
        out = np.empty(a.shape[::-1], dtype=dtype).T if columns else np.empty(a.shape, dtype=dtype)
    for axis in range(a.shape[1]):
        np.multiply(a[:, axis], s, out=out[:, axis])
    return out


def normalized(a) -> np.ndarray:
    """Rows scaled to unit length (rows of length 0 stay 0)."""
    return scale(a, 1.0 / np.maximum(norm(a), 1e-300))


def add(a, b) -> np.ndarray:
    """``a + b`` for (..., 3) a and (3,) or (..., 3) b."""
    a = np.asarray(a)
    b = np.asarray(b)
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    for axis in range(3):
        np.add(a[..., axis], b[..., axis], out=out[..., axis])
    return out


def add_scaled(a, s, b) -> np.ndarray:
    """``a + s[:, None] * b`` for (n, 3) or (3,) a and b and (n,) s."""
    n = len(s)
    out = np.empty((n, 3))
    a = np.asarray(a)
    b = np.asarray(b)
    for axis in range(3):
        np.multiply(s, b[..., axis], out=out[:, axis])
        out[:, axis] += a[..., axis]
    return out


def cross(a, b) -> np.ndarray:
    """Row-wise cross products of (n, 3) arrays (either may be one (3,) vector)."""
    a = np.asarray(a)
    b = np.asarray(b)
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    bx, by, bz = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = ay * bz - az * by
    out[..., 1] = az * bx - ax * bz
    out[..., 2] = ax * by - ay * bx
    return out

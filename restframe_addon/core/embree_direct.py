"""Triangles handed to embree with one memory copy per buffer, past embreex's per-element copy.

embreex's ``TriangleMesh`` fills embree's vertex and index buffers through Python indexing,
one number at a time while holding the GIL: whatever the arrays' dtype or layout, that costs
about 0.5 us per triangle, several times what embree then takes to build its BVH over them.
embreex does not expose its scene or device handle, so this module reads them from the
``EmbreeScene`` and ``EmbreeDevice`` objects (Cython objects whose fields follow the Python
object header) and calls the functions embreex itself calls -- ``rtcNewGeometry``,
``rtcSetNewGeometryBuffer``, ``rtcCommitGeometry``, ``rtcAttachGeometry``,
``rtcReleaseGeometry``, ``rtcCommitScene`` -- in the embree library embreex has already loaded,
and embree's shared buffers (``rtcNewBuffer``, ``rtcSetGeometryBuffer``) so that the pieces of
a mesh use one copy of its vertices.  The triangles then have the vertices embreex would have
given them, in the same order, so embree builds the same BVH.  The copies and the commit run
without the GIL (ctypes releases it): the engine's main thread goes on polling Esc meanwhile.

Before first use the route is proved on a probe scene: the objects' sizes, two fields read back
at their offsets, and two triangles attached this way (own and shared vertices) and hit by rays
through embreex.  Where
anything fails (another embreex build, the library not loaded under a known name),
:func:`ready` and :func:`attach` return False and the caller uses embreex's own ways.
"""

from __future__ import annotations

import ctypes
import glob
import os
import sys

import numpy as np
from embreex import rtcore, rtcore_scene

_HEAD = object.__basicsize__  # the Python object header; the Cython fields follow it
# EmbreeDevice: (RTCDevice device); EmbreeScene: (RTCScene scene_i, int is_committed, EmbreeDevice device)
_DEVICE_HANDLE, _SCENE_HANDLE, _SCENE_COMMITTED, _SCENE_DEVICE = _HEAD, _HEAD, _HEAD + 8, _HEAD + 16
_TRIANGLE, _INDEX, _VERTEX, _UINT3, _FLOAT3 = 0, 0, 1, 0x5003, 0x9003  # embree4 enum values

_library = None  # the proved embree library (ctypes), False once the route failed


def ready(device) -> bool:
    """Can triangles go to embree directly on this device (proved once per process)?"""
    global _library
    if _library is None:
        _library = _proved_library(device) or False
    return bool(_library)


def attach(scene, device, vertices, triangles: np.ndarray) -> bool:
    """Attach triangles (m, 3, vertex indices) to an embreex scene made on ``device`` as one
    triangle geometry, as ``TriangleMesh(scene, vertices, triangles)`` would; ``vertices`` are
    float32 (n, 3) or :class:`SharedVertices`.  False (nothing attached) where the direct route
    is not available."""
    if not ready(device) or _field(scene, _SCENE_DEVICE) != id(device):
        return False
    _attach(_library, scene, device, vertices, triangles)
    return True


def shared_vertices(device, vertices: np.ndarray) -> SharedVertices | None:
    """float32 vertices (n, 3), or (n, 4) as :func:`padded_vertices` lays them out, in one embree
    buffer for the geometries :func:`attach` makes from them; None where the direct route is not
    available."""
    return SharedVertices(_library, device, vertices) if ready(device) else None


class SharedVertices:
    """Vertices copied once into one embree buffer that many geometries use (each holds its own
    reference to it; this object's ends with :meth:`release`)."""

    def __init__(self, lib, device, vertices: np.ndarray):
        self.lib, self.count = lib, len(vertices)
        padded = _padded(vertices)
        self.buffer = lib.rtcNewBuffer(_field(device, _DEVICE_HANDLE), max(padded.nbytes, 16))
        if not self.buffer:
            raise MemoryError(f"embree could not allocate {padded.nbytes} bytes for vertices")
        ctypes.memmove(lib.rtcGetBufferData(self.buffer), padded.ctypes.data, padded.nbytes)

    def release(self) -> None:
        self.lib.rtcReleaseBuffer(self.buffer)


def commit(scene) -> None:
    """Build the BVH of an embreex scene now, as its first query would, but without holding the
    GIL (a ctypes call releases it); only once :func:`ready` is true."""
    _library.rtcCommitScene(_field(scene, _SCENE_HANDLE))
    scene.is_committed = 1  # embreex's own flag: its queries do not commit again


def _field(obj, offset: int) -> int:
    """A pointer-sized field of a Cython object (0 for NULL)."""
    return ctypes.c_void_p.from_address(id(obj) + offset).value or 0


def padded_vertices(vertices: np.ndarray, anchor) -> np.ndarray:
    """float64 vertices (n, 3) relative to ``anchor``, rounded to float32 once, in embree's
    layout (:func:`_padded`) from the start (no float32 (n, 3) copy in between)."""
    padded = np.empty((len(vertices), 4), dtype=np.float32)
    for axis in range(3):  # by column: the (n, 3) -> strided (n, 3 of 4) cast in one call is 5x slower
        np.subtract(vertices[:, axis], anchor[axis], out=padded[:, axis], casting="same_kind")
    padded[:, 3] = 0.0
    return padded


def _padded(vertices) -> np.ndarray:
    """Vertices in embree's layout: x, y, z and an unused fourth float each (as they are if
    they have it already)."""
    if vertices.shape[1] == 4 and vertices.dtype == np.float32 and vertices.flags.c_contiguous:
        return vertices
    padded = np.zeros((len(vertices), 4), dtype=np.float32)
    padded[:, :3] = vertices
    return padded


def _attach(lib, scene, device, vertices, triangles) -> None:
    geometry = lib.rtcNewGeometry(_field(device, _DEVICE_HANDLE), _TRIANGLE)
    if not geometry:
        raise MemoryError("embree could not create a triangle geometry")
    try:
        buffers = [(_INDEX, _UINT3, 12, np.ascontiguousarray(triangles, dtype=np.uint32))]
        if isinstance(vertices, SharedVertices):
            lib.rtcSetGeometryBuffer(geometry, _VERTEX, 0, _FLOAT3, vertices.buffer, 0, 16, vertices.count)
        else:
            buffers.append((_VERTEX, _FLOAT3, 16, _padded(vertices)))
        for kind, form, stride, data in buffers:
            buffer = lib.rtcSetNewGeometryBuffer(geometry, kind, 0, form, stride, len(data))
            if not buffer:
                raise MemoryError(f"embree could not allocate {data.nbytes} bytes for a geometry")
            ctypes.memmove(buffer, data.ctypes.data, data.nbytes)
        lib.rtcCommitGeometry(geometry)
        lib.rtcAttachGeometry(_field(scene, _SCENE_HANDLE), geometry)
    finally:
        lib.rtcReleaseGeometry(geometry)  # the scene keeps its own reference


def _proved_library(device):
    """The embree library embreex uses, once the route is proved on a probe scene of this
    device (None where it cannot be)."""
    if (type(device) is not rtcore.EmbreeDevice or rtcore.EmbreeDevice.__basicsize__ != _HEAD + 8
            or rtcore_scene.EmbreeScene.__basicsize__ != _HEAD + 24):
        return None
    lib = _loaded_embree()
    if lib is None:
        return None
    void, uint, size = ctypes.c_void_p, ctypes.c_uint, ctypes.c_size_t
    for name, result, args in (("rtcNewGeometry", void, [void, ctypes.c_int]),
                               ("rtcSetNewGeometryBuffer", void, [void, ctypes.c_int, uint, ctypes.c_int, size, size]),
                               ("rtcCommitGeometry", None, [void]), ("rtcAttachGeometry", uint, [void, void]),
                               ("rtcReleaseGeometry", None, [void]), ("rtcCommitScene", None, [void]),
                               ("rtcNewBuffer", void, [void, size]), ("rtcGetBufferData", void, [void]),
                               ("rtcReleaseBuffer", None, [void]),
                               ("rtcSetGeometryBuffer", None, [void, ctypes.c_int, uint, ctypes.c_int, void, size, size,
                                                               size])):
        function = getattr(lib, name, None)
        if function is None:
            return None
        function.restype, function.argtypes = result, args
    probe = rtcore_scene.EmbreeScene(device)
    probe.is_committed = 0x2F5A
    seen = ctypes.c_int.from_address(id(probe) + _SCENE_COMMITTED).value
    probe.is_committed = 0
    if seen != 0x2F5A or _field(probe, _SCENE_DEVICE) != id(device) or not _field(probe, _SCENE_HANDLE):
        return None
    # two triangles at z = 2 and z = 3, one with its own vertices, one with shared ones
    corners = np.array([[0, 0, 2], [1, 0, 2], [0, 1, 2], [0, 0, 3], [1, 0, 3], [0, 1, 3]], np.float32)
    _attach(lib, probe, device, corners[:3], np.array([[0, 1, 2]]))
    shared = SharedVertices(lib, device, corners)
    _attach(lib, probe, device, shared, np.array([[5, 4, 3]]))
    shared.release()
    out = probe.run(np.array([[0.25, 0.25, 0.0], [0.25, 0.25, 2.5]], np.float32), np.array([[0, 0, 1]], np.float32),
                    output=1)
    hit = (out["geomID"].tolist(), out["primID"].tolist(), np.abs(out["tfar"] - [2.0, 0.5]).max())
    return lib if hit[:2] == ([0, 1], [0, 0]) and hit[2] < 1e-6 else None


def _loaded_embree():
    """ctypes handle of the embree library already loaded by embreex (never a second copy)."""
    package = os.path.dirname(rtcore.__file__)
    places = [package + ".libs", package, os.path.join(package, ".dylibs")]
    for path in sorted(p for place in places for p in glob.glob(os.path.join(place, "*embree4*"))):
        try:
            if sys.platform == "win32":
                get_module = ctypes.windll.kernel32.GetModuleHandleW
                get_module.restype, get_module.argtypes = ctypes.c_void_p, [ctypes.c_wchar_p]
                handle = get_module(path)
                if handle:
                    return ctypes.CDLL(path, handle=handle)
            else:
                return ctypes.CDLL(path, mode=os.RTLD_NOLOAD | os.RTLD_NOW)
        except (OSError, AttributeError):
            continue
    return None

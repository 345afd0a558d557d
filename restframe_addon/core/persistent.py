"""Persistent data across frames: rest-frame geometry kept from one frame to the next.

A body at constant velocity never changes in its own rest frame, so an animation's frames
can trace the very same embree scenes; only what depends on the frame's time (the camera's
observation event, the lights, the pre-passes) is worked out again.  A
:class:`GeometryCache` gives back an already built :class:`~.frames.Geometry` for parts
whose content is unchanged, keyed by a hash of every byte the build reads (vertices as
placed in the rest frame, triangles, materials, object indices, clocks, normals, UVs), so
no change to a mesh, its velocity, pivot or material can reuse a stale build, and the
pixels are those of a fresh build.  It keeps only what the last finished frame used.

One owner holds a cache for a run of frames (the render engine while Blender keeps it, with
Persistent Data on; the command line for its frames) and hands it to
:func:`~.prepared.prepare`; prepared scenes stay immutable and pickle without it.
"""

from __future__ import annotations

import hashlib
import threading
from typing import Callable

import numpy as np


def parts_key(parts: list[dict]) -> bytes:
    """A digest of everything in the parts (each a dict of arrays or None): equal digests,
    equal builds.  SHA-1 is a content address here (as in git), about 1 GB/s."""
    digest = hashlib.sha1()
    digest.update(len(parts).to_bytes(8, "little"))
    for part in parts:
        for name in sorted(part):
            value = part[name]
            if value is None:
                digest.update(f"{name}:None;".encode())
                continue
            array = np.ascontiguousarray(value)
            digest.update(f"{name}:{array.dtype.str}{array.shape};".encode())
            digest.update(array.data)
    return digest.digest()


class GeometryCache:
    """Built geometry by the content of its parts, for the frames of one owner's renders.

    Thread-safe (an abandoned build may still be finishing while the next frame is
    prepared); ``builds`` and ``reuses`` count what it did.
    """

    def __init__(self):
        self._lock = threading.Lock()
        self._built: dict[bytes, object] = {}
        self._used: set[bytes] = set()  # keys asked for since the last finished frame
        self.builds = 0
        self.reuses = 0

    def __len__(self) -> int:
        return len(self._built)

    def geometry(self, parts: list[dict], build: Callable[[], object]):
        """The geometry of these parts: the one built before for the same content, else
        ``build()`` (kept unless it is None, a cancelled build)."""
        key = parts_key(parts)
        with self._lock:
            self._used.add(key)
            found = self._built.get(key)
            if found is not None:
                self.reuses += 1
                return found
        built = build()
        if built is not None:
            with self._lock:
                self._built[key] = built
                self.builds += 1
        return built

    def finish_frame(self) -> None:
        """A frame's build is complete: forget the geometry it did not use (memory stays
        bounded by one frame's geometry, plus the next frame's new builds while it is prepared)."""
        with self._lock:
            self._built = {key: geometry for key, geometry in self._built.items() if key in self._used}
            self._used = set()

    def clear(self) -> None:
        with self._lock:
            self._built.clear()
            self._used.clear()

"""Tiles rendered in worker processes: every core busy, free of the GIL.

Threads share one GIL, which the Python between a tile's numpy calls holds (12-39% of a
tile), so they stop scaling after a few cores; worker processes do not share it.

A worker is a fresh interpreter (``sys.executable``, Blender's bundled Python inside
Blender) started with a dedicated entry (:mod:`.worker_boot`), never a fork of the running
Blender and without touching multiprocessing's start method.  multiprocessing's own
``spawn`` is not used because it re-runs the parent's ``__main__`` in every child (a
``blender --python script.py`` would run the script again in each worker) and unpickles
its target before any code of ours could recreate Blender's in-memory ``bl_ext`` package;
the dedicated entry does both first.  Only the core is imported in a worker, never bpy.

The pool is module-level (:func:`pool`) and kept warm across the renders of a session and
the frames of an animation.  A render pickles its scene and settings once into a file that
every worker maps for itself (reads, on Windows), at once, so no worker waits for the scene to
pass through the pipes of the others (a new scene replaces the old one there, naming the arrays that
the old one's files hold byte for byte instead of writing them again; the same one rendered again is
not sent again).  The engine does that before it prepares the scene (:func:`build_ahead`), so
the workers build it while this process does, and the render sends them only what the
pre-passes measured.  It then deals work two shares at a time per worker (one in the
render's tail, so that none waits behind a long share while the others run dry).  A share
is a whole tile or, towards the end of a render with several workers, a band of a tile's
rows (:func:`share_out`), so the workers finish together however unevenly the cost is spread
over the image; the caller gets whole tiles, as from threads.  A worker writes each share's
passes into the render's results image, a file mapped in shared memory, where the tile's
bands meet in place; its message says only that it is there, so no result is pickled or
passes through a pipe (the parent spent 1.4 ms unpickling each 256-px tile).  Esc stops the
dealing and each worker stops its share at the next sample batch and drops the ones it
holds; a worker that dies has its shares dealt again to the others (and the unfinished tiles
to threads here when none is left).  A worker ends when its stdin reaches EOF (the parent
closed it or died) or when its parent process is gone.  Tiles are the same bits as in
threads: every random number is keyed by (pixel, sample), a band is rendered in its tile's
sample batches and the pickled scene is built to the same bits.  Each render leaves its :class:`RenderStats`
(:attr:`WorkerPool.last_stats`): when each share ran in which worker and what the parent
spent, for the benchmark's balance and serial-share figures.
"""

from __future__ import annotations

import atexit
import collections
import dataclasses
import itertools
import mmap
import os
import pickle
import queue
import selectors
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time
import traceback
import weakref
from typing import Callable, Iterator

import numpy as np

from . import blas, malloc
from .passes import ALL_PASSES
from .persistent import GeometryCache
from .prepared import PreparedScene, build_unmeasured, measured_as
from .render import Tile, render_tile, tiles_in_threads, warm_up
from .scene import RenderSettings, Scene, render_workers
from .tracer import TraceCache

MALLOC_TUNING = malloc.ENVIRONMENT  # a worker's malloc keeps its large temporaries (see malloc)
# one BLAS thread per worker: the workers fill the cores (see blas)
_ONE_BLAS_THREAD = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}

_TILES_IN_FLIGHT = 2  # shares per worker: one rendering, one waiting, so a worker never idles between them
_SHARES_PER_WORKER = 4  # guided dealing: a share is about this fraction of a worker's part of what is left
# the tail of a render: with at most this many shares a worker left to deal, each worker holds one
# share at a time (none is tied up waiting behind a long one while others run dry) while shares
# take at least _TAIL_SECONDS (the round trip to deal the next, 0.3-1 ms, is then a few percent)
_TAIL_SHARES = 4
_TAIL_SECONDS = 0.02
_MIN_SHARE_PIXELS = 8192  # smaller bands cost more than they win: a render_tile call costs 0.2-3.5 ms whatever its size
_WORKER_MEMORY = 400 << 20  # bytes a worker needs besides its scene (interpreter, numpy, embree, tile batches)
_SCENE_MEMORY_FACTOR = 6  # a worker's rebuilt scene (frames, BVHs, caches) against its pickled size
_START_TIMEOUT = 120.0  # seconds a starting worker may take to say it is ready
_POLL = 0.05  # seconds between Esc checks while waiting for tiles
# while shares finish faster than this, the render loop wakes once per this many seconds for all
# of them, the workers holding work for twice as long, instead of once per share (see _Pace)
_BATCH = 0.04
_WATCHDOG = 0.2  # seconds between a worker's checks that its parent lives
# where a render's files (its scene's pickle, its results image) are made: shared memory first
# (Linux: no file system to allocate blocks in, moving_sphere's 5.6 MB scene 1.8 ms to write instead
# of 4-14 ms into an ext4 /tmp), else the temporary folder
_SHARED_FOLDERS = ("/dev/shm", tempfile.gettempdir())
_ALIGN = 64  # bytes: where each array of a scene's file starts (as numpy aligns its own)
# a finished render's results image is kept for the next one of its size only up to this many bytes:
# its ~1 ms of page faults saved is worth a small image's shared memory, not a large one's held between renders
_KEPT_RESULTS_BYTES = 64 << 20
_IN_BAND_BYTES = 1 << 16  # smaller arrays are copied into the scene's pickle (a write and padding each would cost more)
_FRAME = struct.Struct("<Q")  # a worker's message on its pipe: the length of its pickle, then the pickle
_READ_BYTES = 1 << 16  # at most this much of a worker's pipe a read (a note is ~150 bytes; piped passes take several)
# Windows cannot wait on pipes with select: a reader thread per worker reads its pipe there
_READER_THREADS = sys.platform == "win32"
# a worker maps the scene's file (POSIX); Windows would keep a mapped file from being removed
_MAP_SCENE_FILES = sys.platform != "win32"


class WorkersUnavailable(Exception):
    """No worker process can be started here (the message says why)."""


# --------------------------------------------------------------------------- the parent side
def python_executable() -> str:
    """The interpreter to start workers with; raises WorkersUnavailable when there is none.

    Inside Blender (4.2 and 5.0) ``sys.executable`` is its bundled Python, which Blender's own
    extension manager runs for its command-line tool too (``bpy.app.binary_path_python`` is gone
    since 3.0); with bpy as a module it is the interpreter that imported bpy."""
    executable = sys.executable
    if not executable or not os.path.isfile(executable):
        raise WorkersUnavailable(f"no Python interpreter to start worker processes with "
                                 f"(sys.executable is {executable!r})")
    if os.path.basename(executable).lower().startswith("blender"):
        raise WorkersUnavailable(f"sys.executable is Blender itself ({executable}), not its Python")
    return executable


def available_memory() -> int | None:
    """Bytes of memory available to new processes (Linux's MemAvailable), None where unknown."""
    try:
        with open("/proc/meminfo") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def worker_count(requested: int, scene_bytes: int, memory: int | None) -> int:
    """Workers for a render: as many as requested (the render's thread count), at most as many
    as fit in ``memory`` (bytes available), at least one."""
    if memory is None:
        return max(requested, 1)
    per_worker = _WORKER_MEMORY + _SCENE_MEMORY_FACTOR * scene_bytes
    return max(min(requested, memory // per_worker), 1)


def share_out(rects, workers: int) -> list[tuple[int, tuple[int, int] | None]]:
    """The shares a render deals: (tile index, rows (y0, y1) of it, or None for the whole tile),
    in tile order.

    Guided: a tile is cut into bands of rows of about 1 / (``_SHARES_PER_WORKER`` x workers) of
    the pixels not yet dealt (at least ``_MIN_SHARE_PIXELS``), so the first shares are whole
    tiles and the last ones small, and a worker never waits long at the end for another's
    expensive tile.  One worker gets whole tiles."""
    left = sum((x1 - x0) * (y1 - y0) for x0, y0, x1, y1 in rects)
    shares = []
    for index, (x0, y0, x1, y1) in enumerate(rects):
        pixels, height = (x1 - x0) * (y1 - y0), y1 - y0
        target = max(left / (_SHARES_PER_WORKER * workers), _MIN_SHARE_PIXELS)
        bands = 1 if workers == 1 else max(1, min(height, round(pixels / target)))
        if bands == 1:
            shares.append((index, None))
        else:
            shares.extend((index, (y0 + height * k // bands, y0 + height * (k + 1) // bands)) for k in range(bands))
        left -= pixels
    return shares


class _Pickled:
    """A value pickled for a file, its arrays out of band (pickle protocol 5): their bytes go
    from their place into the file, not first into the pickle (moving_sphere's 5.6 MB scene:
    0.4-0.5 ms to pickle instead of 3.9-4.1, on the loaded VM), and a reader's arrays are views
    of the file's one mapping (or of the one buffer it reads it into), each at a multiple of
    ``_ALIGN`` bytes.

    An array that ``known`` (:class:`_SceneFiles`) finds byte for byte in a file written
    before is not written again: the file's table names that file and place (a texture or mesh
    that did not change between two F12s, exported again; moving_sphere's 5.5 MB of arrays are
    compared in 0.55 ms, where writing them took 2.4-3.9 ms here, and up to 24 ms while the VM's
    memory was new: docs/speed.md, session 13)."""

    _HEAD = struct.Struct("<QQ")  # the pickle's size, the number of arrays (then each array's entry)
    _ENTRY = struct.Struct("<QQQ")  # an array's size, its file (0: this one, k: the k-th named), its offset there

    def __init__(self, value, known: "_SceneFiles | None" = None):
        buffers = []  # the large arrays' (a false answer: out of band); small ones stay in the pickle
        self.pickle = pickle.dumps(value, protocol=5, buffer_callback=lambda buffer: (
            buffer.raw().nbytes < _IN_BAND_BYTES or buffers.append(buffer)))
        self.arrays = []  # the arrays written into this file
        self.named = []  # the earlier files this one's table names (each once), for the reader
        raws = [buffer.raw() for buffer in buffers]
        places = [None if known is None else known.find(array) for array in raws]
        offset = self._HEAD.size + self._ENTRY.size * len(raws) + len(self.pickle)
        entries, self._paddings = [], []  # the zeros before each array written
        for array, place in zip(raws, places):
            if place is not None:
                path, at = place
                if path not in self.named:
                    self.named.append(path)
                entries.append((array.nbytes, 1 + self.named.index(path), at))
                continue
            self._paddings.append(-offset % _ALIGN)
            offset += self._paddings[-1]
            entries.append((array.nbytes, 0, offset))
            self.arrays.append(array)
            offset += array.nbytes
        self.entries = entries  # (size, file, offset) of every array, in the pickle's order
        self._head = self._HEAD.pack(len(self.pickle), len(entries)) + b"".join(
            self._ENTRY.pack(*entry) for entry in entries)
        self.size = offset  # the bytes of its file
        self.bytes = len(self.pickle) + sum(size for size, _, _ in entries)  # the value's, its arrays written here or not

    def write(self, file):
        """Write it into the ``file`` open for writing (:attr:`size` bytes)."""
        file.write(self._head)
        file.write(self.pickle)
        for padding, array in zip(self._paddings, self.arrays):
            file.write(bytes(padding))
            file.write(array)

    def save(self, prefix: str) -> str:
        """Write it into a new file (its name starting with ``prefix``) in the first of
        ``_SHARED_FOLDERS`` with room for it, else in the temporary folder; the file's path."""
        for descriptor, path in _new_files(prefix, self.size):
            try:
                with open(descriptor, "wb") as file:
                    self.write(file)
                return path
            except OSError:  # full after all: the next folder
                _remove(path)
        descriptor, path = tempfile.mkstemp(prefix=prefix)
        with open(descriptor, "wb") as file:
            self.write(file)
        return path

    @classmethod
    def read(cls, paths):
        """The value in the file ``paths[0]`` (written by :meth:`write`; ``paths[1:]``: the files
        its table names, :attr:`named`; a lone path: a file that names none).

        Where a mapped file can still be removed (POSIX), its arrays are views of a private
        (copy-on-write) mapping of each file: the pages the parent wrote are shared, not copied
        into fresh memory (moving_sphere's 5.6 MB: 0.2 ms instead of 2.0-2.5 ms of a cold
        worker's build, which an F12 waits for); the mappings live while their arrays do.
        Elsewhere (Windows, where the parent could not remove a file a worker maps) each is read
        into memory."""
        paths = (paths,) if isinstance(paths, str) else tuple(paths)
        data = [cls._contents(paths[0])] + [None] * (len(paths) - 1)  # each named file's, once it is asked for
        pickled, count = cls._HEAD.unpack_from(data[0])
        start = cls._HEAD.size + cls._ENTRY.size * count
        buffers = []
        for size, file, offset in cls._ENTRY.iter_unpack(data[0][cls._HEAD.size:start]):
            if data[file] is None:
                data[file] = cls._contents(paths[file])
            buffers.append(data[file][offset:offset + size])
        return pickle.loads(data[0][start:start + pickled], buffers=buffers)

    @staticmethod
    def _contents(path: str) -> np.ndarray:
        """A file's bytes: a private mapping of it, or (Windows) a copy read at ``_ALIGN``."""
        with open(path, "rb") as file:
            if _MAP_SCENE_FILES:
                return np.frombuffer(mmap.mmap(file.fileno(), 0, access=mmap.ACCESS_COPY), np.uint8)
            size = os.fstat(file.fileno()).st_size
            data = np.empty(size + _ALIGN, np.uint8)
            data = data[-data.ctypes.data % _ALIGN:][:size]
            file.readinto(memoryview(data))
            return data


class _SceneFiles:
    """The files of the last scene sent, which the workers read: its own, then the earlier ones
    its table names; each named file's arrays, to find a new scene's unchanged arrays in.

    One owner (the pool).  A file goes once the scene sent last no longer names it (the workers
    that hold an earlier scene keep their mappings of it, which outlive the file).  Where the
    files hold more than twice the scene's bytes (arrays of earlier scenes no longer used beside
    the ones named), the next scene names none of the earlier files: it writes those arrays again
    and the earlier files go, so the memory they hold stays bounded."""

    def __init__(self):
        self.paths: list[str] = []  # [the scene's own file, *the files it names]
        self.bytes = 0  # of the scene's arrays and pickle: what a worker holds of it
        self._sizes: dict[str, int] = {}  # each file's size
        self._arrays: dict[int, list[tuple[str, int]]] = {}  # size -> (file, offset) of each array
        self._views: dict[str, np.ndarray] = {}  # file -> its bytes, read-only mapped here (lazily)
        self._differs = np.empty(1 << 15, bool)  # :meth:`_same`'s words compared at a time (256 KiB of each array)

    def find(self, array: memoryview) -> tuple[str, int] | None:
        """(file, offset) of an array with ``array``'s bytes in the files of the last scene (None
        also where such a file cannot be read: removed by someone else, the array is written again)."""
        for path, offset in self._arrays.get(array.nbytes, ()):
            try:
                if self._same(self._view(path)[offset:offset + array.nbytes], array):
                    return path, offset
            except (OSError, ValueError):
                pass
        return None

    def replace(self, path: str, pickled: _Pickled):
        """The scene just written into ``path`` is the last one sent: the files it does not
        name go."""
        named = {0: path, **{index: named for index, named in enumerate(pickled.named, start=1)}}
        self.clear(keep=set(named.values()))
        self._sizes[path] = pickled.size
        held = sum(self._sizes[file] for file in named.values())
        arrays: dict[int, list[tuple[str, int]]] = {}
        for size, file, offset in pickled.entries:
            if file == 0 or held <= 2 * pickled.bytes:
                arrays.setdefault(size, []).append((named[file], offset))
        self.paths, self.bytes, self._arrays = [path, *pickled.named], pickled.bytes, arrays

    def clear(self, keep=frozenset()):
        """Forget the files (and remove them) but those in ``keep``."""
        for path in self.paths:
            if path not in keep:
                self._views.pop(path, None)  # unmapped here before it is removed (Windows)
                self._sizes.pop(path, None)
                _remove(path)
        self.paths, self.bytes, self._arrays = [path for path in self.paths if path in keep], 0, {}

    def _view(self, path: str) -> np.ndarray:
        if path not in self._views:
            with open(path, "rb") as file:
                self._views[path] = np.frombuffer(mmap.mmap(file.fileno(), 0, access=mmap.ACCESS_READ), np.uint8)
        return self._views[path]

    def _same(self, stored: np.ndarray, array: memoryview) -> bool:
        """Whether an array's bytes are ``stored`` (as many), compared as 8-byte words a chunk at a
        time into one buffer (a temporary the size of the arrays would take fresh pages every
        time), stopping at the first chunk that differs."""
        fresh = np.frombuffer(array, np.uint8)  # a PickleBuffer's raw(): its bytes, one dimension
        whole = len(fresh) // 8 * 8
        old_words, new_words = stored[:whole].view(np.uint64), fresh[:whole].view(np.uint64)
        for start in range(0, len(new_words), len(self._differs)):
            differs = self._differs[:len(new_words) - start]
            np.not_equal(old_words[start:start + len(differs)], new_words[start:start + len(differs)], out=differs)
            if differs.any():
                return False
        return bool(np.array_equal(stored[whole:], fresh[whole:]))


def _pass_regions(image: np.ndarray, start: int, layout: dict[str, int], rect) -> dict[str, np.ndarray]:
    """The tile ``rect``'s pass arrays (h, w, channels) in a results ``image`` (float32) from
    its value ``start``: one after another in ``layout``'s order (name: channels).  The one
    place of the image's layout, for the workers writing into it and the parent reading it."""
    x0, y0, x1, y1 = rect
    pixels, regions = (x1 - x0) * (y1 - y0), {}
    for name, channels in layout.items():
        regions[name] = image[start:start + pixels * channels].reshape(y1 - y0, x1 - x0, channels)
        start += pixels * channels
    return regions


class _ResultsImage:
    """A render's pass arrays in one file mapped into this process and every worker: a worker
    writes each share into its tile's place there and sends back only a note, so no result
    passes through a pipe or a pickle, and a tile's bands are whole in place, not joined.

    The tiles this process hands out are views of the mapping (it lives while they do); the
    file itself is removed when the render ends (a worker maps it only while it writes a share),
    unless every share came in and the next render of the same size may take it again
    (:meth:`create`'s ``kept``): its pages are then already mapped here, and a tile's passes are
    read without page faults (about 1 ms of moving_sphere's 10 ms of streaming, docs/speed.md).
    Without room for the file (``path`` None) the workers send their shares' passes through their
    pipes and this process copies them into place, in a tile of its own memory made when its
    first band comes (and handed out with the tile): a tile is assembled one way either way."""

    def __init__(self, path: str | None, values: np.ndarray | None, layout: dict[str, int], offsets: list[int]):
        self.path, self.layout, self.offsets = path, layout, offsets  # offsets: each tile's first value
        self.values = values  # the mapped file's float32 values (None: no file)
        self._own: dict[int, dict[str, np.ndarray]] = {}  # without a file: tile index -> its passes here

    @classmethod
    def create(cls, rects, layout: dict[str, int], kept: "_ResultsImage | None" = None) -> "_ResultsImage":
        """The results image of tiles ``rects``: ``kept``'s file and mapping again when it has the
        size and no tile of it is held any more (:meth:`unheld`), else in a file where a folder has
        room for it, else in this process's memory (the results then come through the pipes)."""
        per_pixel = sum(layout.values())
        offsets = list(itertools.accumulate(((x1 - x0) * (y1 - y0) * per_pixel for x0, y0, x1, y1 in rects),
                                            initial=0))
        size = 4 * offsets[-1]
        if kept is not None and size and kept.values.nbytes == size and kept.unheld():
            return cls(kept.path, kept.values, layout, offsets)
        for descriptor, path in _new_files(f"restframe-tiles-{os.getpid()}-", size) if size else ():
            try:
                os.ftruncate(descriptor, size)
                mapped = mmap.mmap(descriptor, size)
            except OSError:
                os.close(descriptor)
                _remove(path)
                continue
            os.close(descriptor)
            return cls(path, np.frombuffer(mapped, np.float32), layout, offsets)
        return cls(None, None, layout, offsets)

    def unheld(self) -> bool:
        """No view of this image's values is left (no tile of its render is held): a render may
        write into it again."""
        return sys.getrefcount(self.values) == 2  # this attribute and getrefcount's argument

    def place(self, tile_index: int) -> tuple | None:
        """Where a worker writes a share of the tile (None: into no file, it sends the passes)."""
        return None if self.path is None else (self.path, self.offsets[tile_index], self.layout)

    def passes(self, tile_index: int, rect) -> dict[str, np.ndarray]:
        """The tile's pass arrays (h, w, channels): views of the image."""
        if self.values is not None:
            return _pass_regions(self.values, self.offsets[tile_index], self.layout, rect)
        if tile_index not in self._own:
            values = np.empty(self.offsets[tile_index + 1] - self.offsets[tile_index], np.float32)
            self._own[tile_index] = _pass_regions(values, 0, self.layout, rect)
        return self._own[tile_index]

    def put(self, tile_index: int, rect, rows, passes: dict):
        """Copy a share's passes that came through a pipe into their tile's place."""
        top = 0 if rows is None else rows[0] - rect[1]
        for name, region in self.passes(tile_index, rect).items():
            region[top:top + len(passes[name])] = passes[name]

    def tile(self, tile_index: int, rect) -> Tile:
        """The whole tile, once every share of it is in (handed out: this image no longer holds it)."""
        passes = self.passes(tile_index, rect)
        self._own.pop(tile_index, None)
        return Tile(*rect, passes)


def _new_files(prefix: str, size: int) -> Iterator[tuple[int, str]]:
    """New files (descriptor, path) for ``size`` bytes, one in each of ``_SHARED_FOLDERS`` that has
    room for them twice over (a full tmpfs would kill a worker writing to its mapping: SIGBUS), in
    that order: the caller takes the first it can fill and removes the others it is given."""
    for folder in _SHARED_FOLDERS:
        try:
            if not os.path.isdir(folder) or shutil.disk_usage(folder).free < 2 * size:
                continue
            made = tempfile.mkstemp(prefix=prefix, dir=folder)
        except OSError:
            continue
        yield made


def _write_share(place, rect, rows, passes: dict, mapping: "_ResultsMapping | None" = None) -> bool:
    """Write a share's passes into its tile's ``place`` = (file, first value, layout) in a results
    image (worker side); False (nothing written) when they are not the passes the layout expects
    or the image is gone (its render ended: Esc).  Through ``mapping``, the worker's kept
    mapping of the image (None: mapped for this share alone)."""
    path, offset, layout = place
    x0, y0, x1, y1 = rect
    top, bottom = (0, y1 - y0) if rows is None else (rows[0] - y0, rows[1] - y0)
    if passes.keys() != layout.keys() or any(passes[name].shape != (bottom - top, x1 - x0, channels)
                                             for name, channels in layout.items()):
        return False
    mapping = mapping if mapping is not None else _ResultsMapping()
    try:
        regions = _pass_regions(mapping.values(path), offset, layout, rect)
    except (OSError, ValueError):  # gone, or emptied
        mapping.release()
        return False
    for name, region in regions.items():
        region[top:bottom] = passes[name]
    del regions, region  # no view may outlive the mapping
    mapping.kept_or_released()
    return True


class _ResultsMapping:
    """A worker's mapping of the results image it writes its shares into, kept for the next
    shares and renders into the same file (the parent keeps a small image for the next render
    of its size): its pages are then mapped here already, where a mapping made for each share
    faults in every page of its tile again (moving_sphere's 256-px tiles: 0.69 ms a share, 0.05 ms
    into a kept mapping; the bars' 64-px ones 0.07 / 0.005 ms).  Kept only for an image the parent
    may keep too (at most ``_KEPT_RESULTS_BYTES``) and where a mapped file can still be removed
    (POSIX); let go when another image comes, and when the worker is idle and its file is gone
    (:meth:`release_if_gone`), so that no finished render's image stays in memory for a worker."""

    def __init__(self):
        self._identity = None  # (device, inode) of the mapped file: a new file may reuse a removed one's name
        self._path = self._mapped = self._values = None

    @property
    def held(self) -> bool:
        return self._mapped is not None

    def values(self, path: str) -> np.ndarray:
        """The float32 values of the results image ``path``, mapped (raises OSError when it is gone)."""
        status = os.stat(path)
        identity = (status.st_dev, status.st_ino)
        if identity != self._identity:
            self.release()
            with open(path, "r+b") as image:
                self._mapped = mmap.mmap(image.fileno(), 0)
            self._path, self._identity = path, identity
            self._values = np.frombuffer(self._mapped, np.float32)
        return self._values

    def kept_or_released(self):
        """After a share: keep the mapping for the next where that pays, else let it go."""
        if not _MAP_SCENE_FILES or self._values is None or self._values.nbytes > _KEPT_RESULTS_BYTES:
            self.release()

    def release_if_gone(self):
        """Let the mapping go if its file was removed or replaced (the parent did not keep it)."""
        try:
            status = os.stat(self._path)
            gone = (status.st_dev, status.st_ino) != self._identity
        except OSError:
            gone = True
        if gone:
            self.release()

    def release(self):
        self._values = None
        if self._mapped is not None:
            self._mapped.close()
        self._path, self._identity, self._mapped = None, None, None


@dataclasses.dataclass
class RenderStats:
    """Where a process render's time went, for the benchmark.  Times are ``time.monotonic()``
    (one clock for every process of the machine); cpu: CPU seconds of the thread doing it."""

    started: float
    ended: float = 0.0
    workers: int = 0
    shares: int = 0  # work units dealt (tiles, or bands of their rows)
    in_place: int = 0  # shares a worker wrote into the results image (the others came through its pipe)
    pickling: float = 0.0  # this process pickling the scene (0: sent before; built ahead: pickled then)
    sending: float = 0.0  # writing the scene's file and telling the workers (CPU)
    loop_cpu: float = 0.0  # the render loop handling messages (dealing, receiving, placing piped bands), this thread
    polling_cpu: float = 0.0  # its checks for Esc while no message came (every _POLL s: it grows with the wall time)
    receiving_cpu: float = 0.0  # the reader threads unpickling the workers' messages
    caller: float = 0.0  # wall time the caller spent between tiles (the engine: streaming a tile into Blender's result)
    caller_cpu: float = 0.0  # the same in CPU seconds of this thread (what it costs, whatever the machine's load)
    builds: dict = dataclasses.field(default_factory=dict)  # worker pid -> (start, end, cpu) of rebuilding the scene
    rendered: dict = dataclasses.field(default_factory=dict)  # pid -> [(tile index, pixels, start, end, cpu)] per share

    @property
    def parent_seconds(self) -> float:
        """This process's own work for the render: what runs beside or between the workers' tiles."""
        return self.pickling + self.sending + self.loop_cpu + self.receiving_cpu + self.caller_cpu


def _parent_packages(module_name: str) -> list[tuple[str, list[str]]]:
    """The packages above RESTframe's own (``restframe_addon``), with their folders: inside
    Blender ``bl_ext`` (a plain module there, no folder), ``bl_ext.<repo>`` and
    ``bl_ext.<repo>.<id>``; none from the repository."""
    parts = module_name.split(".")
    top = parts.index("restframe_addon")
    names = [".".join(parts[:i]) for i in range(1, top + 1)]
    return [(name, list(getattr(sys.modules[name], "__path__", []))) for name in names]


class _Worker:
    """One worker process, its pipes and the tiles dealt to it."""

    def __init__(self, executable: str, environment: dict, inbox: _Inbox):
        boot = {"path": list(sys.path), "module": __name__, "parent_pid": os.getpid(),
                "parents": _parent_packages(__name__)}
        self.process = subprocess.Popen(
            # -I: isolated (neither the script's folder nor the environment's PYTHON* variables are used)
            [executable, "-I", os.path.join(os.path.dirname(os.path.abspath(__file__)), "worker_boot.py")],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=environment,
            creationflags=getattr(subprocess, "CREATE_NO_WINDOW", 0))  # Windows: no console window per worker
        self.started = time.monotonic()
        self.ready = False
        self.alive = True
        self.scene_id = None  # the scene it holds
        self.measured = None  # (scene id, measurements) it was last sent
        self.dealt: dict[int, tuple] = {}  # share id -> (tile index, rows), of the current render
        self.receiving_cpu = 0.0  # CPU seconds spent reading and unpickling its messages
        self.posted: list[bytes] = []  # pickled messages for its next write
        self.send(boot)
        self._inbox = inbox
        inbox.add(self)

    @property
    def pid(self) -> int:
        return self.process.pid

    def post(self, message):
        """Queue ``message`` for the next :meth:`send` (one write for several: each write costs
        both processes a system call, and the worker a wake-up)."""
        self.posted.append(pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL))

    def send(self, *messages) -> bool:
        """Pickle ``messages`` to the worker, after those posted, in one write; False once it is gone."""
        for message in messages:
            self.post(message)
        if not self.alive or not self.posted:
            self.posted.clear()
            return self.alive
        try:
            self.process.stdin.write(b"".join(self.posted))
            self.process.stdin.flush()
        except (OSError, ValueError):
            self.alive = False
        self.posted.clear()
        return self.alive

    def close(self, wait: float = 1.0):
        """"exit" and EOF on its stdin end the worker; kill it if it has not ended after ``wait``
        seconds.  (EOF alone means its parent died: it then removes the scene's file.)"""
        self.send(("exit",))
        self.alive = False
        self._inbox.remove(self)
        try:
            self.process.stdin.close()
        except OSError:
            pass
        try:
            self.process.wait(wait)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()


class _Inbox:
    """The workers' messages, (worker, message) in the order they come.

    Where the platform can wait on pipes (POSIX), the render loop reads them itself, waiting on
    every worker's pipe at once (``selectors``), so a message costs one read and one unpickling
    in that thread.  Elsewhere (Windows) a reader thread per worker reads its pipe into a queue,
    which costs each message a thread's wake-up and a hand-off besides.  A message is framed by
    its length (:data:`_FRAME`); a worker's end of file (it ended or died) is its ("dead",)."""

    def __init__(self, reader_threads: bool | None = None):
        self._queue: queue.Queue = queue.Queue()  # reader threads: what they read
        self._read: collections.deque = collections.deque()  # this thread: read, not yet taken
        use_threads = _READER_THREADS if reader_threads is None else reader_threads
        self._selector = None if use_threads else selectors.DefaultSelector()
        self.in_this_thread = self._selector is not None  # whether get() reads the pipes (and its CPU is the caller's)
        self._buffer = bytearray(_READ_BYTES)  # this thread's reads land here (a reader thread has its own)

    def add(self, worker: _Worker):
        """Read ``worker``'s messages from now on."""
        if self._selector is None:
            threading.Thread(target=self._read_thread, args=(worker,), name=f"restframe-worker-{worker.pid}",
                             daemon=True).start()
        else:
            self._selector.register(worker.process.stdout.fileno(), selectors.EVENT_READ, (worker, bytearray()))

    def get(self, timeout: float):
        """The next (worker, message); raises queue.Empty when none came within ``timeout`` seconds."""
        if self._selector is None:
            return self._queue.get(timeout=timeout)
        deadline = time.monotonic() + timeout
        while not self._read:
            left = deadline - time.monotonic()
            if not self._selector.get_map():
                raise queue.Empty
            for key, _ in self._selector.select(max(left, 0.0)):
                self._read_ready(key)
            if left <= 0 and not self._read:
                raise queue.Empty
        return self._read.popleft()

    def take(self, timeout: float) -> list:
        """Every (worker, message) that came, waiting up to ``timeout`` seconds for the first
        (none: an empty list)."""
        try:
            messages = [self.get(timeout)]
        except queue.Empty:
            return []
        if self._selector is None:
            while not self._queue.empty():
                messages.append(self._queue.get_nowait())
            return messages
        for key, _ in self._selector.select(0):
            self._read_ready(key)
        messages.extend(self._read)
        self._read.clear()
        return messages

    def _read_ready(self, key):
        """Read what ``key``'s pipe holds (select said it would not block) and take its whole messages."""
        worker, pending = key.data
        if not self._read_chunk(worker, pending, self._buffer, self._read.append):  # EOF: the worker is gone
            self._selector.unregister(key.fd)
            self._read.append((worker, ("dead",)))

    def _read_thread(self, worker: _Worker):
        pending, buffer = bytearray(), bytearray(_READ_BYTES)
        try:
            while self._read_chunk(worker, pending, buffer, self._queue.put):
                pass
        except Exception:  # a message that does not unpickle: the worker cannot be trusted
            pass
        self._queue.put((worker, ("dead",)))  # EOF or a broken pipe: the worker is gone

    @staticmethod
    def _read_chunk(worker: _Worker, pending: bytearray, buffer: bytearray, take) -> bool:
        """One read of ``worker``'s pipe (blocking until it holds something) into ``buffer``, then
        appended to ``pending``; ``take((worker, message))`` for each message it completes.  False
        at its end of file.  The same buffer for every read: ``os.read`` of a large size allocates
        a fresh one each time (1 MiB: a mapping made and unmapped, 13 us a read here)."""
        cpu = time.thread_time()
        try:
            count = worker.process.stdout.raw.readinto(buffer)
        except (OSError, ValueError):
            count = 0
        if count:
            pending += memoryview(buffer)[:count]
            for message in _messages(pending):
                take((worker, message))
        worker.receiving_cpu += time.thread_time() - cpu
        return bool(count)

    def remove(self, worker: _Worker):
        """Stop reading ``worker``'s pipe (it is being closed; its reader thread ends at its EOF)."""
        if self._selector is not None and worker.process.stdout.fileno() in self._selector.get_map():
            self._selector.unregister(worker.process.stdout.fileno())


def _messages(pending: bytearray) -> list:
    """The whole messages at the start of ``pending`` (framed by :data:`_FRAME`), which loses
    them: what is left is the start of the next message.  The one place that reads the framing."""
    messages, start = [], 0
    while len(pending) - start >= _FRAME.size:
        (size,) = _FRAME.unpack_from(pending, start)
        if len(pending) - start - _FRAME.size < size:
            break
        start += _FRAME.size
        messages.append(pickle.loads(memoryview(pending)[start:start + size]))
        start += size
    del pending[:start]
    return messages


class _Pace:
    """How fast a render's shares go, so that its loop wakes once for several short shares.

    Each wake-up costs this process about as much CPU as the work it then does (on the 2-core VM
    measured, 60-250 us of cold caches after sleeping while the workers render; the 11x11 bars
    took 0.2-0.3 ms of the parent's CPU per 12-ms share).  So while shares take less than
    ``_BATCH`` a worker, the loop deals each worker work for twice ``_BATCH`` (so none runs dry
    meanwhile) and sleeps ``_BATCH`` at a time, then handles every share that came.  Towards the
    end, with less than a few such lots left a worker, it deals two shares at a time, so no
    worker waits at the end while another works through its queue, and sleeps at most half the
    work a worker holds."""

    def __init__(self, shares, rects):
        self._pixels = []  # each share's pixels
        for tile, rows in shares:
            x0, y0, x1, y1 = rects[tile]
            self._pixels.append((x1 - x0) * ((y1 - y0) if rows is None else rows[1] - rows[0]))
        self._shares_finished, self._pixels_finished, self._seconds_finished = 0, 0, 0.0  # wall seconds

    def finished(self, share: int, seconds: float) -> int:
        """Count a share finished after ``seconds``; its pixels."""
        self._shares_finished += 1
        self._pixels_finished += self._pixels[share]
        self._seconds_finished += seconds
        return self._pixels[share]

    def _share_seconds(self) -> float | None:
        """Wall seconds a finished share took on average (None: none finished yet)."""
        return self._seconds_finished / self._shares_finished if self._shares_finished else None

    def seconds(self, shares) -> float:
        """The estimated work of ``shares`` (share ids), in seconds."""
        per_pixel = self._seconds_finished / max(self._pixels_finished, 1)
        return per_pixel * sum(self._pixels[share] for share in shares)

    def wants(self, worker: _Worker, batching: bool, tail: bool = False) -> bool:
        """Whether ``worker`` is to be dealt another share (``batching``: :meth:`batching`; ``tail``:
        :meth:`tail`; decided once a round)."""
        if tail:
            return not worker.dealt
        return len(worker.dealt) < _TILES_IN_FLIGHT or (batching and self.seconds(worker.dealt) < 2 * _BATCH)

    def tail(self, todo, workers: int) -> bool:
        """Whether the render is in its tail: few shares left to deal (``_TAIL_SHARES`` a worker),
        long ones (``_TAIL_SECONDS``), and someone to balance with.  Simulated with moving_sphere's
        measured band costs (tests/bench/sim_shares.py), a worker then holding one share instead
        of two evens out the workers' ends: 16 workers 0.76-0.77 -> 0.84-0.86 of the ideal, 8 workers
        0.85-0.88 -> 0.91-0.92, 2 workers 0.98-0.99 as before."""
        share_seconds = self._share_seconds()
        return (workers > 1 and share_seconds is not None and share_seconds >= _TAIL_SECONDS
                and len(todo) <= _TAIL_SHARES * workers)

    def pause(self, workers, todo=()) -> float:
        """Seconds the loop may sleep before it handles what came: 0 (wait for each message) unless
        shares come faster than one a ``_BATCH``; then at most ``_BATCH`` and half the work a
        worker holds, so that none runs dry.  0 in the tail (a worker waits for its next share) and
        once nothing is left to deal and no worker holds more than ``_TILES_IN_FLIGHT`` shares: the
        render ends with those, and a sleep would hold its end (and the caller's work on the tiles)
        up to half of them (the 11x11 bars on one worker: 0.4-8.7 ms of its 0.16 s), for at most
        ``_TILES_IN_FLIGHT`` wake-ups a worker."""
        share_seconds = self._share_seconds()
        if (share_seconds is None or share_seconds >= len(workers) * _BATCH or self.tail(todo, len(workers))
                or not todo and all(len(worker.dealt) <= _TILES_IN_FLIGHT for worker in workers)):
            return 0.0
        return min(_BATCH, min(self.seconds(worker.dealt) for worker in workers) / 2)

    def batching(self, todo, workers: int) -> bool:
        """Whether a worker may hold work for 2 ``_BATCH``: shares come faster than one a batch and
        enough is left a worker that none waits at the end for another's queue."""
        share_seconds = self._share_seconds()
        return (share_seconds is not None and share_seconds < workers * _BATCH
                and (workers == 1 or self.seconds(share for share, _ in todo) > 4 * _BATCH * workers))


class WorkerPool:
    """Worker processes rendering tiles of one prepared scene at a time."""

    def __init__(self, environment: dict | None = None):
        """``environment``: the workers' environment variables (default: this process's with the
        malloc tuning and one BLAS thread)."""
        self._environment = environment if environment is not None else {
            **os.environ, **MALLOC_TUNING, **_ONE_BLAS_THREAD}
        self._workers: list[_Worker] = []
        self._inbox = _Inbox()  # (worker, message) from every worker
        self._busy = threading.Lock()  # one render at a time
        self._jobs = itertools.count(1)
        self._scene_ids = itertools.count(1)
        self._sent_scene = None  # (weakref to the scene, its settings pickled, its id) last pickled
        self._scene_files = _SceneFiles()  # the files holding its pickle and arrays, which the workers read
        self._ahead = None  # (scene id, pickling, sending) of a scene sent by build_ahead, for its render's stats
        self._unremoved: list[str] = []  # results images still mapped when their render ended (Windows)
        weakref.finalize(self, _remove_all, self._unremoved)
        # the last render's results image when every share of it came in (no worker writes into it
        # again): the next render of its size takes it (_ResultsImage.create), else its file goes
        self._kept: list[_ResultsImage] = []
        weakref.finalize(self, _remove_images, self._kept)
        weakref.finalize(self, self._scene_files.clear)  # when the pool goes (at exit at the latest)
        self._tokens = itertools.count(1)
        self._broken = None  # why workers cannot run here, once every worker of a render died before it was ready
        self.last_stats: RenderStats | None = None  # of the last render in worker processes

    @property
    def pids(self) -> list[int]:
        return [worker.pid for worker in self._workers if worker.alive]

    def render(self, prepared: PreparedScene, should_stop: Callable[[], bool], count: int,
               warn: Callable[[str], None] | None = None) -> Iterator[Tile]:
        """Yield the tiles of the prepared scene's region as they complete, rendered by up to
        ``count`` workers; in threads, after ``warn(message)``, where none can be started or
        another render holds the pool.  Returns early once ``should_stop()`` is true."""
        warn = warn or (lambda message: None)
        rects = prepared.tiles()
        if not self._busy.acquire(blocking=False):
            warn("the worker processes are busy with another render: rendering in threads")
            yield from tiles_in_threads(prepared, rects, count, should_stop)
            return
        try:
            yield from self._render(prepared, rects, should_stop, count, warn)
        finally:
            self._busy.release()

    def build_ahead(self, scene: Scene, settings: RenderSettings, count: int) -> None:
        """Have up to ``count`` workers build ``scene`` with ``settings`` while this process
        prepares it (its build and pre-passes), so that the render of the prepared scene finds
        it built, instead of waiting for every worker to build it then.  Nothing happens where
        another render holds the pool or no worker can start (the render says why)."""
        if not self._busy.acquire(blocking=False):
            return
        try:
            self._start(0)  # raises where no worker can start: then nothing is pickled
            stats = RenderStats(time.monotonic())
            scene_id = self._scene_id(scene, settings, stats)
            ahead = self._start(worker_count(count, self._scene_files.bytes, available_memory()))
            self._send_scene(ahead, scene_id, stats)
            sending = time.thread_time()
            for worker in ahead:  # now: they build while this process prepares
                worker.send()
            stats.sending += time.thread_time() - sending
            self._ahead = (scene_id, stats.pickling, stats.sending)
        except WorkersUnavailable:
            pass
        finally:
            self._busy.release()

    def _render(self, prepared, rects, should_stop, count, warn):
        stats = RenderStats(time.monotonic())
        scene_id = self._scene_id(prepared.scene, prepared.settings, stats)
        if self._ahead is not None and self._ahead[0] == scene_id:  # its pickling and sending count for this render
            stats.pickling, stats.sending = self._ahead[1:]
        self._ahead = None
        try:
            workers = self._start(worker_count(count, self._scene_files.bytes, available_memory()))
        except WorkersUnavailable as error:
            self._forget_scene()
            warn(f"{error}: rendering in threads")
            yield from tiles_in_threads(prepared, rects, count, should_stop)
            return
        self.last_stats = stats
        job = next(self._jobs)
        for worker in self._workers:
            worker.dealt = {}
        receiving = {worker: worker.receiving_cpu for worker in workers}
        self._send_scene(workers, scene_id, stats, prepared.measurements)
        cpu = time.thread_time()
        kept = self._kept.pop() if self._kept else None
        results = _ResultsImage.create(rects, {name: ALL_PASSES[name] for name in ("Combined", *prepared.passes)},
                                       kept)
        if kept is not None and results.values is not kept.values:
            self._unremoved.append(kept.path)
        del kept
        _remove_all(self._unremoved)
        shares = share_out(rects, len(workers))
        stats.workers, stats.shares = len(workers), len(shares)
        todo = collections.deque(enumerate(shares))  # (share id, (tile index, rows))
        pace = _Pace(shares, rects)
        bands = collections.Counter(tile for tile, _ in shares)  # shares of each tile not yet in
        done = set()  # tiles yielded
        try:
            while len(done) < len(rects):
                iteration = time.thread_time()
                if should_stop():
                    return
                if todo:  # once every share is dealt, each wake-up (a finished share) would ask every worker for
                    # nothing (~13 us with 16); what was posted went with the deal of the last share
                    self._deal(workers, todo, job, scene_id, rects, results, pace)
                workers = [worker for worker in workers if worker.alive]
                if not workers:
                    if not any(worker.ready for worker in self._workers):
                        self._broken = f"no worker process started with {sys.executable} (see the console)"
                    warn("every worker process ended: rendering the rest in threads")
                    yield from tiles_in_threads(prepared, [rect for index, rect in enumerate(rects)
                                                           if index not in done], count, should_stop)
                    return
                pause = pace.pause(workers, todo)
                if pause > 0:
                    time.sleep(pause)
                messages = self._inbox.take(0.0 if pause > 0 else _POLL)
                if not messages:
                    self._stop_stuck(workers)
                    stats.polling_cpu += time.thread_time() - iteration
                    continue
                finished = []
                for worker, message in messages:
                    received = self._receive(worker, message, job, todo, scene_id, stats, pace)
                    if received is None:
                        continue
                    tile_index, rows, passes = received
                    if passes is not None:  # it came through the pipe
                        results.put(tile_index, rects[tile_index], rows, passes)
                    bands[tile_index] -= 1
                    if bands[tile_index] == 0:
                        finished.append((tile_index, results.tile(tile_index, rects[tile_index])))
                for position, (tile_index, tile) in enumerate(finished, start=1):
                    tile.more_ready = position < len(finished)
                    if should_stop():  # Esc: not another tile, even one finished in the same round
                        return
                    done.add(tile_index)
                    handed, cpu_handed = time.monotonic(), time.thread_time()
                    stats.loop_cpu += cpu_handed - cpu
                    yield tile
                    cpu = time.thread_time()
                    stats.caller += time.monotonic() - handed
                    stats.caller_cpu += cpu - cpu_handed
        finally:
            if len(done) < len(rects):  # Esc, an error, or the caller stopped iterating: free the workers at once
                for worker in workers:
                    worker.send(("cancel", job))
            if (results.path is not None and results.values.nbytes <= _KEPT_RESULTS_BYTES and len(done) == len(rects)
                    and not any(worker.dealt for worker in workers)):
                self._kept.append(results)  # no share of it is out: for the next render of its size
            elif results.path is not None and not _remove(results.path):  # mapped here while the tiles live
                self._unremoved.append(results.path)  # Windows: removed once they are gone
            stats.receiving_cpu = sum(worker.receiving_cpu - before for worker, before in receiving.items())
            stats.loop_cpu += (time.thread_time() - cpu - stats.polling_cpu
                               - (stats.receiving_cpu if self._inbox.in_this_thread else 0.0))
            stats.ended = time.monotonic()

    def _send_scene(self, workers, scene_id: int, stats: RenderStats, measurements=None):
        """Post the scene ``scene_id`` to the workers that do not hold it, and the pre-passes'
        ``measurements`` of its prepared scene (None: not yet, :meth:`build_ahead`) to those
        that do not have them: written with their first shares (a worker that dies before
        gets none again: it is not dealt any)."""
        sending = time.thread_time()
        measured = None if measurements is None else (scene_id, measurements)
        for worker in workers:
            if worker.scene_id != scene_id:
                worker.post(("scene", scene_id, tuple(self._scene_files.paths)))
                worker.scene_id, worker.measured = scene_id, None
            if measured is not None and worker.measured != measured:
                worker.post(("measured", *measured))
                worker.measured = measured
        stats.sending += time.thread_time() - sending

    def _scene_id(self, scene: Scene, settings: RenderSettings, stats: RenderStats) -> int:
        """The id of the scene and settings, pickled once into a new file of ``_scene_files`` (kept
        for workers started later; its arrays that the previous scene's files hold are named, not
        written again, and the files it does not name go); the same scene with the same settings
        (rendered again, or built ahead) keeps its id and is not pickled or sent again."""
        settings_pickle = pickle.dumps(settings, protocol=pickle.HIGHEST_PROTOCOL)
        if (self._sent_scene is None or self._sent_scene[0]() is not scene
                or self._sent_scene[1] != settings_pickle):
            pickling = time.thread_time()
            self._sent_scene = None
            pickled = _Pickled((scene, settings), self._scene_files)
            stats.pickling = time.thread_time() - pickling
            writing = time.thread_time()
            self._scene_files.replace(pickled.save(f"restframe-scene-{os.getpid()}-"), pickled)
            stats.sending = time.thread_time() - writing
            self._sent_scene = (weakref.ref(scene), settings_pickle, next(self._scene_ids))
        return self._sent_scene[2]

    def _forget_scene(self):
        """Remove the files of the scene sent last (workers that hold it have read them)."""
        self._scene_files.clear()
        self._sent_scene = None

    def _start(self, count: int) -> list[_Worker]:
        """``count`` live workers, starting the missing ones."""
        self._workers = [worker for worker in self._workers if worker.alive]
        if self._broken:
            raise WorkersUnavailable(self._broken)
        executable = python_executable()
        while len(self._workers) < count:
            try:
                self._workers.append(_Worker(executable, self._environment, self._inbox))
            except OSError as error:
                if not self._workers:
                    raise WorkersUnavailable(f"cannot start a worker process with {executable}: {error}") from None
                break
        return self._workers[:count]

    def _deal(self, workers, todo, job, scene_id, rects, results, pace: _Pace):
        """Deal every worker the shares it wants (``pace``: ``_TILES_IN_FLIGHT``, more while batching,
        one in the render's tail), one share per worker in turn (so the first round reaches every
        worker); each share names its tile's place in the ``results`` image (None: no image, the
        passes come back in the message)."""
        tail = pace.tail(todo, len(workers))
        batching = not tail and pace.batching(todo, len(workers))
        wanting = [worker for worker in workers if worker.alive]
        while todo and wanting:
            # a worker that wants no share now wants none later this round (what it holds only
            # grows): each turn asks only those dealt one the turn before (16 workers: half the asking)
            wanting = [worker for worker in wanting if pace.wants(worker, batching, tail)]
            for worker in wanting[:len(todo)]:
                share, (tile_index, rows) = todo.popleft()
                worker.post(("tile", job, scene_id, share, rects[tile_index], rows, results.place(tile_index)))
                worker.dealt[share] = (tile_index, rows)
        for worker in workers:  # one write a worker for all it was dealt (and what was posted before)
            if worker.posted and worker.alive and not worker.send():
                self._lost(worker, todo)

    def _lost(self, worker: _Worker, todo):
        """A worker ended: its shares go back to the front of the queue."""
        worker.alive = False
        todo.extendleft(sorted(worker.dealt.items(), reverse=True))
        worker.dealt = {}
        worker.close(wait=0.0)

    def _stop_stuck(self, workers):
        """A worker that has not said it is ready long after it started is ended (and its tiles dealt again)."""
        for worker in workers:
            if not worker.ready and time.monotonic() - worker.started > _START_TIMEOUT:
                worker.process.kill()

    def _receive(self, worker: _Worker, message, job: int, todo, scene_id: int, stats: RenderStats, pace: _Pace):
        """Handle one message of a worker; (tile index, rows, passes) when it is a finished share
        of this render (passes None: written into the results image)."""
        kind = message[0]
        if kind == "dead":
            if worker.alive or worker.dealt:
                self._lost(worker, todo)
            return None
        if kind == "ready":
            worker.ready = True
        elif kind == "built" and message[1] == scene_id:
            stats.builds[worker.pid] = message[2]
        elif kind == "error" and message[1] == job:
            raise message[2]
        elif kind == "tile" and message[1] == job:
            _, _, share, complete, passes, (started, ended, cpu) = message
            unit = worker.dealt.pop(share, None)
            if unit is not None and complete:
                pixels = pace.finished(share, ended - started)
                stats.rendered.setdefault(worker.pid, []).append((unit[0], pixels, started, ended, cpu))
                stats.in_place += passes is None
                return (*unit, passes)
            if unit is not None:  # cut short although this render goes on: deal it again
                todo.appendleft((share, unit))
        return None  # a message of an earlier render

    def status(self, timeout: float = 60.0) -> dict[int, dict]:
        """Each live worker's answer once it has dealt with everything sent before (when no render
        runs): {pid: {"modules": its sys.modules names, "late_shares": whether each share of an
        earlier render that arrived since the last status was complete (False: cut short by Esc)}}."""
        with self._busy:
            token = next(self._tokens)
            waiting = {worker: {"late_shares": []} for worker in self._workers if worker.send(("status", token))}
            deadline = time.monotonic() + timeout
            while any("modules" not in answer for answer in waiting.values()) and time.monotonic() < deadline:
                try:
                    worker, message = self._inbox.get(timeout=_POLL)
                except queue.Empty:
                    continue
                if worker not in waiting:
                    continue
                if message[0] == "status" and message[1] == token:
                    waiting[worker]["modules"] = message[2]
                elif message[0] == "tile":
                    waiting[worker]["late_shares"].append(message[3])
                elif message[0] == "dead":
                    worker.alive = False
                    waiting.pop(worker)
            return {worker.pid: answer for worker, answer in waiting.items()}

    def close(self):
        """End every worker (they end by themselves when this process ends)."""
        for worker in self._workers:
            worker.close()
        self._workers = []
        self._forget_scene()
        self._unremoved.extend(image.path for image in self._kept)
        self._kept.clear()
        _remove_all(self._unremoved)


_pool: WorkerPool | None = None
_pool_lock = threading.Lock()


def pool() -> WorkerPool:
    """The session's worker pool (started lazily, kept warm until :func:`shutdown` or exit)."""
    global _pool
    with _pool_lock:
        if _pool is None:
            _pool = WorkerPool()
            atexit.register(shutdown)
        return _pool


def shutdown():
    """End the session's workers (the extension is disabled or the process exits)."""
    global _pool
    with _pool_lock:
        if _pool is not None:
            _pool.close()
            _pool = None


def build_ahead(scene: Scene, settings: RenderSettings) -> None:
    """:meth:`WorkerPool.build_ahead` on the session's pool, for a render in worker processes:
    call it before preparing the scene (the workers build while this process prepares)."""
    if settings.parallelism == "PROCESSES":
        pool().build_ahead(scene, settings, render_workers(settings.threads))


def render_tiles(prepared: PreparedScene, should_stop: Callable[[], bool], count: int,
                 warn: Callable[[str], None] | None = None) -> Iterator[Tile]:
    """:meth:`WorkerPool.render` on the session's pool."""
    yield from pool().render(prepared, should_stop, count, warn)


# --------------------------------------------------------------------------- the worker side
def serve(commands, results, parent_pid: int):
    """A worker's loop (started by :mod:`.worker_boot`): scenes and tiles in, tiles out."""
    _batch_scheduling()
    inbox: queue.Queue = queue.Queue()
    cancelled = [0]  # renders up to this job were cancelled (Esc)
    # the files of the last scene and results image sent: removed here if the parent dies without doing it
    scene_files, results_file = [()], [None]

    def orphaned():
        for path in (*scene_files[0], results_file[0]):
            if path is not None:
                _remove(path)
        os._exit(0)

    def terminated(signum, frame):
        """SIGTERM, often to the whole process group: if the parent goes too (a plain Python
        parent dies of it without removing anything), remove the scene's file for it."""
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline:
            if not _process_alive(parent_pid):
                orphaned()
            time.sleep(0.02)
        os._exit(0)

    signal.signal(signal.SIGTERM, terminated)

    def read():
        while True:
            try:
                message = pickle.load(commands)
            except Exception:  # EOF without "exit": the parent died
                orphaned()
            if message[0] == "exit":
                os._exit(0)
            if message[0] == "scene":
                scene_files[0] = message[2]
            if message[0] == "tile" and message[6] is not None:
                results_file[0] = message[6][0]
            if message[0] == "cancel":
                cancelled[0] = max(cancelled[0], message[1])
            inbox.put(message)

    def watch_parent():
        while _process_alive(parent_pid):
            time.sleep(_WATCHDOG)
        orphaned()

    held = []  # framed messages that go with the next one sent (no one waits for them alone)

    def send(message, hold=False):
        """Send ``message`` to the parent with those held before it, in one write; ``hold``: only
        with the next (a scene's "built", which the parent then reads with the first share's note:
        a read fewer a worker and render, and no wake-up of its loop for a "built" alone, 2-4 an
        F12 on 16 workers)."""
        payload = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
        held.append(_FRAME.pack(len(payload)) + payload)
        if hold:
            return
        try:
            results.write(b"".join(held))
            results.flush()
        except OSError:  # the parent closed the pipe or died (Ctrl-C, SIGTERM): nobody waits for this tile
            os._exit(0)
        held.clear()

    threading.Thread(target=read, name="restframe-commands", daemon=True).start()
    threading.Thread(target=watch_parent, name="restframe-watchdog", daemon=True).start()
    send(("ready", os.getpid()))
    built, prepared, scene_id, cache = None, None, None, None  # built: the scene; prepared: with its measurements
    built_unseen = unseen = None  # the tiles that see nothing, of built (found as it was built) and of prepared
    geometry = GeometryCache()  # persistent data: each frame of an animation rebuilds only what changed
    mapping = _ResultsMapping()  # of the results image the last share went into
    with blas.single_threaded():
        while True:
            try:
                message = inbox.get(timeout=_WATCHDOG if mapping.held else None)
            except queue.Empty:  # idle: a render has ended
                mapping.release_if_gone()
                continue
            kind = message[0]
            if kind == "scene":
                built = prepared = cache = built_unseen = unseen = None  # the old scene's memory goes first
                scene_id = message[1]
                started, cpu = time.monotonic(), time.thread_time()
                try:
                    built = build_unmeasured(*_Pickled.read(message[2]), geometry)
                    cache = TraceCache()
                    built_unseen = warm_up(built, cache)  # (in an F12, while the parent prepares)
                except Exception as error:
                    built = _picklable(error)
                send(("built", scene_id, (started, time.monotonic(), time.thread_time() - cpu)), hold=True)
            elif kind == "measured":
                if message[1] == scene_id:
                    if isinstance(built, BaseException):
                        prepared = built
                    else:
                        prepared = measured_as(built, message[2])
                        unseen = built_unseen.measured(prepared)
            elif kind == "tile":
                _, job, tile_scene, share, rect, rows, place = message
                if job <= cancelled[0]:
                    continue
                started, cpu = time.monotonic(), time.thread_time()
                try:
                    if tile_scene != scene_id or prepared is None:
                        raise RuntimeError(f"tile of scene {tile_scene} sent to a worker holding scene {scene_id}"
                                           f"{'' if prepared else ', not measured'}")
                    if isinstance(prepared, BaseException):
                        raise prepared
                    tile = render_tile(prepared, rect, lambda job=job: job <= cancelled[0], cache, rows, unseen)
                except Exception as error:
                    send(("error", job, _picklable(error)))
                    continue
                # the passes come back through the pipe only when complete and not written in place
                piped = tile.complete and not (place is not None and _write_share(place, rect, rows, tile.passes, mapping))
                send(("tile", job, share, tile.complete, tile.passes if piped else None,
                      (started, time.monotonic(), time.thread_time() - cpu)))
            elif kind == "status":
                send(("status", message[1], sorted(sys.modules)))


def _batch_scheduling():
    """Schedule this worker (and the threads it starts) as CPU-bound batch work where the system
    can (Linux's SCHED_BATCH, at the same nice value: the same share of the cores): woken by the
    parent's message, it does not preempt the running parent, which would otherwise lose its core
    in the middle of dealing (the 11x11 bars on the 2-core VM: the second worker's first shares
    written 1.6-4.5 ms after the first's, 0.02 ms with it) or of the engine's streaming."""
    if hasattr(os, "sched_setscheduler") and hasattr(os, "SCHED_BATCH"):
        try:
            os.sched_setscheduler(0, os.SCHED_BATCH, os.sched_param(0))
        except OSError:  # not allowed here (a sandbox): the default policy
            pass


def _picklable(error: BaseException) -> BaseException:
    """The error itself when it pickles (a RenderError naming the object), else its traceback as text."""
    try:
        pickle.loads(pickle.dumps(error))
        return error
    except Exception:
        return RuntimeError("".join(traceback.format_exception(error)))


def _remove(path: str) -> bool:
    """Remove a file; False when it is still there (Windows: open or mapped)."""
    try:
        os.remove(path)
    except FileNotFoundError:  # removed already (by a worker or the parent)
        pass
    except OSError:  # still open or mapped (Windows)
        return False
    return True


def _remove_all(paths: list[str]):
    paths[:] = [path for path in paths if not _remove(path)]


def _remove_images(images: list[_ResultsImage]):
    """Remove the files of results images (kept ones: no render writes into them again)."""
    paths = [image.path for image in images]
    images.clear()
    _remove_all(paths)


def _process_alive(pid: int) -> bool:
    """Whether the parent process still runs (POSIX: it is still our parent; Windows: its handle is not signalled)."""
    if sys.platform != "win32":
        return os.getppid() == pid
    import ctypes

    synchronize, wait_timeout = 0x00100000, 0x102
    kernel32 = ctypes.windll.kernel32
    handle = kernel32.OpenProcess(synchronize, False, pid)
    if not handle:
        return False
    try:
        return kernel32.WaitForSingleObject(handle, 0) == wait_timeout
    finally:
        kernel32.CloseHandle(handle)

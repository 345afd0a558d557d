"""Render frames and still regions on a Dask cluster (``dask.distributed``).

    python -m restframe_addon render FILE.blend -o out/f_####.exr --frames 1-250 --scheduler tcp://host:8786
    python -m restframe_addon render FILE.blend -o still.exr --frame 1 --regions 16 --workers 2

Every frame depends only on its own time and every pixel only on (pixel, sample), so a
task is one frame, or one region (Blender's render border, cropped) of one frame.  Dask
does the scheduling, retries and fault handling; this module only describes the tasks,
ships the .blend when workers cannot see it, writes finished frames atomically on the
client and assembles regions into the image a single process would have written.

Workers render through a child process (``python -m restframe_addon.distributed --serve``,
one per worker, started once): Blender as a Python module must run on its process's main
thread (bpy crashes when it renders from a Dask worker thread).  The child receives one
:class:`headless.RenderSpec` per task (as JSON) and renders it with the same code as
``python -m restframe_addon render`` (it opens the .blend afresh), with the worker's own
interpreter and ``sys.path`` and as many cores as Dask gives the worker (its thread count: the
child's tile workers do not oversubscribe a machine where Dask runs a worker per core), so a
worker must be able to ``import bpy`` and ``import restframe_addon``; the client checks that
on every worker before sending work and reports the ones that cannot.

A result carries the engine's proof that every tile was rendered; the client writes nothing
else.  A child stopped by SIGINT or SIGTERM (Ctrl-C on the worker's terminal) writes
nothing and exits, and its task is retried like a crash.

Dask is imported lazily: the extension itself never needs it.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field

from . import headless


class DistributedError(Exception):
    """A problem with the cluster, the workers or a task, reported without a traceback."""


class TaskCrashed(Exception):
    """A render child died without a RESTframe error (signal, crash): worth retrying elsewhere."""


# --------------------------------------------------------------------------- work description
@dataclass
class Job:
    """One render command: the frames (and regions) to render and where they go."""

    blend: str  # absolute path on the client
    scene: str
    output_ext: str  # ".exr", ".png", ... (what the output files are)
    frames: dict[int, str]  # frame -> output path on the client
    samples: int | None = None
    percentage: int | None = None
    resolution: tuple[int, int] = (0, 0)  # full image size in pixels (after the percentage)
    regions: int = 1
    border: tuple[int, int, int, int] | None = None  # the file's render border in pixels (None: off)
    crop: bool = False  # the border is cropped: the output is the border's pixels alone
    assets: list[str] = field(default_factory=list)  # files the .blend uses, relative to its folder
    missing_assets: list[str] = field(default_factory=list)  # absolute paths the workers must see
    scene_format: bool = False  # the output had no extension: workers use the scene's own format settings


@dataclass(frozen=True)
class Task:
    """One Dask task: a frame, or one region of it, of the job's .blend."""

    blend: str  # the client's path
    copy: str  # the name of a worker's shipped copy (the .blend's SHA-256 and the job's token)
    scene: str
    frame: int
    ext: str  # what the task's file is (".exr", ...; "" = the scene's own format)
    samples: int | None = None
    percentage: int | None = None
    region: tuple[int, int, int, int] | None = None

    def render_spec(self, blend: str, output: str, threads: int | None = None) -> headless.RenderSpec:
        return headless.RenderSpec(blend=blend, output=output, frame=self.frame, scene=self.scene,
                                   samples=self.samples, percentage=self.percentage, region=self.region,
                                   threads=threads)


def job_regions(job: Job) -> list[tuple[int, int, int, int] | None]:
    """The regions of each frame's tasks (None: the frame whole), tiling the file's render
    border if it has one, as a single render would fill it."""
    if job.regions == 1:
        return [None]
    x0, y0, x1, y1 = job.border or (0, 0, *job.resolution)
    return [(rx0 + x0, ry0 + y0, rx1 + x0, ry1 + y0) for rx0, ry0, rx1, ry1 in split_regions(x1 - x0, y1 - y0, job.regions)]


def job_canvas(job: Job) -> tuple[tuple[int, int], tuple[int, int]]:
    """(origin, size) in pixels of the image a single render writes: the border when cropped."""
    if job.border is not None and job.crop:
        x0, y0, x1, y1 = job.border
        return (x0, y0), (x1 - x0, y1 - y0)
    return (0, 0), job.resolution


def split_regions(width: int, height: int, count: int) -> list[tuple[int, int, int, int]]:
    """``count`` pixel rectangles (x0, y0, x1, y1; x1/y1 exclusive, origin bottom left) tiling
    the image in a grid of cells as square as possible."""
    if count < 1:
        raise DistributedError(f"--regions must be at least 1 (got {count})")
    if count > width * height:
        raise DistributedError(f"cannot split a {width}x{height} image into {count} regions")
    best = None
    for cols in range(1, count + 1):
        if count % cols:
            continue
        rows = count // cols
        if cols > width or rows > height:
            continue
        badness = abs(math.log((width / cols) / (height / rows)))
        if best is None or badness < best[0]:
            best = (badness, cols, rows)
    if best is None:  # a prime count too large for one row or column
        raise DistributedError(f"cannot split a {width}x{height} image into {count} regions "
                               "(use a count with a factor pair that fits the image)")
    _, cols, rows = best
    xs = [round(i * width / cols) for i in range(cols + 1)]
    ys = [round(j * height / rows) for j in range(rows + 1)]
    return [(xs[i], ys[j], xs[i + 1], ys[j + 1]) for j in range(rows) for i in range(cols)]


def file_digest(path: str) -> str:
    sha = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            sha.update(block)
    return sha.hexdigest()


def blend_assets(blend: str) -> tuple[list[str], list[str]]:
    """Files the open .blend reads besides itself (unpacked images, linked libraries and what
    those link, recursively): (paths relative to the .blend's folder, absolute paths elsewhere)."""
    import bpy

    folder = os.path.dirname(os.path.abspath(blend))
    relative, absolute = [], []

    def add(filepath: str, library) -> None:
        path = os.path.normpath(bpy.path.abspath(filepath, library=library))
        if not os.path.exists(path):
            return  # missing here too: the render warns about it wherever it runs
        inside = os.path.relpath(path, folder)
        if filepath.startswith("//") and not inside.startswith(os.pardir) and os.path.isfile(path):
            relative.append(inside)
        else:
            absolute.append(path)

    for image in bpy.data.images:
        if image.packed_file is None and image.source in {'FILE', 'SEQUENCE', 'MOVIE', 'TILED'} and image.filepath:
            add(image.filepath, image.library)
    for library in bpy.data.libraries:  # indirect ones too, each relative to the library that links it
        if library.packed_file is None and library.filepath:
            add(library.filepath, library.parent)
    return sorted(set(relative)), sorted(set(absolute))


# --------------------------------------------------------------------------- on the workers
def _child_env() -> dict[str, str]:
    """The worker's environment with its import path, so the child finds what the worker finds."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(_import_paths(sys.path))
    # Dask's nanny pins OMP/MKL/OpenBLAS to one thread and trims malloc eagerly for its own
    # worker threads; the renderer runs its own thread pool and allocates large arrays per tile
    # (measured: 4.4 s instead of 3.0 s a frame with them), so its child goes without them.
    try:
        import dask

        for key, value in (dask.config.get("distributed.nanny.pre-spawn-environ", None) or {}).items():
            if env.get(key) == str(value):
                del env[key]
    except Exception:  # no dask here (the child is started outside a worker): nothing was set
        pass
    return env


def _import_paths(paths: list[str]) -> list[str]:
    """sys.path entries worth handing to a child, less the ones bpy adds inside its own package
    (its scripts/modules hold a pure-Python ``bpy`` that would shadow the real module)."""
    keep = []
    for p in paths:
        p = p or os.getcwd()  # '' = the working directory, which the child does not share
        parts = os.path.normpath(p).split(os.sep)
        if p and os.path.isdir(p) and not ("bpy" in parts[:-1] and "site-packages" in parts):
            keep.append(p)
    return list(dict.fromkeys(keep))


def _die_with_parent() -> None:  # pragma: no cover - runs in the child before exec
    """Linux: the render child gets SIGKILL when its worker dies, so a killed worker's frame
    stops instead of finishing unseen."""
    try:
        import ctypes
        import signal

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except Exception:
        pass


def dask_cores() -> int | None:
    """The cores Dask gives this worker process (its thread count; one task renders at a time
    here), so its render child starts that many tile workers, not one per core of the machine
    where Dask already runs a worker per core; None outside a Dask worker."""
    try:
        from distributed import get_worker

        return max(int(get_worker().state.nthreads), 1)
    except (ImportError, ValueError, AttributeError):
        return None


def _local_blend(task: Task, bundle: dict | None) -> str:
    """The .blend this worker opens: the client's path when shared, else the shipped copy."""
    if bundle is None:
        return task.blend
    root = bundle_dir(task.copy)
    blend = os.path.join(root, "files", os.path.basename(task.blend))
    marker = os.path.join(root, ".complete")
    if os.path.isfile(marker):
        os.utime(marker)  # in use: not stale (_remove_stale_copies)
    else:
        staging = tempfile.mkdtemp(prefix=".staging-", dir=_makedirs(os.path.dirname(root)))
        for relative, data in bundle.items():
            target = os.path.join(staging, "files", relative)
            os.makedirs(os.path.dirname(target), exist_ok=True)
            with open(target, "wb") as fh:
                fh.write(data)
        open(os.path.join(staging, ".complete"), "w").close()
        try:
            os.rename(staging, root)  # atomic; another task of this machine may have won
        except OSError:
            shutil.rmtree(staging, ignore_errors=True)
    return blend


def _makedirs(path: str) -> str:
    os.makedirs(path, exist_ok=True)
    return path


# One long-lived render child per worker process ("render server"): it imports bpy and the
# add-on once and renders requests on its own main thread, so a task costs a render, not an
# interpreter start.  It dies with its worker (stdin closes; SIGKILL on Linux).
_server = None
_server_lock = threading.Lock()
_SERVER_START_TIMEOUT = 300.0


class _Server:
    def __init__(self):
        import collections

        _remove_stale_task_dirs()
        _remove_stale_copies()
        kwargs = {"preexec_fn": _die_with_parent} if sys.platform.startswith("linux") else {}
        self.process = subprocess.Popen(
            [sys.executable, "-m", "restframe_addon.distributed", "--serve"], stdin=subprocess.PIPE,
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=_child_env(), cwd=tempfile.gettempdir(),
            text=True, errors="replace", **kwargs)
        self.log = collections.deque(maxlen=50)  # the child's last stderr lines, for error messages
        threading.Thread(target=self._read_log, daemon=True).start()
        self.hello = self._answer()  # bpy version and add-on path, or the import error

    def _read_log(self):
        for line in self.process.stderr:
            if line.strip():
                self.log.append(line.strip())

    def _answer(self) -> dict:
        line = self.process.stdout.readline()
        if not line:
            self.process.wait()
            return {"dead": f"the render child exited with {self.process.returncode}: {self.log_tail()}"}
        return json.loads(line)

    def log_tail(self, lines: int = 5) -> str:
        time.sleep(0.2)  # let the reader thread catch the last words
        return " | ".join(list(self.log)[-lines:]) or "no output"

    def request(self, spec: headless.RenderSpec) -> dict:
        try:
            self.process.stdin.write(json.dumps({"render": spec.to_json()}) + "\n")
            self.process.stdin.flush()
        except OSError:  # it died since the last task
            self.process.wait()
            return {"dead": f"the render child exited with {self.process.returncode}: {self.log_tail()}"}
        return self._answer()

    def close(self):
        self.process.kill()
        self.process.wait(timeout=10)


def _task_dir_root() -> str:
    return os.path.join(tempfile.gettempdir(), f"restframe-dask-{os.getuid() if hasattr(os, 'getuid') else 0}")


# A shipped copy not used for this long belongs to a job whose client never said it ended
# (interrupted, or its connection lost): a worker's render server removes it when it starts.
STALE_COPY_SECONDS = 24 * 3600.0


def _remove_stale_copies(max_age: float = STALE_COPY_SECONDS) -> None:
    root = os.path.join(_task_dir_root(), "blends")
    for name in os.listdir(root) if os.path.isdir(root) else []:
        path = os.path.join(root, name)
        marker = os.path.join(path, ".complete")
        try:
            used = os.path.getmtime(marker if os.path.exists(marker) else path)
        except OSError:
            continue  # removed meanwhile by another worker
        if time.time() - used > max_age:
            shutil.rmtree(path, ignore_errors=True)


def _remove_stale_task_dirs() -> None:
    """Task folders of worker processes that died mid-frame (a killed worker cleans nothing)."""
    root = os.path.join(_task_dir_root(), "tasks")
    for name in os.listdir(root) if os.path.isdir(root) else []:
        pid = name.split("-")[0]
        if os.path.isdir("/proc") and pid.isdigit() and int(pid) != os.getpid() and not os.path.exists(f"/proc/{pid}"):
            shutil.rmtree(os.path.join(root, name), ignore_errors=True)


def bundle_dir(copy: str) -> str:
    """Where a worker keeps the .blend (and files) shipped to it for one job."""
    return os.path.join(_task_dir_root(), "blends", copy)


def remove_bundle(copy: str) -> None:
    """On a worker at the end of a job: its shipped copy goes (one job never reuses another's,
    so removing it cannot pull a file from under a running render)."""
    shutil.rmtree(bundle_dir(copy), ignore_errors=True)


def _ensure_server() -> _Server:
    """This worker's render server, started (or restarted after a crash) when needed."""
    global _server
    if _server is None or _server.process.poll() is not None:
        if _server is not None:
            _server.close()
        _server = _Server()
    return _server


def server_hello() -> dict:
    """Start this worker's render server; what it says (versions, or why it cannot render)."""
    with _server_lock:
        server = _ensure_server()
        hello = dict(server.hello)
        if "ready" not in hello:
            _forget_server()
        return hello


def _forget_server() -> None:
    global _server
    if _server is not None:
        _server.close()
        _server = None


def _serve() -> int:
    """The render server's loop: one JSON request per line on stdin, one answer per line."""
    reply = os.fdopen(os.dup(1), "w")
    os.dup2(2, 1)  # whatever Blender or the CLI prints goes to the log, not the protocol
    sys.stdout = sys.stderr

    def answer(message: dict) -> None:
        reply.write(json.dumps(message) + "\n")
        reply.flush()

    try:
        import bpy

        import restframe_addon
        import restframe_addon.engine  # noqa: F401  (the core and embreex)
        from restframe_addon.core import workers
    except BaseException as error:
        answer({"error": f"{type(error).__name__}: {error}"})
        return 1
    answer({"ready": bpy.app.version_string, "addon": os.path.dirname(restframe_addon.__file__)})
    try:
        with headless.interruptible():
            for line in sys.stdin:
                spec = headless.RenderSpec.from_json(json.loads(line)["render"])
                try:
                    outcome = headless.render(spec)
                    answer({"tiles": outcome.tiles, "total": outcome.total, "complete": outcome.complete,
                            "tile_workers": len(workers.pool().pids)})
                except headless.CommandError as error:
                    answer({"error": str(error)})
    except headless.Interrupted as interrupt:
        # stopped by a signal: nothing was written; say so (if the worker still listens) and leave
        answer({"interrupted": str(interrupt)})
        return interrupt.status
    return 0


def render_task(task: Task, bundle: dict | None = None) -> dict:
    """Render one frame (or one region of it) in this worker's render server; return the file's
    bytes with the engine's tile count as proof that it is complete (and ``tile_workers``: the
    tile worker processes the render child runs, as many as this worker's cores at most).

    Returns ``{"error": message}`` for RESTframe's own errors (bad scene: no use retrying) and
    raises :class:`TaskCrashed` when the render child died or was interrupted, so Dask retries
    the task."""
    import socket

    started = time.monotonic()
    where = f"{socket.gethostname()} (pid {os.getpid()})"
    blend = _local_blend(task, bundle)
    workdir = tempfile.mkdtemp(prefix=f"{os.getpid()}-", dir=_makedirs(os.path.join(_task_dir_root(), "tasks")))
    try:
        out = os.path.join(workdir, "result" + task.ext)
        with _server_lock:  # bpy is one per process: one render at a time per worker
            server = _ensure_server()
            if "ready" not in server.hello:
                raise TaskCrashed(f"the render child on {where} cannot start: "
                                  f"{server.hello.get('error') or server.hello.get('dead')}")
            answer = server.request(task.render_spec(blend, out, dask_cores()))
            if "interrupted" in answer:  # the child is on its way out: the next task starts a new one
                _forget_server()
        if "dead" in answer or "interrupted" in answer:
            raise TaskCrashed(f"on {where}: {answer.get('dead') or answer.get('interrupted')}")
        if "error" in answer:
            return {"error": answer["error"], "host": where}
        if not answer.get("complete"):
            raise TaskCrashed(f"on {where}: the render child returned an incomplete frame "
                              f"({answer.get('tiles')} of {answer.get('total')} tiles)")
        written = [name for name in os.listdir(workdir) if name.startswith("result")]
        if len(written) != 1:
            raise TaskCrashed(f"on {where}: the render child wrote {written or 'nothing'}")
        with open(os.path.join(workdir, written[0]), "rb") as fh:
            data = fh.read()
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    return {"data": data, "host": where, "seconds": time.monotonic() - started,
            "tiles": answer["tiles"], "total": answer["total"], "complete": True,
            "tile_workers": answer.get("tile_workers")}


def is_complete(result: dict) -> bool:
    """Whether a task's result proves that every tile of its frame or region was rendered."""
    return result.get("complete") is True and (result.get("total") or 0) > 0 and result.get("tiles") == result.get("total")


def _make_probe(blend: str, digest: str, size: int, absolute_assets: list[str]):
    """A probe for ``client.run`` that reports whether a worker can render.

    Built as a closure so cloudpickle ships it by value: it must run on workers that cannot
    import restframe_addon (that is what it finds out).  Where it can, it starts the worker's
    render server, which imports bpy and the add-on."""

    def probe():
        import hashlib as _hashlib
        import importlib as _importlib
        import os as _os
        import sys as _sys

        try:
            module = _importlib.import_module("restframe_addon.distributed")
            hello = module.server_hello()
        except Exception as error:
            hello = {"error": f"{type(error).__name__}: {error}"}
        same_blend = False
        if _os.path.isfile(blend) and _os.path.getsize(blend) == size:
            sha = _hashlib.sha256()
            with open(blend, "rb") as fh:
                for block in iter(lambda: fh.read(1 << 20), b""):
                    sha.update(block)
            same_blend = sha.hexdigest() == digest
        return {"import_ok": "ready" in hello, "output": hello.get("error") or hello.get("dead") or "",
                "python": _sys.executable, "blend_visible": same_blend,
                "assets_missing": [p for p in absolute_assets if not _os.path.exists(p)]}

    return probe


# --------------------------------------------------------------------------- on the client
class Progress:
    """One text bar for the job: tasks done, frames done, rate and ETA."""

    def __init__(self, total_tasks: int, total_frames: int, stream=None, width: int = 30):
        self.total_tasks, self.total_frames = total_tasks, total_frames
        self.tasks = self.frames = 0
        self.stream = stream or sys.stdout
        self.width = width
        self.started = time.monotonic()
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()

    def line(self) -> str:
        elapsed = time.monotonic() - self.started
        fraction = self.tasks / self.total_tasks if self.total_tasks else 1.0
        filled = int(round(fraction * self.width))
        rate = self.frames / elapsed if elapsed > 0 else 0.0
        if self.tasks and self.tasks < self.total_tasks:
            eta = f"ETA {elapsed / self.tasks * (self.total_tasks - self.tasks):.0f} s"
        else:
            eta = f"{elapsed:.1f} s" if self.tasks else "ETA --"
        return (f"restframe: [{'#' * filled}{'.' * (self.width - filled)}] {self.frames}/{self.total_frames} frames"
                f" ({self.tasks}/{self.total_tasks} tasks), {rate:.2f} frames/s, {eta}")

    def update(self, tasks: int = 0, frames: int = 0) -> None:
        self.tasks += tasks
        self.frames += frames
        if self.tty:
            self.stream.write("\r" + self.line())
            if self.tasks >= self.total_tasks:
                self.stream.write("\n")
        else:
            self.stream.write(self.line() + "\n")
        self.stream.flush()


def connect(scheduler: str | None, workers: int | None):
    """A Dask client: to ``scheduler`` if given, else to a new LocalCluster of worker
    processes (one thread each: bpy is one per process) on the loopback interface."""
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError:
        raise DistributedError("the Dask path needs dask.distributed: pip install 'dask[distributed]'") from None
    if scheduler:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as error:
            raise DistributedError(f"cannot reach the Dask scheduler at {scheduler}: {error}") from None
        except ValueError as error:  # not an address at all
            raise DistributedError(f"--scheduler {scheduler!r} is not a Dask scheduler address "
                                   f"(e.g. tcp://HOST:8786): {error}") from None
        return client, None
    import logging

    count = workers or os.cpu_count() or 1
    cluster = LocalCluster(n_workers=count, threads_per_worker=1, processes=True, host="127.0.0.1",
                           dashboard_address=":0", silence_logs=logging.ERROR)
    return Client(cluster), cluster


def check_workers(client, job: Job, digest: str, timeout: float = 60.0) -> bool:
    """Probe every worker; raise a clear error for any that cannot import the add-on (or bpy),
    or cannot see an absolute texture path.  Returns whether the .blend must be shipped."""
    try:
        client.wait_for_workers(1, timeout=timeout)
    except TimeoutError:
        raise DistributedError(f"no Dask worker joined the scheduler within {timeout:.0f} s") from None
    size = os.path.getsize(job.blend)
    results = client.run(_make_probe(job.blend, digest, size, job.missing_assets))
    broken = {address: r for address, r in results.items() if not r["import_ok"]}
    if broken:
        lines = []
        for address, r in sorted(broken.items()):
            last = r["output"].strip().splitlines()[-1] if r["output"].strip() else "no output"
            lines.append(f"  {address} ({r['python']}): {last}")
        raise DistributedError(
            f"{len(broken)} of {len(results)} Dask worker(s) cannot import the RESTframe add-on (and bpy):\n"
            + "\n".join(lines)
            + "\n  every worker needs bpy and restframe_addon importable by its Python "
              "(pip install bpy; put the add-on's parent folder on PYTHONPATH)")
    unseen = {address: r["assets_missing"] for address, r in results.items() if r["assets_missing"]}
    if unseen:
        address, paths = sorted(unseen.items())[0]
        raise DistributedError(f"worker {address} cannot see files the .blend uses by absolute path: "
                               f"{', '.join(paths[:5])} (use a shared path, relative paths or pack them)")
    return not all(r["blend_visible"] for r in results.values())


def make_bundle(job: Job) -> dict[str, bytes]:
    """The .blend and its relative files, keyed by path relative to the .blend's folder."""
    folder = os.path.dirname(job.blend)
    bundle = {}
    for relative in [os.path.basename(job.blend), *job.assets]:
        with open(os.path.join(folder, relative), "rb") as fh:
            bundle[relative] = fh.read()
    return bundle


def assemble_exr(pieces: list[tuple[tuple[int, int, int, int], bytes]], resolution: tuple[int, int]):
    """Cropped multilayer EXRs of regions -> (parts, headers) of the whole image.

    Returns a list of (part name, header, {channel: array}) in the first piece's order, with
    arrays (H, W) top row first, as OpenEXR stores them."""
    import numpy as np
    import OpenEXR

    width, height = resolution
    parts = None
    with tempfile.TemporaryDirectory(prefix="restframe-assemble-") as tmp:
        for index, ((x0, y0, x1, y1), data) in enumerate(pieces):
            path = os.path.join(tmp, f"{index}.exr")
            with open(path, "wb") as fh:
                fh.write(data)
            with OpenEXR.File(path, separate_channels=True) as exr:
                if parts is None:
                    parts = []
                    for part in exr.parts:
                        header = {k: v for k, v in part.header.items()
                                  if k not in ("channels", "chunkCount", "dataWindow", "displayWindow", "name")}
                        full = {name: np.zeros((height, width), dtype=channel.pixels.dtype)
                                for name, channel in part.channels.items()}
                        parts.append((part.name(), header, full))
                for (name, _, full), part in zip(parts, exr.parts):
                    if part.name() != name:
                        raise DistributedError(f"region {index} has part {part.name()!r} where {name!r} was expected")
                    for channel_name, channel in part.channels.items():
                        pixels = channel.pixels
                        if pixels.shape != (y1 - y0, x1 - x0):
                            raise DistributedError(f"region {(x0, y0, x1, y1)} came back as {pixels.shape[::-1]} pixels")
                        full[channel_name][height - y1:height - y0, x0:x1] = pixels
    return parts


def write_exr(parts, resolution: tuple[int, int], path: str) -> None:
    import numpy as np
    import OpenEXR

    width, height = resolution
    window = (np.array([0, 0], dtype=np.int32), np.array([width - 1, height - 1], dtype=np.int32))
    exr_parts = []
    for name, header, channels in parts:
        header = dict(header, dataWindow=window, displayWindow=window)
        exr_parts.append(OpenEXR.Part(header, {k: OpenEXR.Channel(k, v) for k, v in channels.items()}, name))

    def write(partial):
        with OpenEXR.File(exr_parts) as exr:
            exr.write(partial)

    headless.write_atomically(path, write)


def combined_rgba(parts, resolution) -> "np.ndarray":
    """The Combined pass of assembled parts as (H, W, 4) float32, row 0 at the bottom."""
    import numpy as np

    width, height = resolution
    for _, _, channels in parts:
        names = {k.rsplit(".", 1)[-1]: k for k in channels if ".Combined." in k or k.startswith("Combined.")}
        if {"R", "G", "B"} <= set(names):
            alpha = channels[names["A"]] if "A" in names else np.ones((height, width), np.float32)
            rgba = np.stack([channels[names[c]] for c in "RGB"] + [alpha], axis=2)
            return rgba[::-1].astype(np.float32)
    raise DistributedError("the assembled regions have no Combined pass")


def run_job(job: Job, scheduler: str | None = None, workers: int | None = None, retries: int = 2,
            overwrite: bool = False, write_image=None, stream=None) -> int:
    """Render ``job`` on Dask.  ``write_image(rgba, path)`` writes an assembled non-EXR still
    (Blender's colour management, on the client).  Returns the number of failed frames."""
    stream = stream or sys.stdout
    todo = {frame: path for frame, path in job.frames.items() if overwrite or not os.path.exists(path)}
    skipped = sorted(set(job.frames) - set(todo))
    if skipped:
        print(f"restframe: skipping {len(skipped)} frame(s) already on disk "
              f"({', '.join(map(str, skipped[:10]))}{', ...' if len(skipped) > 10 else ''}); "
              "--overwrite renders them again", file=stream, flush=True)
    if not todo:
        print("restframe: nothing to render", file=stream, flush=True)
        return 0
    regions = job_regions(job)
    (origin_x, origin_y), canvas = job_canvas(job)

    client, cluster = connect(scheduler, workers)
    ship = False
    try:
        from dask.distributed import as_completed

        digest = file_digest(job.blend)
        copy = f"{digest}-{os.getpid()}-{os.urandom(4).hex()}"
        ship = check_workers(client, job, digest)
        bundle = client.scatter(make_bundle(job), broadcast=False, hash=False) if ship else None
        print(f"restframe: {len(todo)} frame(s) x {len(regions)} region(s) on "
              f"{len(client.scheduler_info()['workers'])} Dask worker(s) at {client.scheduler.address}"
              + (" (the .blend is shipped to the workers)" if ship else ""), file=stream, flush=True)
        # regions assemble as EXR (full float) whatever the final format
        task_ext = ".exr" if job.regions > 1 else ("" if job.scene_format else job.output_ext)
        futures = {}
        for frame in sorted(todo):
            for index, region in enumerate(regions):
                task = Task(blend=job.blend, copy=copy, scene=job.scene, frame=frame, ext=task_ext,
                            samples=job.samples, percentage=job.percentage, region=region)
                future = client.submit(render_task, task, bundle, retries=retries, pure=False,
                                       key=f"restframe-frame{frame}-region{index}-{digest[:8]}-{os.urandom(4).hex()}")
                futures[future] = (frame, index)
        progress = Progress(len(futures), len(todo), stream)
        pieces: dict[int, dict[int, bytes]] = {}
        failed: dict[int, str] = {}
        for future in as_completed(futures):
            frame, index = futures.pop(future)
            if frame in failed:
                progress.update(tasks=1)
                continue
            try:
                result = future.result()
            except Exception as error:
                result = {"error": f"{type(error).__name__}: {error}"}
            if "error" not in result and not is_complete(result):
                result = {"error": f"the result from {result.get('host')} does not prove it is complete "
                                   f"({result.get('tiles')} of {result.get('total')} tiles): not written"}
            if "error" in result:
                message = result["error"]
                message = message[len(f"frame {frame}: "):] if message.startswith(f"frame {frame}: ") else message
                failed[frame] = message
                print(f"restframe: error: frame {frame}: {message}", file=sys.stderr, flush=True)
                progress.update(tasks=1)
                continue
            done_frame = False
            if len(regions) == 1:
                headless.write_bytes(todo[frame], result["data"])
                done_frame = True
            else:
                pieces.setdefault(frame, {})[index] = result["data"]
                if len(pieces[frame]) == len(regions):
                    on_canvas = [((x0 - origin_x, y0 - origin_y, x1 - origin_x, y1 - origin_y), pieces[frame][i])
                                 for i, (x0, y0, x1, y1) in enumerate(regions)]
                    parts = assemble_exr(on_canvas, canvas)
                    del pieces[frame]
                    if job.output_ext == ".exr":
                        write_exr(parts, canvas, todo[frame])
                    elif write_image is not None:
                        write_image(combined_rgba(parts, canvas), todo[frame])
                    else:
                        raise DistributedError(f"no writer for {job.output_ext} images")
                    done_frame = True
            progress.update(tasks=1, frames=1 if done_frame else 0)
            if done_frame:
                print(f"restframe: frame {frame} -> {todo[frame]} ({result['host']}, {result['seconds']:.2f} s)",
                      file=stream, flush=True)
        return len(failed)
    finally:
        if ship and client.status == "running":  # also when interrupted: best effort, never blocks the exit
            try:
                client.run(remove_bundle, copy)
            except Exception:
                pass  # a worker that cannot be reached cleans up at its next start (_remove_stale_copies)
        client.close()
        if cluster is not None:
            cluster.close()


if __name__ == "__main__":
    if sys.argv[1:] == ["--serve"]:
        sys.exit(_serve())
    sys.exit("usage: python -m restframe_addon.distributed --serve (started by Dask workers)")

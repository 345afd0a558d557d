"""Running the command line, reading and comparing EXR and PNG files for the Dask tests.
(Not in conftest.py: test modules importing from "conftest" would get tests/blender's.)"""

import os
import subprocess
import sys

import numpy as np
import OpenEXR

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SAMPLE = os.path.join(ROOT, "sample_blends", "moving_sphere.blend")


def cli_command(*args) -> list[str]:
    """The headless ``render`` command with ``args``, run from the repository."""
    return [sys.executable, "-m", "restframe_addon", "render", *map(str, args)]


def run_cli(*args, timeout=240):
    return subprocess.run(cli_command(*args), cwd=ROOT, capture_output=True, text=True, timeout=timeout)


def start_cli(*args) -> subprocess.Popen:
    """The ``render`` command started in the background, its output captured as text (for a test
    that signals or kills parts of it while it runs)."""
    return subprocess.Popen(cli_command(*args), cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def exr_channels(path) -> dict[str, np.ndarray]:
    """'part/channel' -> (H, W) float array of a (multi-part) EXR, in file order."""
    channels = {}
    with OpenEXR.File(str(path), separate_channels=True) as exr:
        for part in exr.parts:
            for name, channel in part.channels.items():
                channels[f"{part.name()}/{name}"] = np.asarray(channel.pixels, dtype=np.float64)
    return channels


def assert_same_exr(path, reference, atol=1e-6):
    got, want = exr_channels(path), exr_channels(reference)
    assert list(got) == list(want)  # same parts and channels, same order
    assert "ViewLayer.Combined/ViewLayer.Combined.R" in got and "ViewLayer.Doppler/ViewLayer.Doppler.X" in got
    for name in want:
        assert got[name].shape == want[name].shape, name
        np.testing.assert_allclose(got[name], want[name], rtol=0, atol=atol, err_msg=name)
    # not a blank frame: the comparison means something
    assert want["ViewLayer.Combined/ViewLayer.Combined.R"].std() > 0.01


def png_pixels(path) -> np.ndarray:
    """Decoded 8-bit pixels (H, W, C) of a PNG, through zlib only (no imaging library)."""
    import struct
    import zlib

    data = open(path, "rb").read()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, idat, header = 8, b"", None
    while pos < len(data):
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + length]
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat += body
        pos += 12 + length
    width, height, depth, colour, _, _, interlace = header
    assert depth == 8 and interlace == 0 and colour in (2, 6)
    channels = 3 if colour == 2 else 4
    raw = zlib.decompress(idat)
    stride = width * channels
    rows, prev = [], np.zeros(stride, dtype=np.int64)
    for y in range(height):
        kind = raw[y * (stride + 1)]
        line = np.frombuffer(raw, dtype=np.uint8, count=stride, offset=y * (stride + 1) + 1).astype(np.int64)
        out = np.zeros(stride, dtype=np.int64)
        for x in range(stride):
            a = out[x - channels] if x >= channels else 0
            b, c = prev[x], (prev[x - channels] if x >= channels else 0)
            if kind == 0:
                pred = 0
            elif kind == 1:
                pred = a
            elif kind == 2:
                pred = b
            elif kind == 3:
                pred = (a + b) // 2
            else:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                pred = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
            out[x] = (line[x] + pred) & 0xFF
        rows.append(out)
        prev = out
    return np.array(rows).reshape(height, width, channels)

"""Read RESTframe's multilayer EXR renders into numpy (for scripts, pipelines and tests).

Blender 5.0 writes a multilayer EXR as one part per pass, channels named
``ViewLayer.<Pass>.<Channel>`` (``ViewLayer.Combined`` holds RGBA).  Needs the
``OpenEXR`` package, which Blender does not bundle: imported on use only.
"""

from __future__ import annotations

import numpy as np


def read_passes(path, layer: str = "ViewLayer", bottom_up: bool = True) -> dict[str, np.ndarray]:
    """Pass name -> (H, W, C) float64 array; row 0 is the bottom row (Blender's order) unless
    ``bottom_up`` is False (image order, top row first)."""
    import OpenEXR

    passes: dict[str, list] = {}
    with OpenEXR.File(str(path)) as exr:
        for part in exr.parts:
            for name, channel in part.channels.items():
                pixels = np.asarray(channel.pixels, dtype=np.float64)
                if pixels.ndim == 2:
                    pixels = pixels[..., None]
                # "ViewLayer.Doppler.X" -> "Doppler"; "ViewLayer.Combined" (RGBA grouped) -> "Combined"
                pass_name = name[len(layer) + 1:] if name.startswith(layer + ".") else name
                if pixels.shape[2] == 1 and "." in pass_name:
                    pass_name = pass_name.rsplit(".", 1)[0]
                passes.setdefault(pass_name, []).append(pixels[::-1] if bottom_up else pixels)
    return {name: np.concatenate(parts, axis=2) for name, parts in passes.items()}

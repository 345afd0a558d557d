"""Generate RESTframe's compact colour-science data from the colour-science library.

The extension cannot bundle colour-science (and scipy), so the few tables the
spectral renderer needs are written once into ``restframe_addon/data/colour.npz``;
``tests/core/test_spectral.py`` checks the file against the library.

    tools/dev.sh tools/make_colour_data.py
"""

from pathlib import Path

import colour
import numpy as np

OUT = Path(__file__).resolve().parents[1] / "restframe_addon" / "data" / "colour.npz"
SHAPE = colour.SpectralShape(360, 830, 1)  # the CIE 1931 observer's full range, 1 nm


def tables():
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(SHAPE)
    # Blender's scene-linear space: Rec.709 primaries, D65 white (identical to linear sRGB)
    space = colour.RGB_COLOURSPACES["ITU-R BT.709"]
    return {
        "wavelength_nm": np.asarray(cmfs.wavelengths, dtype=np.float64),
        "cmf_xyz": np.asarray(cmfs.values, dtype=np.float64),
        "xyz_to_rgb": np.asarray(space.matrix_XYZ_to_RGB, dtype=np.float64),
        "white_xy": np.asarray(space.whitepoint, dtype=np.float64),
        "bradford": np.asarray(colour.adaptation.CAT_BRADFORD, dtype=np.float64),
    }


def main():
    OUT.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(OUT, **tables())
    print(f"wrote {OUT} ({OUT.stat().st_size} bytes)")


if __name__ == "__main__":
    main()

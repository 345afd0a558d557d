"""Colour models for the shader: plain RGB, or spectra shifted by every Doppler factor.

Both give the shader the same operations on ``(n, C)`` arrays of colour values:
reflectances, emissions, light and world colours evaluated at the *local*
wavelengths of a frame, and ``shift`` to carry wavelengths across a frame change.
In RGB mode (C = 3 channels, no wavelengths) the shift is the identity and the
D powers are those of frequency-integrated light (radiance D^4, point irradiance
D^4, sun D^2).  In spectral mode (C = K wavelengths per ray) a ray seeing a frame
with Doppler factor D samples that frame at ``lambda * D`` and every density
gains one more power of D (D^5, D^5, D^3): ``docs/physics.md#spectral-colour``.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from . import spectral

_LUT_SIZE = 17  # RGB cube resolution for textured reflectances (exact RGB by linearity)


class RGBColour:
    """Scene-linear RGB throughout: no wavelengths, frequency-integrated D powers."""

    channels = 3
    extra_power = 0

    def __init__(self, materials, lights, world_color):
        self.materials = materials
        self.light_rgb = [pl.radiant for pl in lights]
        # keyed lamps: (lamp-clock times, radiant (N, 3)) sampled as their curves
        self.light_keyed = [None if pl.keyed is None else
                            (pl.keyed[0], pl.keyed[1] * pl.keyed[2][:, None] * _tint(pl.light)) for pl in lights]
        self.world_rgb = np.asarray(world_color, dtype=np.float64)

    def camera_wavelengths(self, pixel, sample):
        return None

    def shift(self, lam, doppler):
        return lam

    def base_color(self, mat, uv, lam, columns: bool = False):
        return self.materials.base_color(mat, uv, columns)

    def emission(self, mat, lam):
        return np.take(self.materials.emission, mat, axis=0)

    def light(self, index, lam, n, clock=None):
        """A lamp's colour * power; a keyed lamp's at its clock readings ``clock`` (n,) of emission."""
        keyed = self.light_keyed[index]
        if keyed is None:
            return np.broadcast_to(self.light_rgb[index], (n, 3))
        times, radiant = keyed
        return np.column_stack([np.interp(clock, times, radiant[:, i]) for i in range(3)])

    def world(self, lam, n):
        return np.broadcast_to(self.world_rgb, (n, 3))

    def emitter_rgb(self, rgb, lam):
        """Emitted radiance of RGB colours (n, 3) varying per ray (an environment image)."""
        return rgb

    def to_rgb(self, values, lam):
        return values


def _tint(light):
    """The RGB of a lamp's black body (1 without a temperature), as prepare_lights applies it."""
    return spectral.blackbody_rgb(light.temperature) if light.temperature > 0.0 else 1.0


class SpectralColour:
    """K wavelengths per camera ray: the fixed nodes of a :class:`~.spectral.Quadrature`.

    Spectra come from :mod:`.spectral`; they are analytic, so any shifted wavelength
    (far infrared, far ultraviolet) has a value.
    """

    extra_power = 1

    def __init__(self, materials, lights, world_color, wavelengths: int):
        self.quadrature = spectral.quadrature(wavelengths)
        self.channels = self.quadrature.count
        self.materials = materials
        q = self.quadrature
        self.base_coeffs = q.fit_reflectance(materials.base)
        self.emission_coeffs, self.emission_scale = q.fit_emission(materials.emission)
        self.lights = []
        self.light_keyed = []  # keyed lamps: (lamp-clock times, spectrum coefficients (N, 3), scales (N,))
        for pl in lights:
            coeffs, scale = q.fit_emission(pl.light.color)
            self.lights.append((coeffs, scale * pl.power, float(pl.light.temperature)))
            if pl.keyed is None:
                self.light_keyed.append(None)
            else:
                times, color, power = pl.keyed
                coeffs, scale = q.fit_emission(color)
                self.light_keyed.append((times, coeffs, scale * power))
        self.world_coeffs, self.world_scale = q.fit_emission(world_color)

    def camera_wavelengths(self, pixel, sample):
        return np.broadcast_to(self.quadrature.wavelengths, (len(pixel), self.channels))

    def shift(self, lam, doppler):
        """Wavelengths in the emitting frame: observed lambda times D."""
        return lam * doppler[:, None]

    def base_color(self, mat, uv, lam, columns: bool = False):
        """(``columns``: ignored, spectra are long rows)"""
        values = spectral.sigmoid_spectrum(self.base_coeffs[mat], lam)
        if uv is not None:
            for m, texture in enumerate(self.materials.textures):
                if texture is None:
                    continue
                sel = np.flatnonzero(mat == m)
                if len(sel):
                    rgb = self.materials.base_color(np.full(len(sel), m), uv[sel])
                    values[sel] = _lut_reflectance(self.quadrature.count, rgb, lam[sel])
        return values

    def emission(self, mat, lam):
        return self._emitter(self.emission_coeffs[mat], self.emission_scale[mat], lam)

    def light(self, index, lam, n, clock=None):
        """A lamp's spectrum at the wavelengths ``lam``; a keyed lamp's at its clock readings
        ``clock`` (n,) of emission: the spectra of the neighbouring samples blended linearly (so
        its colour is the samples' colours blended, as in RGB)."""
        coeffs, scale, temperature = self.lights[index]
        keyed = self.light_keyed[index]
        if keyed is None:
            shape = scale * spectral.sigmoid_spectrum(np.broadcast_to(coeffs, (n, 3)), lam)
        else:
            times, coeffs, scales = keyed
            i = np.clip(np.searchsorted(times, clock, side="right") - 1, 0, len(times) - 1)
            j = np.minimum(i + 1, len(times) - 1)
            span = times[j] - times[i]
            f = np.clip(np.where(span > 0, (clock - times[i]) / np.where(span > 0, span, 1.0), 0.0), 0.0, 1.0)
            shape = (((1.0 - f) * scales[i])[:, None] * spectral.sigmoid_spectrum(coeffs[i], lam)
                     + (f * scales[j])[:, None] * spectral.sigmoid_spectrum(coeffs[j], lam))
        if temperature > 0.0:
            return shape * spectral.blackbody_spectrum(lam, temperature)
        return shape * spectral.white_spectrum(lam)

    def world(self, lam, n):
        return self._emitter(np.broadcast_to(self.world_coeffs, (n, 3)), np.broadcast_to(self.world_scale, (n,)), lam)

    def emitter_rgb(self, rgb, lam):
        """Emission spectra (n, K) of RGB colours (n, 3) varying per ray (an environment image):
        scale x a reflectance spectrum from the RGB-cube table x white, exact in RGB as textures."""
        rgb = np.maximum(rgb, 0.0)
        scale = rgb.max(axis=1)
        shape = _lut_reflectance(self.quadrature.count, rgb / np.where(scale > 0.0, scale, 1.0)[:, None], lam)
        return scale[:, None] * shape * spectral.white_spectrum(lam)

    def to_rgb(self, values, lam):
        """Observed spectra as Rec.709; spectra outside its gamut (strongly shifted, nearly
        monochromatic) are clipped at zero per channel: a display cannot show negative light."""
        return np.maximum(self.quadrature.observed_rgb(values), 0.0)

    @staticmethod
    def _emitter(coeffs, scale, lam):
        return scale[:, None] * spectral.sigmoid_spectrum(coeffs, lam) * spectral.white_spectrum(lam)


@lru_cache(maxsize=4)
def _lut_coefficients(count: int):
    axis = np.linspace(0.0, 1.0, _LUT_SIZE)
    grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)
    return spectral.quadrature(count).fit_reflectance(grid).reshape(_LUT_SIZE, _LUT_SIZE, _LUT_SIZE, 3)


def _lut_reflectance(count, rgb, lam):
    """Reflectance spectra for arbitrary (texture) colours: trilinear blend of the spectra at
    the 8 surrounding RGB-cube nodes.  The RGB of a spectrum is linear in it, so the blend
    reproduces the colour exactly, and stays within [0, 1]."""
    lut = _lut_coefficients(count)
    pos = np.clip(rgb, 0.0, 1.0) * (_LUT_SIZE - 1)
    base = np.minimum(np.floor(pos).astype(np.int64), _LUT_SIZE - 2)
    frac = pos - base
    out = np.zeros(lam.shape)
    for corner in range(8):
        bits = np.array([(corner >> 2) & 1, (corner >> 1) & 1, corner & 1])
        weight = np.prod(np.where(bits, frac, 1.0 - frac), axis=1)
        idx = base + bits
        out += weight[:, None] * spectral.sigmoid_spectrum(lut[idx[:, 0], idx[:, 1], idx[:, 2]], lam)
    return out

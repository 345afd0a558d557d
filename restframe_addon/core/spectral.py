"""Spectra for the Doppler colour shift: RGB uplift, light spectra, CIE integration.

Why spectra: a Doppler factor D maps every emitted wavelength to ``lambda / D``.
What the camera sees at 380-780 nm may have left an approaching source in the
infrared (0.9c head-on: D = 4.36, so 1.7-3.4 um) or a receding one in the
ultraviolet, so every spectrum here is an analytic function defined at *every*
wavelength, not a table over the visible band.

* Reflectance: the sigmoid-polynomial model of Jakob & Hanika (2019), "A
  Low-Dimensional Function Space for Efficient Spectral Upsampling":
  ``R(lambda) = S(c0 t^2 + c1 t + c2)`` with ``S(x) = 1/2 + x / (2 sqrt(1 + x^2))``,
  smooth, within [0, 1] by construction, three numbers per colour.  Outside the
  fitted 360-830 nm it keeps its edge values (real pigments are roughly flat in
  the near IR and UV).
  Chosen over linear bases (Mallett & Yuksel 2019: tabulated only for 380-780 nm)
  and Smits (1999: box spectra, undefined outside the visible band).
* White: Planck's law at 6504 K (the correlated colour temperature of D65): a
  thermal spectrum is what a real white source emits beyond the visible band.
  The observer is white-balanced to it (Bradford adaptation to D65), so it
  integrates exactly to Rec.709 white (1, 1, 1).
* Emission and light colours: ``scale * R_rgb(lambda) * white(lambda)``; a light
  with a blackbody temperature uses Planck's law at that temperature instead.
* Observation: spectral radiance integrated against the CIE 1931 2-degree
  observer (360-830 nm) and mapped to Blender's scene-linear Rec.709.

The fits reproduce the RGB they come from to ~1e-9 under the white light, so a
scene with nothing moving renders the same colours spectrally and in RGB.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

LAMBDA_MIN, LAMBDA_MAX = 360.0, 830.0  # nm: the CIE observer's range (the observed band)
_MID, _HALF = 595.0, 235.0  # the sigmoid polynomial's variable t = (lambda - 595) / 235
WHITE_TEMPERATURE = 6504.0  # K
_H, _C, _K = 6.62607015e-34, 299792458.0, 1.380649e-23


@lru_cache(maxsize=1)
def colour_data():
    """CIE 1931 2-degree observer at 1 nm (360-830) and the XYZ -> Rec.709 matrix."""
    with np.load(Path(__file__).resolve().parents[1] / "data" / "colour.npz") as data:
        return {k: data[k] for k in data.files}


def cmf(lam):
    """CIE 1931 colour matching functions at wavelengths lam (nm), zero outside 360-830: (..., 3)."""
    data = colour_data()
    grid, values = data["wavelength_nm"], data["cmf_xyz"]
    return np.stack([np.interp(lam, grid, values[:, i], left=0.0, right=0.0) for i in range(3)], axis=-1)


def planck(lam, temperature):
    """Black-body spectral radiance shape at lam (nm), normalised to 1 at 560 nm."""
    def radiance(l_nm):
        l = np.asarray(l_nm, dtype=np.float64) * 1e-9
        with np.errstate(over="ignore"):
            return 1.0 / (l**5 * np.expm1(_H * _C / (l * _K * temperature)))

    return radiance(lam) / radiance(560.0)


def sigmoid(x):
    return 0.5 + x / (2.0 * np.sqrt(1.0 + x * x))


def sigmoid_spectrum(coeffs, lam):
    """Evaluate sigmoid-polynomial spectra: coeffs (n, 3), lam (n, K) nm -> (n, K).

    Beyond the fitted 360-830 nm a spectrum keeps its edge value: the quadratic would
    otherwise run off to 0 or 1 on a whim of the fit (a red pigment turning into a
    strong ultraviolet reflector), while real pigments are roughly flat there.
    """
    t = np.clip((lam - _MID) / _HALF, -1.0, 1.0)
    x = (coeffs[:, 0:1] * t + coeffs[:, 1:2]) * t + coeffs[:, 2:3]
    return sigmoid(x)


class Quadrature:
    """K fixed wavelengths (the midpoints of equal strata of 360-830 nm) and their CIE weights.

    The weights are the observer's functions integrated over each stratum, so the
    observer's fine structure is integrated exactly; what remains is the curvature
    of the (smooth) spectra within a stratum, which falls as 1/K^2.  The RGB uplift
    and the white balance are solved under this same rule, so with nothing moving
    a spectral render reproduces the RGB one exactly at any K; K sets how finely
    Doppler-shifted spectra are resolved.
    """

    def __init__(self, count: int):
        self.count = int(count)
        data = colour_data()
        grid, values = data["wavelength_nm"], data["cmf_xyz"]
        edges = np.linspace(LAMBDA_MIN, LAMBDA_MAX, self.count + 1)
        self.wavelengths = 0.5 * (edges[1:] + edges[:-1])
        fine = np.linspace(LAMBDA_MIN, LAMBDA_MAX, self.count * 64 + 1)
        mid = 0.5 * (fine[1:] + fine[:-1])
        samples = np.stack([np.interp(mid, grid, values[:, i]) for i in range(3)], axis=-1) * (fine[1] - fine[0])
        self.weights = samples.reshape(self.count, 64, 3).sum(axis=1)  # (K, 3)
        self.xyz_to_rgb = self._white_balanced(data)
        self.to_rgb = self.xyz_to_rgb @ self.weights.T  # (3, K): spectrum at the nodes -> RGB
        t = (self.wavelengths - _MID) / _HALF
        self.basis = np.stack([t**2, t, np.ones_like(t)], axis=1)  # (K, 3)
        self.white = white_spectrum(self.wavelengths)

    def _white_balanced(self, data):
        """XYZ -> scene-linear Rec.709, white-balanced so that the 6504 K black body is (1, 1, 1).

        Bradford adaptation of the black body's XYZ to D65, then the Rec.709 matrix.
        """
        xyz_white = white_spectrum(self.wavelengths) @ self.weights
        x, y = data["white_xy"]
        xyz_d65 = np.array([x / y, 1.0, (1.0 - x - y) / y])
        cone = data["bradford"]
        adapt = np.linalg.inv(cone) @ np.diag((cone @ xyz_d65) / (cone @ (xyz_white / xyz_white[1]))) @ cone
        return data["xyz_to_rgb"] @ adapt / xyz_white[1]

    def observed_rgb(self, radiance):
        """Spectral radiance at the nodes (n, K) -> scene-linear Rec.709 (n, 3)."""
        return radiance @ self.to_rgb.T

    def reflectance_rgb(self, coeffs):
        """RGB of sigmoid reflectances (n, 3 coefficients) under the white light."""
        return (sigmoid(coeffs @ self.basis.T) * self.white) @ self.to_rgb.T

    def fit_reflectance(self, rgb, iterations: int = 60, tolerance: float = 1e-10):
        """Coefficients (n, 3) of reflectance spectra whose colour under the white light is ``rgb``
        (clipped to [0, 1]; least squares where no reflectance reaches it), by damped
        Gauss-Newton from a grey start."""
        rgb = np.clip(np.atleast_2d(np.asarray(rgb, dtype=np.float64)), 0.0, 1.0)
        to_rgb = self.to_rgb * self.white  # (3, K)
        mean = np.clip(rgb.mean(axis=1), 1e-4, 1 - 1e-4)
        c = np.zeros((len(rgb), 3))
        c[:, 2] = (2 * mean - 1) / np.sqrt(1 - (2 * mean - 1) ** 2)  # S^-1(mean)
        # pure white and black are flat at every wavelength (1 - S = 2.5e-17 at x = 1e8)
        c[np.all(rgb >= 1.0, axis=1), 2] = 1e8
        c[np.all(rgb <= 0.0, axis=1), 2] = -1e8
        damping = np.full(len(rgb), 1e-3)
        residual = self.reflectance_rgb(c) - rgb
        cost = np.einsum("ij,ij->i", residual, residual)
        for _ in range(iterations):
            active = np.flatnonzero(cost > tolerance**2)
            if len(active) == 0:
                break
            ca = c[active]
            x = ca @ self.basis.T  # (m, K)
            slope = 0.5 / (1.0 + x * x) ** 1.5
            jac = np.einsum("kl,ml,lj->mkj", to_rgb, slope, self.basis)  # (m, 3, 3)
            jtj = np.einsum("mki,mkj->mij", jac, jac)
            jtr = np.einsum("mki,mk->mi", jac, residual[active])
            # Levenberg-Marquardt; the ridge keeps saturated sigmoids (zero slope) and very few
            # wavelengths (rank-deficient Jacobians) solvable
            scale = np.einsum("mii->m", jtj)[:, None, None] + 1e-30
            diag = np.einsum("mii->mi", jtj)[:, :, None] * np.eye(3) + 1e-9 * scale * np.eye(3)
            step = np.linalg.solve(jtj + damping[active, None, None] * diag, -jtr[..., None])[..., 0]
            trial = ca + step
            trial_res = self.reflectance_rgb(trial) - rgb[active]
            trial_cost = np.einsum("ij,ij->i", trial_res, trial_res)
            better = trial_cost < cost[active]
            idx = active[better]
            c[idx], residual[idx], cost[idx] = trial[better], trial_res[better], trial_cost[better]
            damping[idx] = np.maximum(damping[idx] * 0.3, 1e-12)
            damping[active[~better]] = np.minimum(damping[active[~better]] * 10.0, 1e12)  # unreachable targets
        return c

    def fit_emission(self, rgb):
        """(coefficients (n, 3), scale (n,)) of emission colours: scale * S(c) * white."""
        rgb = np.clip(np.atleast_2d(np.asarray(rgb, dtype=np.float64)), 0.0, None)
        scale = rgb.max(axis=1)
        return self.fit_reflectance(rgb / np.where(scale > 0, scale, 1.0)[:, None]), scale


@lru_cache(maxsize=8)
def quadrature(count: int) -> Quadrature:
    return Quadrature(count)


FINE = 470  # 1 nm strata: the reference quadrature


def white_spectrum(lam):
    """The spectrum of Rec.709 white (1, 1, 1), at any wavelength (nm)."""
    return planck(lam, WHITE_TEMPERATURE)


def blackbody_spectrum(lam, temperature):
    """A black body at ``temperature`` with the luminance of the white spectrum."""
    lam_ref = quadrature(FINE).wavelengths
    y_bar = quadrature(FINE).weights[:, 1]
    ratio = (planck(lam_ref, WHITE_TEMPERATURE) @ y_bar) / (planck(lam_ref, temperature) @ y_bar)
    return planck(lam, temperature) * ratio


def blackbody_rgb(temperature):
    """Rec.709 colour of ``blackbody_spectrum`` (the white black body is (1, 1, 1))."""
    q = quadrature(FINE)
    return q.observed_rgb(blackbody_spectrum(q.wavelengths, temperature)[None])[0]

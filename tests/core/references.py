"""Independent references for the core tests, written from textbook formulas (never the add-on's code)."""

import math

import numpy as np


def boost_matrix(beta):
    """The textbook Lorentz boost into a frame moving with velocity beta, acting on (tau, x, y, z)."""
    beta = np.asarray(beta, dtype=np.float64)
    b2 = float(beta @ beta)
    if b2 == 0.0:
        return np.eye(4)
    gamma = 1.0 / math.sqrt(1.0 - b2)
    m = np.eye(4)
    m[0, 0] = gamma
    m[0, 1:] = m[1:, 0] = -gamma * beta
    m[1:, 1:] += (gamma - 1.0) * np.outer(beta, beta) / b2
    return m


def half_vector_ggx(n, view, light, alpha):
    """GGX D G2 / (4 cos_v cos_l) (height-correlated Smith G2 from the Lambdas, cosines clipped at
    1e-6) and v.h, from the normalised half vector h = (v + l) / |v + l| (Walter et al. 2007)."""
    h = view + light
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    cos_v, cos_l = (np.clip(np.sum(n * x, axis=1), 1e-6, 1.0) for x in (view, light))
    cos_h, a2 = np.sum(n * h, axis=1), alpha**2
    d = a2 / (np.pi * (1.0 - cos_h**2 + a2 * cos_h**2) ** 2)
    lam = [0.5 * (np.sqrt(1.0 + a2 * (1.0 / c**2 - 1.0)) - 1.0) for c in (cos_v, cos_l)]
    return d / (1.0 + lam[0] + lam[1]) / (4.0 * cos_v * cos_l), np.sum(view * h, axis=1)

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

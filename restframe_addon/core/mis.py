"""Multiple importance sampling weights (Veach 1997) for combining sampling strategies."""

from __future__ import annotations

import numpy as np


def power_heuristic(pdf_chosen, pdf_other):
    """Weight of a sample drawn by the strategy with density ``pdf_chosen`` when the other
    strategy would have drawn it with ``pdf_other`` (both per the same measure; exponent 2).

    A delta strategy (pdf inf) gets weight 1 against a finite one and its competitor 0;
    where both densities are 0 the weight is 0.
    """
    a = np.asarray(pdf_chosen, dtype=np.float64)
    b = np.asarray(pdf_other, dtype=np.float64)
    with np.errstate(invalid="ignore", over="ignore"):
        ratio = b / a  # inf / inf cannot happen: only one strategy of a pair is a delta
        weight = 1.0 / (1.0 + ratio * ratio)
    return np.where(a > 0.0, np.where(np.isinf(a), 1.0, weight), 0.0)

"""validation.one_minus_speed_squared: exact 1 - |beta|^2, correctly rounded, at rest too."""

from fractions import Fraction

import pytest

from restframe_addon.core.validation import one_minus_speed_squared


@pytest.mark.parametrize("beta", [(0.0, 0.0, 0.0), (-0.0, 0.0, -0.0), (5e-324, 0.0, 0.0), (0.0, -1e-160, 0.0),
                                  (0.6, 0.0, 0.8 - 2 ** -53), (1 - 2 ** -53, 0.0, 0.0), (0.3, -0.4, 0.5)])
def test_one_minus_speed_squared_is_the_exact_value_correctly_rounded(beta):
    exact = 1 - sum(Fraction(c) ** 2 for c in beta)
    assert one_minus_speed_squared(beta) == float(exact)
    assert one_minus_speed_squared(list(beta)) == float(exact)  # any sequence of floats

"""The recurrent policies' linear layer: x @ w.T with each output summed over its inputs in order, so a row's result
is the same alone or in any batch (what the evaluation's batch independence needs) and on any CPU."""

import numpy as np
import pytest

from agents.policies.recurrent import linear


@pytest.mark.parametrize("n", [1, 3, 4, 5, 9, 64])
def test_linear_sums_in_order_and_rows_do_not_depend_on_their_batch(n):
    rng = np.random.default_rng(n)
    x, w = rng.normal(size=(n, 37)), rng.normal(size=(50, 37))
    seq = np.zeros((n, 50))
    for f in range(37):                     # the sequential sum, term by term
        seq = seq + x[:, f:f + 1] * w[None, :, f]
    y = linear(x, w)
    assert np.array_equal(y, seq)
    assert all(np.array_equal(linear(x[i:i + 1], w)[0], y[i]) for i in range(n))
    assert np.allclose(y, x @ w.T, rtol=1e-12, atol=1e-12)
    assert linear(x[:, :0], w[:, :0]).shape == (n, 50) and not linear(x[:, :0], w[:, :0]).any()

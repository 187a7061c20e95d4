"""Readings gathered over spans: span_means against the plain mean of each slice."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from calib.numerics.windows import span_means


@settings(max_examples=80, deadline=None)
@given(st.integers(0, 2**32 - 1), st.booleans())
def test_span_means_are_each_slices_mean(seed, in_order):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 200))
    x = rng.normal(0, 1, (n, 3))
    edges = np.sort(rng.integers(0, n + 1, 2 * int(rng.integers(1, 8))))
    spans = edges.reshape(-1, 2)
    if not in_order:  # overlapping, unordered, some empty
        spans = np.sort(rng.integers(0, n + 1, (int(rng.integers(1, 8)), 2)), axis=1)[::-1]
    got = span_means(x, spans)
    for (a, b), row in zip(spans, got, strict=True):
        if b > a:
            np.testing.assert_allclose(row, x[a:b].mean(axis=0), rtol=1e-12, atol=1e-12)
        else:
            assert np.all(np.isnan(row))


def test_span_means_of_no_span_is_empty():
    assert span_means(np.ones((5, 3)), []).shape == (0, 3)

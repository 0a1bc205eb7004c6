"""core.expansions.top_mean: the one reduction of the cosine rules and the presence check."""

from __future__ import annotations

import numpy as np
import pytest

from quash_plugins.core.expansions import CosineMargin, top_mean


@pytest.mark.parametrize("k", [1, 2, 3, 7, 50])
def test_top_mean_is_the_mean_of_the_k_largest_by_sorting(k):
    c = np.random.default_rng(k).standard_normal((40, 7)).astype(np.float32)
    expected = np.sort(c, axis=1)[:, ::-1][:, : min(k, 7)].mean(axis=1)
    np.testing.assert_allclose(top_mean(c, k), expected, rtol=1e-5, atol=1e-6)


def test_cosine_margin_reduces_with_it():
    c = np.random.default_rng(0).uniform(-1, 1, (25, 9)).astype(np.float32)
    got = CosineMargin(positives=4, k=2).apply(c)
    by_hand = np.sort(c[:, :4], axis=1)[:, -2:].mean(axis=1)
    by_hand = by_hand - np.sort(c[:, 4:], axis=1)[:, -2:].mean(axis=1)
    np.testing.assert_allclose(got, by_hand, rtol=1e-5, atol=1e-6)


def test_the_declarations_stay_importable_from_core_kernels():
    """A plugin written against ``quash_plugins.core.kernels`` (where the declarations
    lived) gets the very same classes and functions from there."""
    from quash_plugins.core import expansions, kernels

    for name in ("KINDS", "KernelPart", "KernelExpansion", "CosineExpansion", "CosineMargin"):
        assert getattr(kernels, name) is getattr(expansions, name)
    assert kernels.top_mean is top_mean
    assert kernels.reference_kernel is expansions.reference_kernel
    assert set(kernels.__all__) <= set(dir(kernels))

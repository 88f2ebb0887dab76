"""The edge classes' 3x3 test (minirt.model.result.changes) is scipy.ndimage's maximum_filter !=
minimum_filter (size 3, mode "nearest"), pixel for pixel, on every label type the classes read."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from minirt.model.result import changes


@pytest.mark.parametrize("shape", [(1, 1), (1, 5), (5, 1), (2, 2), (3, 7), (17, 33), (64, 64)])
@pytest.mark.parametrize("dtype", [np.int32, np.int8, np.float64, np.uint64, bool])
def test_changes_is_scipys_filters(shape, dtype):
    rng = np.random.default_rng([*shape, np.dtype(dtype).num])
    for labels in (2, 5, 2**40):
        a = rng.integers(0, labels, shape).astype(dtype)
        want = ndimage.maximum_filter(a, size=3, mode="nearest") != ndimage.minimum_filter(a, size=3, mode="nearest")
        got = changes(a)
        assert got.dtype == bool and got.shape == a.shape
        np.testing.assert_array_equal(got, want)

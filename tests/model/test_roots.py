"""minirt.model.roots' helpers against the NumPy expressions they stand for, bit for bit."""

import numpy as np

from minirt.model.roots import row_norm


def test_row_norm_is_numpys_norm_bit_for_bit():
    """minirt.model.roots.row_norm, the bands' and hazards' |v| per row, against np.linalg.norm(v, axis=-1): the
    same bits at every scale, overflow and underflow included, NaN and infinities, rows and images."""
    rng = np.random.default_rng(5)
    odd = [[np.nan, 1, 2], [np.inf, 0, 1], [0, -0.0, 0], [1e308, 1e308, 1], [5e-324, 0, 0], [np.inf, -np.inf, 0],
           [0, 0, np.nan], [3, 4, 0], [-1e-200, 1e-200, 0]]  # fmt: skip
    for scale in (1e-300, 1e-160, 1.0, 1e150, 1e300):
        v = np.concatenate([odd, rng.normal(size=(5000, 3)) * scale])
        with np.errstate(over="ignore", under="ignore", invalid="ignore"):
            want, got = np.linalg.norm(v, axis=-1), row_norm(v)
            assert np.array_equal(got.view(np.uint64), want.view(np.uint64))
            img = v[:5004].reshape(36, 139, 3)
            assert np.array_equal(row_norm(img).view(np.uint64), np.linalg.norm(img, axis=-1).view(np.uint64))

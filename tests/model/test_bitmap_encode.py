"""``bitmap.encode`` (one scratch buffer) writes the same levels as ``quantise(transfer(...))``, the
definition it stands for, on every encoding and gamma: values on and beside every rounding step, out of
range, NaN, infinities and both zeros, in float64 and float32."""

import numpy as np
import pytest

from minirt.model import bitmap


def _colours(dtype) -> np.ndarray:
    rng = np.random.default_rng(13)
    levels = np.arange(257.0)
    steps = np.concatenate([levels / 255.0, (levels + 0.5) / 255.0, levels / 256.0])
    beside = np.concatenate([np.nextafter(steps, -np.inf), steps, np.nextafter(steps, np.inf)])
    odd = np.array([np.nan, np.inf, -np.inf, 0.0, -0.0, -1e-300, 1.0, 1.0 + 2**-52, 2.0, -3.0, 1e300])
    x = np.concatenate([beside, odd, rng.normal(0.5, 0.7, 3000)])
    x = x[: x.size // 3 * 3].reshape(-1, 1, 3)
    return x.astype(dtype)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("gamma", ["linear", "srgb", "2.2"])
@pytest.mark.parametrize("encoding", ["round", "floor256", "floor"])
def test_encode_is_transfer_then_quantise(encoding, gamma, dtype):
    with np.errstate(invalid="ignore", over="ignore"):
        x = _colours(dtype)
        want = bitmap.quantise(bitmap.transfer(x, gamma), encoding)
        got = bitmap.encode(x, encoding, gamma)
    assert got.dtype == np.uint8 and got.shape == x.shape
    np.testing.assert_array_equal(got, want)


def test_encode_names_an_unknown_encoding():
    with pytest.raises(ValueError, match="unknown encoding"):
        bitmap.encode(np.zeros((1, 1, 3)), "ceil")


@pytest.mark.parametrize("dtype", [np.int16, np.float64, np.float32])
def test_channel_max_and_any_are_numpys_reductions_over_the_last_axis(dtype):
    """The elementwise forms the diagnosis and the checks use: the same values as max(-1) and any(-1),
    NaN in any channel included, for images and flat pixel lists."""
    rng = np.random.default_rng(3)
    d = rng.integers(-300, 300, size=(17, 13, 3)).astype(dtype)
    if np.issubdtype(dtype, np.floating):
        d[2, 3, 1], d[5, 5, 0], d[7, 1, 2] = np.nan, np.inf, -np.inf
    for a in (d, d.reshape(-1, 3)):
        assert np.array_equal(bitmap.channel_max(a), a.max(-1), equal_nan=np.issubdtype(dtype, np.floating))
        m = a > 200
        assert np.array_equal(bitmap.channel_any(m), m.any(-1))

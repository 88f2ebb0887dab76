"""The statistics of stochastic renders (minirt.harness.stochastic): Welch's test with the variance floor,
pinned to the former hand-written test and to SciPy's (bit for bit), and Sidak's correction."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from minirt.harness.stochastic import sidak_alpha, z_test
from minirt.harness.tolerances import THRESHOLDS


def test_z_test_catches_a_bias_and_passes_noise():
    rng = np.random.default_rng(1)
    n = 64
    truth = rng.random((32, 32, 3))
    var = np.full_like(truth, 0.01)
    a = truth + rng.normal(0, np.sqrt(var / n))
    b = truth + rng.normal(0, np.sqrt(var / n))
    mask = np.ones_like(truth, bool)
    _, _, frac = z_test(a, var, n, b, var, n, mask)
    assert frac >= 0.9975
    _, _, frac = z_test(a, var, n, b * 1.2, var, n, mask)
    assert frac < 0.5


@pytest.mark.parametrize("seed", range(5))
def test_z_test_with_estimated_variances_of_few_samples(seed):
    """Variances estimated from 4 samples per pixel (what a 4-spp render reports): the statistic is
    t-distributed with few degrees of freedom; judged as normal, a correct render fails (measured: a
    fuzzed 4-sample scene, 99.74% < 99.75%). Equal means must pass; a doubled image must not."""
    rng = np.random.default_rng(seed)
    n = 4
    truth = rng.random((48, 48, 3))
    sa = truth[..., None] + rng.normal(0, 0.2, (*truth.shape, n))
    sb = truth[..., None] + rng.normal(0, 0.2, (*truth.shape, n))
    a, va = sa.mean(-1), sa.var(-1, ddof=1)
    b, vb = sb.mean(-1), sb.var(-1, ddof=1)
    mask = np.ones_like(truth, bool)
    _, _, frac = z_test(a, va, n, b, vb, n, mask)
    assert frac >= 0.9975
    sc = truth[..., None] * 2 + 1 + rng.normal(0, 0.2, (*truth.shape, 64))
    sd = truth[..., None] + rng.normal(0, 0.2, (*truth.shape, 64))
    _, _, frac = z_test(sc.mean(-1), sc.var(-1, ddof=1), 64, sd.mean(-1), sd.var(-1, ddof=1), 64, mask)
    assert frac < 0.5


def _z_test_before(a, var_a, n_a, b, var_b, n_b, mask):
    """The hand-written Welch test the harness used before it called SciPy (kept to pin the numbers)."""
    from scipy.stats import t as student_t

    floor = THRESHOLDS["z_var_floor"].value
    ea, eb = var_a / n_a, var_b / n_b
    z = np.abs(a - b) / np.sqrt(ea + eb + floor)
    with np.errstate(divide="ignore", invalid="ignore"):
        den = (ea * ea / (n_a - 1) if n_a > 1 else 0.0) + (eb * eb / (n_b - 1) if n_b > 1 else 0.0)
        dof = np.where(den > 0, (ea + eb) ** 2 / den, np.inf)
    dof = np.clip(np.nan_to_num(dof, nan=np.inf), 1.0, 1e9)
    p = 2 * student_t.sf(z, dof)
    vals = p[mask]
    alpha = 1 - (1 - THRESHOLDS["z_significance"].value) ** (1 / max(vals.size, 1))
    return p, alpha, float((vals > alpha).mean()) if vals.size else 1.0


@pytest.mark.parametrize(("n_a", "n_b"), [(4, 4), (2, 64), (64, 1024), (16, 3)])
def test_z_test_p_values_unchanged_by_scipy(n_a, n_b):
    """SciPy's Welch test (with the floor folded into the variances) gives the former p-values to 1e-12,
    including zero-variance pixels (one side or both) and variances far below the floor."""
    rng = np.random.default_rng(n_a * 1000 + n_b)
    a = rng.random((20, 20, 3))
    b = a + rng.normal(0, 0.05, a.shape)
    va, vb = rng.random(a.shape) * 0.1, rng.random(a.shape) * 0.1
    va[0], vb[0], va[1], vb[2, :5] = 0.0, 0.0, 0.0, 1e-12
    b[3] = a[3]  # equal means: p = 1
    mask = rng.random(a.shape) < 0.8
    p_new, alpha_new, frac_new = z_test(a, va, n_a, b, vb, n_b, mask)
    p_old, alpha_old, frac_old = _z_test_before(a, va, n_a, b, vb, n_b, mask)
    assert np.abs(p_new - p_old).max() <= 1e-12
    assert abs(alpha_new - alpha_old) <= 1e-12 * alpha_old and frac_new == frac_old
    assert 0 < frac_new < 1  # the inputs exercise both outcomes


def test_z_test_is_scipys_welch_test_without_the_floor(monkeypatch):
    """With the floor at 0 the p-values are scipy.stats.ttest_ind's Welch test on the samples themselves."""
    from scipy.stats import ttest_ind

    monkeypatch.setitem(THRESHOLDS, "z_var_floor", replace(THRESHOLDS["z_var_floor"], value=0.0))
    rng = np.random.default_rng(3)
    sa, sb = rng.normal(0.5, 0.2, (50, 5)), rng.normal(0.55, 0.1, (50, 9))
    ref = ttest_ind(sa, sb, axis=1, equal_var=False)
    p, _, _ = z_test(sa.mean(1), sa.var(1, ddof=1), 5, sb.mean(1), sb.var(1, ddof=1), 9, np.ones(50, bool))
    assert np.abs(p - ref.pvalue).max() <= 1e-12 and ref.pvalue.min() < 0.05


@pytest.mark.parametrize(("n_a", "n_b"), [(4, 4), (2, 64), (64, 1024), (16, 3)])
def test_welch_is_scipys_bit_for_bit(n_a, n_b):
    """z_test's Welch test, written on scipy.special.stdtr to spare the check the import of scipy.stats,
    gives the very bits of scipy.stats.ttest_ind_from_stats and of the t law's sf: zero variances on one
    side or both, equal means, infinite and NaN differences included."""
    from scipy.stats import t as student_t
    from scipy.stats import ttest_ind_from_stats

    from minirt.harness.stochastic import DOF_NORMAL, _welch

    rng = np.random.default_rng(n_a * 7 + n_b)
    a = rng.random((24, 24, 3))
    b = a + rng.normal(0, 0.05, a.shape)
    sa, sb = rng.random(a.shape) * 0.3, rng.random(a.shape) * 0.3
    sa[0], sb[0], sa[1], sb[2, :5] = 0.0, 0.0, 0.0, 1e-9
    b[3] = a[3]
    b[4, 0], b[4, 1], b[4, 2] = np.inf, -np.inf, np.nan
    with np.errstate(divide="ignore", invalid="ignore"):
        ours = _welch(a, sa, n_a, b, sb, n_b)
        theirs = ttest_ind_from_stats(a, sa, n_a, b, sb, n_b, equal_var=False).pvalue
    assert np.array_equal(ours, theirs, equal_nan=True)
    assert np.isnan(ours).any() and (ours == 1.0).any() and (ours < 1e-6).any()

    from scipy.special import stdtr

    x = np.abs(np.concatenate([(a - b).ravel(), [0.0, 1e-300, 40.0]])) / np.sqrt(1e-6)
    assert np.array_equal(2 * stdtr(DOF_NORMAL, -x), 2 * student_t.sf(x, DOF_NORMAL), equal_nan=True)


def test_a_check_of_stochastic_renders_does_not_import_scipy_stats():
    """The point of writing the test on scipy.special: z_test leaves scipy.stats unimported."""
    import subprocess
    import sys

    code = (
        "import sys, numpy as np\n"
        "from minirt.harness.stochastic import z_test\n"
        "a = np.ones((4, 4, 3)); z_test(a, a, 4, a, a, 4, a > 0)\n"
        "print('scipy.stats' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


def test_sidak_alpha():
    assert sidak_alpha(0.01, 1) == pytest.approx(0.01, rel=1e-15)
    m = 3 * 64 * 64
    alpha = sidak_alpha(0.01, m)
    assert (1 - alpha) ** m == pytest.approx(0.99, rel=1e-12)  # family-wise 1 %
    assert 0.01 / m < alpha < 0.01 / m * 1.01  # just above Bonferroni's

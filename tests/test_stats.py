"""jaxcart.analysis.stats on fixed samples: values worked out by hand (in the comments) or by brute
force, against the definitions of rliable 1.2.0 (Agarwal et al. 2021)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import mannwhitneyu, trim_mean

from jaxcart.analysis import stats

SAMPLE = np.array([0.0, 10, 20, 30, 40, 50, 60, 500])


def test_point_estimates_by_hand():
    # n = 8: IQM drops int(0.25 * 8) = 2 from each end -> mean(20, 30, 40, 50) = 35.
    assert stats.iqm(SAMPLE) == 35.0
    assert stats.iqm(SAMPLE[::-1]) == 35.0  # order does not matter
    # n = 5: int(1.25) = 1 from each end -> mean(2, 3, 4) = 3 (the 100 is trimmed).
    assert stats.iqm(np.array([100.0, 1, 2, 3, 4])) == 3.0
    # n = 3 and fewer: nothing is trimmed.
    assert stats.iqm(np.array([1.0, 2, 9])) == 4.0
    for x in (SAMPLE, np.arange(7.0) ** 2, np.array([5.0])):
        assert stats.iqm(x) == pytest.approx(trim_mean(x, 0.25))  # rliable's aggregate_iqm
    # optimality gap: shortfalls 500, 490, 480, 470, 460, 450, 440, 0 -> 3290 / 8.
    assert stats.optimality_gap(SAMPLE) == pytest.approx(411.25)
    # rliable's form gamma - mean(min(x, gamma)); a score above 500 counts as 500.
    assert stats.optimality_gap(np.array([600.0, 400])) == 50.0
    estimates = stats.bootstrap_cis(SAMPLE, stats.ESTIMATORS, reps=200)
    assert estimates["mean"].value == pytest.approx(710 / 8)
    assert estimates["median"].value == 35.0
    assert estimates["iqm"].value == 35.0
    # [reps, n] -> [reps]: the estimators reduce the last axis of a batch of resamples.
    batch = np.stack([SAMPLE, SAMPLE + 1])
    np.testing.assert_allclose(stats.iqm(batch, axis=-1), [35.0, 36.0])
    np.testing.assert_allclose(stats.optimality_gap(batch, axis=-1), [411.25, 410.375])


def test_nan_iqm_leaves_nan_out():
    x = np.array([[1.0, 2, 3, 100, np.nan, np.nan], [np.nan] * 6, list(SAMPLE[:6])])
    np.testing.assert_allclose(
        stats.nan_iqm(x), [stats.iqm(x[0, :4]), np.nan, stats.iqm(SAMPLE[:6])]
    )


@pytest.mark.parametrize(
    "x, y, expected",
    [
        # pairs (1,1) tie 0.5, (1,3) 0, (2,1) 1, (2,3) 0 -> 1.5 / 4
        ([1, 2], [1, 3], 0.375),
        ([1, 3], [1, 2], 0.625),
        ([3], [1, 2], 1.0),
        ([1, 2], [1, 2], 0.5),  # identical runs: rliable's special case, 0.5
        ([5, 5, 5], [5], 0.5),
        # x = 2 beats 1, ties 2, loses to 3; x = 4 beats all three: (1 + 0.5 + 0 + 3) / 6
        ([2, 4], [1, 2, 3], 0.75),
    ],
)
def test_probability_of_improvement_by_hand(x, y, expected):
    assert stats.probability_of_improvement(x, y) == pytest.approx(expected)
    assert stats.probability_of_improvement(y, x) == pytest.approx(1 - expected)


def test_probability_of_improvement_is_mann_whitney_u():
    rng = np.random.default_rng(3)
    for n, m in [(5, 7), (8, 8), (3, 10)]:
        x, y = rng.integers(0, 6, n).astype(float), rng.integers(0, 6, m).astype(float)
        u = mannwhitneyu(x, y, alternative="greater").statistic  # rliable's computation
        assert stats.probability_of_improvement(x, y) == pytest.approx(u / (n * m))


def brute_force_interval(boot: list[float]) -> tuple[float, float]:
    return tuple(np.percentile(boot, [2.5, 97.5]))


def test_bootstrap_ci_is_the_percentile_interval_of_resampled_statistics():
    reps = 300
    for statistic in (np.mean, np.median, stats.iqm, stats.optimality_gap):
        estimate = stats.bootstrap_ci(SAMPLE, statistic, reps=reps, seed=7)
        rng = np.random.default_rng(7)
        idx = rng.integers(0, len(SAMPLE), size=(reps, len(SAMPLE)))
        boot = [float(statistic(SAMPLE[i])) for i in idx]  # one resample at a time
        assert (estimate.ci_low, estimate.ci_high) == pytest.approx(brute_force_interval(boot))
        assert estimate.value == pytest.approx(float(statistic(SAMPLE)))


def test_bootstrap_ci_deterministic_and_covers():
    a = stats.bootstrap_ci(SAMPLE, stats.iqm)
    assert a == stats.bootstrap_ci(SAMPLE, stats.iqm)  # fixed default seed
    assert a != stats.bootstrap_ci(SAMPLE, stats.iqm, seed=1)
    assert a.ci_low <= a.value <= a.ci_high
    assert a.to_dict() == {"value": a.value, "ci_low": a.ci_low, "ci_high": a.ci_high}
    # Coverage: the 95% interval of the mean of 30 draws from N(0, 1) contains 0 about 95% of
    # the time (the percentile bootstrap runs a little short at n = 30: ~93%).
    rng = np.random.default_rng(0)
    hits = [
        (e := stats.bootstrap_ci(rng.normal(size=30), np.mean, reps=500, seed=s)).ci_low
        <= 0
        <= e.ci_high
        for s in range(300)
    ]
    assert 0.88 <= np.mean(hits) <= 0.99


def test_single_seed_interval_is_degenerate():
    e = stats.bootstrap_ci(np.array([321.0]), stats.iqm)
    assert (e.value, e.ci_low, e.ci_high) == (321.0, 321.0, 321.0)
    with pytest.raises(ValueError, match="scores is empty"):
        stats.bootstrap_ci(np.array([]), np.mean)


def test_probability_of_improvement_ci_resamples_both_runs_independently():
    x, y = np.array([1.0, 2, 3, 4, 4]), np.array([1.0, 3, 2.5])
    reps = 400
    e = stats.probability_of_improvement_ci(x, y, reps=reps, seed=5)
    assert e.value == pytest.approx(stats.probability_of_improvement(x, y))
    rng = np.random.default_rng(5)
    ix = rng.integers(0, len(x), size=(reps, len(x)))  # X's seeds first, then Y's
    iy = rng.integers(0, len(y), size=(reps, len(y)))
    boot = [stats.probability_of_improvement(x[i], y[j]) for i, j in zip(ix, iy)]
    assert (e.ci_low, e.ci_high) == pytest.approx(brute_force_interval(boot))
    assert e == stats.probability_of_improvement_ci(x, y, reps=reps, seed=5)
    # Every pair won: the interval cannot move.
    assert stats.probability_of_improvement_ci([9.0, 8], [1.0, 2]) == stats.Estimate(1, 1, 1)


def test_resample_counts_match_indices():
    counts = stats.resample_counts(4, 50, np.random.default_rng(2))
    idx = stats.resample_indices(4, 50, np.random.default_rng(2))
    assert counts.shape == (50, 4) and (counts.sum(1) == 4).all()
    for c, i in zip(counts, idx):
        assert c.tolist() == np.bincount(i, minlength=4).tolist()


def test_performance_profile_tiny_sample():
    scores, taus = np.array([0.0, 100, 500]), np.array([0.0, 50, 100, 499, 500])
    # strictly above tau: {100, 500}, {100, 500}, {500}, {500}, none
    expected = [2 / 3, 2 / 3, 1 / 3, 1 / 3, 0]
    np.testing.assert_allclose(stats.performance_profile(scores, taus), expected)
    np.testing.assert_allclose(
        stats.performance_profile(np.stack([scores, scores + 1]), taus)[0], expected
    )
    profile, low, high = stats.performance_profile_band(scores, taus, reps=300, seed=4)
    np.testing.assert_allclose(profile, expected)
    rng = np.random.default_rng(4)
    idx = rng.integers(0, 3, size=(300, 3))
    boot = np.array([stats.performance_profile(scores[i], taus) for i in idx])
    np.testing.assert_allclose(low, np.percentile(boot, 2.5, axis=0))
    np.testing.assert_allclose(high, np.percentile(boot, 97.5, axis=0))
    assert (low <= profile).all() and (profile <= high).all() and high[-1] == 0


def test_curve_band_mean_and_iqm():
    values = np.array([[np.nan, np.nan], [1.0, 3.0], [2.0, np.nan], [5.0, 5.0]])
    mean, low, high = stats.curve_band(values)
    np.testing.assert_allclose(mean, [np.nan, 2.0, 2.0, 5.0])
    # Two seeds {1, 3}: resampled means 1, 2, 3 with probability 1/4, 1/2, 1/4.
    np.testing.assert_allclose([low[1], high[1]], [1.0, 3.0])
    assert np.isnan(low[[0, 2]]).all() and np.isnan(high[[0, 2]]).all()  # fewer than 2 seeds
    np.testing.assert_allclose([low[3], high[3]], [5.0, 5.0])
    _, low, high = stats.curve_band(values, bounds=(0.0, 2.5))
    assert high[1] == 2.5 and low[1] == 1.0

    rng = np.random.default_rng(0)
    curves = rng.uniform(0, 500, size=(6, 9))
    curves[0, :4] = np.nan  # seeds whose first episode has not ended
    for statistic, reduce in (("mean", np.mean), ("iqm", stats.iqm)):
        point, low, high = stats.curve_band(curves, statistic, reps=200, seed=3)
        idx = np.random.default_rng(3).integers(0, 9, size=(200, 9))  # whole curves
        for t in range(6):
            finite = curves[t][np.isfinite(curves[t])]
            assert point[t] == pytest.approx(reduce(finite))
            boot = []
            for i in idx:
                drawn = curves[t, i][np.isfinite(curves[t, i])]
                boot.append(reduce(drawn) if drawn.size else np.nan)
            boot = np.array(boot)
            expected = np.percentile(boot[np.isfinite(boot)], [2.5, 97.5])
            assert (low[t], high[t]) == pytest.approx(tuple(expected))


def test_first_reach_and_fraction():
    values = np.array([[10.0, np.nan, 500], [500, 20, 500], [499, 30, 500]])
    steps = np.array([100.0, 200, 300])
    first = stats.first_at_least(values, steps, 500)
    np.testing.assert_array_equal(first, [200, np.inf, 100])
    np.testing.assert_allclose(
        stats.fraction_reached(first, [0, 100, 250, 1e9]), [0, 1 / 3, 2 / 3, 2 / 3]
    )

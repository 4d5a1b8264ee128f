"""jaxcart.analysis (stats, tasks, curves, comparisons) on fixed samples: values worked out by hand
(in the comments), by brute force (one resample at a time) or by SciPy, against the definitions
of rliable 1.2.0 (Agarwal et al. 2021)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import mannwhitneyu, trim_mean

from jaxcart.analysis import stats, summary

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
    estimates = {n: stats.bootstrap_ci(SAMPLE, f, reps=200) for n, f in stats.ESTIMATORS.items()}
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


# --- refusals: scores with NaN, infinity or no entries ---------------------------------------


@pytest.mark.parametrize(
    "call",
    [
        lambda x: stats.iqm(x),
        lambda x: stats.mean(x),
        lambda x: stats.median(x),
        lambda x: stats.optimality_gap(x),
        lambda x: stats.bootstrap_ci(x, stats.iqm, reps=10),
        lambda x: stats.bootstrap_ci(x, stats.optimality_gap, reps=10),
        lambda x: stats.performance_profile(x, [0.0, 500]),
        lambda x: stats.performance_profile_band(x, [0.0, 500], reps=10),
    ],
)
def test_scores_with_nan_or_nothing_are_refused(call):
    # Before: iqm gave a finite wrong value (NaN sorted last, then trimmed away), bootstrap_ci a
    # NaN estimate with a finite interval, and empty input NaN; SciPy's answer is NaN.
    with_nan = np.array([500.0, np.nan, 420, 480, np.nan, 500, 300, 500])
    assert np.isnan(trim_mean(with_nan, 0.25))
    with pytest.raises(ValueError, match=r"scores holds 2 NaN and 0 infinite values among 8"):
        call(with_nan)
    with pytest.raises(ValueError, match=r"scores holds 0 NaN and 1 infinite"):
        call(np.array([1.0, np.inf]))
    with pytest.raises(ValueError, match="scores is empty"):
        call(np.array([]))


def test_pairs_name_the_refused_run():
    good, bad = np.array([1.0, 2]), np.array([1.0, np.nan])
    for call in (
        stats.probability_of_improvement,
        stats.probability_of_improvement_ci,
        stats.difference_ci,
    ):
        with pytest.raises(ValueError, match=r"^x holds 1 NaN"):
            call(bad, good)
        with pytest.raises(ValueError, match=r"^y holds 1 NaN"):
            call(good, bad)
        with pytest.raises(ValueError, match=r"^y is empty"):
            call(good, [])
        with pytest.raises(ValueError, match="1-D array"):
            call(good[None], good)


def test_median_is_over_seeds_not_rliables_median_of_task_means():
    scores = np.array([500.0] * 5 + [339.0])
    # rliable's aggregate_median of a [runs, tasks] matrix: the median over tasks of each
    # task's mean; with one task that is the mean, 2839 / 6.
    rliable_median = np.median(np.mean(scores[:, None], axis=0))
    assert stats.median(scores) == 500.0 != rliable_median
    assert stats.ESTIMATORS["median"] is stats.median


# --- difference_ci ----------------------------------------------------------------------------


def test_difference_ci_resamples_each_run_within_itself():
    x, y = SAMPLE, np.array([5.0, 15, 25, 35, 400])
    reps = 300
    for statistic in (stats.iqm, stats.mean, stats.median):
        e = stats.difference_ci(x, y, statistic, reps=reps, seed=11)
        assert e.value == pytest.approx(float(statistic(x) - statistic(y)))
        rng = np.random.default_rng(11)
        ix = rng.integers(0, len(x), size=(reps, len(x)))  # X's seeds first, then Y's
        iy = rng.integers(0, len(y), size=(reps, len(y)))
        boot = [float(statistic(x[i]) - statistic(y[j])) for i, j in zip(ix, iy)]
        assert (e.ci_low, e.ci_high) == pytest.approx(brute_force_interval(boot))
        assert e == stats.difference_ci(x, y, statistic, reps=reps, seed=11)  # deterministic
        assert e != stats.difference_ci(x, y, statistic, reps=reps, seed=12)
    # Two saturated runs: every resample differs by 0.
    assert stats.difference_ci([500.0] * 4, [500.0] * 6) == stats.Estimate(0, 0, 0)


# --- wilson_interval --------------------------------------------------------------------------


def test_wilson_interval_by_hand_and_against_scipy():
    from scipy.stats import binomtest

    # 64/64 at 95%: z = 1.959964, z^2 = 3.841459; centre (1 + z^2/128) / (1 + z^2/64) =
    # 1.0300114 / 1.0600228 = 0.971688; half-width z sqrt(z^2 / (4 * 64^2)) / 1.0600228 =
    # 1.959964 * 0.0153122 / 1.0600228 = 0.028312 -> [0.943376, 1].
    e = stats.wilson_interval(64, 64)
    assert e.value == 1.0 and e.ci_high == 1.0
    assert e.ci_low == pytest.approx(0.943376, abs=1e-6)
    # 0/10: p = 0, the mirror image: [0, z^2/10 / (1 + z^2/10)] = [0, 0.277533].
    assert stats.wilson_interval(0, 10).to_dict() == pytest.approx(
        {"value": 0.0, "ci_low": 0.0, "ci_high": 0.2775328}, abs=1e-6
    )
    for k, n in [(0, 1), (1, 1), (3, 7), (50, 64), (63, 64), (1, 1000), (500, 1000)]:
        for confidence in (0.9, 0.95, 0.99, 0.9875):
            e = stats.wilson_interval(k, n, confidence)
            ci = binomtest(k, n).proportion_ci(confidence, method="wilson")
            assert e.value == k / n
            assert (e.ci_low, e.ci_high) == pytest.approx((ci.low, ci.high), abs=1e-12)


@pytest.mark.parametrize(
    "args, match",
    [((1, 0), "n must be"), ((5, 4), "successes must"), ((-1, 4), "successes must"),
     ((1.5, 4), "successes must"), ((1, 4, 1.0), "confidence")],
)  # fmt: skip
def test_wilson_interval_refuses(args, match):
    with pytest.raises(ValueError, match=match):
        stats.wilson_interval(*args)


# --- performance profiles at least tau --------------------------------------------------------


def test_performance_profile_at_least_shows_the_solved_fraction():
    scores, taus = np.array([0.0, 100, 500, 500]), np.array([0.0, 100, 499, 500])
    # at least tau: all four; {100, 500, 500}; {500, 500}; {500, 500}
    np.testing.assert_allclose(
        stats.performance_profile(scores, taus, at_least=True), [1, 3 / 4, 1 / 2, 1 / 2]
    )
    assert stats.performance_profile(scores, taus)[-1] == 0  # strictly above 500: never
    profile, low, high = stats.performance_profile_band(scores, taus, reps=300, at_least=True)
    idx = np.random.default_rng(stats.DEFAULT_SEED).integers(0, 4, size=(300, 4))
    boot = np.array([stats.performance_profile(scores[i], taus, at_least=True) for i in idx])
    np.testing.assert_allclose(profile, [1, 3 / 4, 1 / 2, 1 / 2])
    np.testing.assert_allclose(low, np.percentile(boot, 2.5, axis=0))
    np.testing.assert_allclose(high, np.percentile(boot, 97.5, axis=0))


# --- several tasks: the stratified bootstrap --------------------------------------------------

TASKS_X = [np.array([0.0, 10, 20, 30]), np.array([100.0, 300, 500]), np.array([50.0, 60])]
TASKS_Y = [np.array([5.0, 10, 10]), np.array([500.0, 200]), np.array([40.0, 60, 70, 80])]


def brute_force_pooled(tasks, reps, rng):
    """One resample at a time: each task's seeds drawn within the task, tasks in order."""
    draws = [rng.integers(0, len(t), size=(reps, len(t))) for t in tasks]
    return [np.concatenate([t[d[r]] for t, d in zip(tasks, draws)]) for r in range(reps)]


def test_stratified_bootstrap_ci_resamples_within_tasks():
    reps = 300
    for statistic in (stats.iqm, stats.mean, stats.optimality_gap):
        e = stats.bootstrap_ci(TASKS_X, statistic, reps=reps, seed=4)
        assert e.value == pytest.approx(float(statistic(np.concatenate(TASKS_X))))
        pooled = brute_force_pooled(TASKS_X, reps, np.random.default_rng(4))
        boot = [float(statistic(p)) for p in pooled]
        assert (e.ci_low, e.ci_high) == pytest.approx(brute_force_interval(boot))
        assert e == stats.bootstrap_ci(TASKS_X, statistic, reps=reps, seed=4)
    assert stats.bootstrap_ci(TASKS_X, stats.mean) != stats.bootstrap_ci(
        TASKS_X, stats.mean, seed=5
    )
    # Seeds never move between tasks: every resample keeps three 0s and three 100s.
    assert stats.bootstrap_ci([[0.0] * 3, [100.0] * 3], stats.mean) == stats.Estimate(50, 50, 50)
    assert stats.bootstrap_ci([0.0] * 3 + [100.0] * 3, stats.mean).ci_low < 50  # pooled: moves


def test_stratified_statistics_match_rliables_aggregates():
    # rliable: aggregate_iqm = trim_mean(scores [runs, tasks], 0.25, axis=None); its
    # probability_of_improvement = mean over tasks of Mann-Whitney U / (n m).
    rng = np.random.default_rng(8)
    x, y = rng.integers(0, 6, size=(5, 3)) * 100.0, rng.integers(0, 6, size=(7, 3)) * 100.0
    e = stats.bootstrap_ci(list(x.T), stats.iqm, reps=50)
    assert e.value == pytest.approx(trim_mean(x, 0.25, axis=None))
    expected = np.mean(
        [
            0.5
            if np.array_equal(x[:, m], y[:, m])
            else mannwhitneyu(x[:, m], y[:, m], alternative="greater").statistic / (5 * 7)
            for m in range(3)
        ]
    )
    assert stats.probability_of_improvement(list(x.T), list(y.T)) == pytest.approx(expected)


def test_one_task_is_the_single_run_statistic_on_the_same_resamples():
    x, y = TASKS_X[0], TASKS_Y[0]
    assert stats.bootstrap_ci([x], stats.iqm, reps=200) == stats.bootstrap_ci(
        x, stats.iqm, reps=200
    )
    assert stats.difference_ci([x], [y], reps=200) == stats.difference_ci(x, y, reps=200)
    assert stats.probability_of_improvement_ci(
        [x], [y], reps=200
    ) == stats.probability_of_improvement_ci(x, y, reps=200)


def test_stratified_difference_and_improvement_by_brute_force():
    reps = 200
    e = stats.difference_ci(TASKS_X, TASKS_Y, stats.mean, reps=reps, seed=6)
    assert e.value == pytest.approx(np.concatenate(TASKS_X).mean() - np.concatenate(TASKS_Y).mean())
    rng = np.random.default_rng(6)
    px, py = brute_force_pooled(TASKS_X, reps, rng), brute_force_pooled(TASKS_Y, reps, rng)
    boot = [a.mean() - b.mean() for a, b in zip(px, py)]
    assert (e.ci_low, e.ci_high) == pytest.approx(brute_force_interval(boot))

    p = stats.probability_of_improvement_ci(TASKS_X, TASKS_Y, reps=reps, seed=6)
    # Pairs X wins per task (ties half), by X's seed: task 0, X 0/10/20/30 against Y 5, 10, 10:
    # 0 + 2 + 3 + 3 = 8 of 12; task 1, X 100/300/500 against 500, 200: 0 + 1 + 1.5 = 2.5 of 6;
    # task 2, X 50/60 against 40, 60, 70, 80: 1 + 1.5 = 2.5 of 8.
    by_hand = np.mean([8 / 12, 2.5 / 6, 2.5 / 8])
    assert p.value == pytest.approx(by_hand)
    assert stats.probability_of_improvement(TASKS_X, TASKS_Y) == pytest.approx(by_hand)
    rng = np.random.default_rng(6)
    dx = [rng.integers(0, len(t), size=(reps, len(t))) for t in TASKS_X]  # all X draws first
    dy = [rng.integers(0, len(t), size=(reps, len(t))) for t in TASKS_Y]
    boot = [
        np.mean(
            [
                stats.probability_of_improvement(tx[ix[r]], ty[iy[r]])
                for tx, ty, ix, iy in zip(TASKS_X, TASKS_Y, dx, dy)
            ]
        )
        for r in range(reps)
    ]
    assert (p.ci_low, p.ci_high) == pytest.approx(brute_force_interval(boot))
    assert p == stats.probability_of_improvement_ci(TASKS_X, TASKS_Y, reps=reps, seed=6)


def test_stratified_refusals():
    with pytest.raises(ValueError, match="scores is empty"):
        stats.bootstrap_ci([], stats.iqm)
    with pytest.raises(ValueError, match=r"^x\[1\] holds 1 NaN"):
        stats.difference_ci([[1.0], [np.nan, 2]], [[1.0]])
    with pytest.raises(ValueError, match=r"^y\[0\] is empty"):
        stats.probability_of_improvement([[1.0]], [[]])
    with pytest.raises(ValueError, match="x has 2 tasks and y 1"):
        stats.probability_of_improvement_ci([[1.0], [2.0]], [[1.0]])


@pytest.mark.parametrize("name", sorted(stats.RANGE_BELOW))
def test_below_range_below_seeds_an_interval_is_the_seeds_range(name):
    """What :func:`stats.interval_label` says: below RANGE_BELOW seeds the bootstrap
    interval of the estimator is the lowest and highest seed (so not labelled a 95% CI);
    from RANGE_BELOW on it lies inside them."""
    rng = np.random.default_rng(7)
    below = stats.RANGE_BELOW[name]
    for n in (below - 1, below):
        for _ in range(20):
            x = rng.normal(300, 50, size=n)
            e = stats.bootstrap_ci(x, stats.ESTIMATORS[name], seed=int(rng.integers(1000)))
            ends = sorted(stats.ESTIMATORS[name](x[[i] * n]) for i in (x.argmin(), x.argmax()))
            is_range = np.allclose([e.ci_low, e.ci_high], ends)
            assert is_range == (n < below), (name, n, e)
    assert stats.interval_label(below - 1, name) == f"range of {below - 1} seeds"
    assert stats.interval_label(below, name) == "95% CI"
    assert stats.interval_label([below, 2], name) == f"95% CI; range below {below} seeds"
    assert stats.interval_label(1) == "range of 1 seed"


# --- curve scores -----------------------------------------------------------------------------


def test_auc_counts_nan_iterations_as_zero():
    # seed 0: no episode finished in iteration 1 -> (0 + 20 + 40) / 3 = 20;
    # seed 1: diverged after iteration 2 -> (10 + 30 + 0) / 3 = 40 / 3.
    curves = np.array([[np.nan, 10], [20.0, 30], [40.0, np.nan]])
    np.testing.assert_allclose(summary.auc(curves), [20.0, 40 / 3])
    with pytest.raises(ValueError, match="1 infinite"):
        summary.auc(np.array([[np.inf, 1.0]]))
    with pytest.raises(ValueError, match="non-empty"):
        summary.auc(np.zeros((0, 3)))


@pytest.mark.parametrize("env_id, worst", [("Acrobot-v1", -500.0), ("MountainCar-v0", -200.0)])
def test_an_iteration_without_a_return_scores_the_envs_worst_return(env_id, worst):
    """On a -1-a-step env 0 is the best return: counted as 0, an iteration before the first
    episode ends (or after a divergence) would score a slow or broken run up."""
    rng = np.random.default_rng(5)
    learned = np.sort(rng.uniform(worst, 0.0, size=(20, 1)), axis=0)  # [iterations, 1]
    early = np.tile(learned, (1, 6))  # six seeds of one shape
    for s in range(6):  # the same curve, its first episodes ending s iterations later
        early[:s, s] = np.nan
    diverged = learned.copy()
    diverged[8:] = np.nan  # stopped by the trainer after iteration 8
    auc = summary.auc(np.hstack([early, diverged]), env_id)
    assert (np.diff(auc[:6]) <= 0).all()  # a later first episode never scores higher
    assert auc[6] < auc[:6].min()  # the diverged run ranks last
    assert summary.auc(np.full((3, 1), np.nan), env_id) == [worst]
    at_2 = summary.return_at(early, np.arange(1.0, 21), 2, env_id)  # iteration 1
    np.testing.assert_array_equal(at_2[:3], [learned[1, 0], learned[1, 0], worst])
    # a CartPole run with a return every iteration scores as it did: the plain mean
    cartpole = rng.uniform(0, 500, size=(20, 3))
    np.testing.assert_array_equal(summary.auc(cartpole), cartpole.mean(axis=0))


def test_auc_is_recomputable_from_metrics_csv(tmp_path):
    import csv

    from jaxcart.rundir.directory import write_metrics_csv

    rng = np.random.default_rng(1)
    returns = rng.uniform(0, 500, size=(7, 3))
    returns[:2, 1] = np.nan  # seed 1's first episode ends in iteration 3
    write_metrics_csv(tmp_path / "metrics.csv", {"rollout/ep_rew_mean": returns}, batch_size=64)
    per_seed: dict[int, list[float]] = {}
    with open(tmp_path / "metrics.csv") as f:
        for row in csv.DictReader(f):
            value = float(row["rollout/ep_rew_mean"])  # "nan" reads as NaN
            per_seed.setdefault(int(row["seed_index"]), []).append(
                0.0 if np.isnan(value) else value
            )
    expected = [np.mean(per_seed[s]) for s in range(3)]
    np.testing.assert_allclose(summary.auc(returns), expected, rtol=1e-6)  # csv: float32


def test_return_at_first_iteration_at_or_past_the_budget():
    curves = np.array([[np.nan, 10], [20.0, 30], [40.0, 50]])
    env_steps = np.array([100.0, 200, 300])
    np.testing.assert_array_equal(summary.return_at(curves, env_steps, 50), [0, 10])
    np.testing.assert_array_equal(summary.return_at(curves, env_steps, 200), [20, 30])
    np.testing.assert_array_equal(summary.return_at(curves, env_steps, 201), [40, 50])
    with pytest.raises(ValueError, match="never reaches 301 env steps: it ends at 300"):
        summary.return_at(curves, env_steps, 301)
    with pytest.raises(ValueError, match="iterations"):
        summary.return_at(curves, env_steps[:2], 100)


# --- what comparisons can still say -----------------------------------------------------------


def test_saturated():
    assert stats.saturated([[500.0] * 64, [500.0] * 10])
    assert not stats.saturated([[500.0] * 64, [500.0] * 9 + [499.0]])
    assert stats.saturated([[3.0]])
    with pytest.raises(ValueError, match=r"runs\[1\] holds 1 NaN"):
        stats.saturated([[500.0], [np.nan]])


def test_bonferroni():
    # 4 comparisons at 95%: each at 1 - 0.05/4 = 0.9875; up to 4 x 5% = 20% miss at least once.
    assert stats.bonferroni_confidence(4) == pytest.approx(0.9875)
    assert stats.familywise_miss_bound(4) == pytest.approx(0.20)
    assert stats.familywise_miss_bound(40) == 1.0
    # The bound holds for independent intervals: 1 - 0.95^N <= N x 5%.
    for n in range(1, 30):
        assert 1 - 0.95**n <= stats.familywise_miss_bound(n) + 1e-12
    with pytest.raises(ValueError, match="comparisons"):
        stats.bonferroni_confidence(0)

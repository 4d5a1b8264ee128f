"""Evaluation during training (``--eval-every N``) and the best policy kept (``--keep-best``):
greedy episodes inside the compiled program every N iterations, from start states shared by
every run; each run's best parameters carried through checkpoints and waves into
``params_best.npz``, with their Gymnasium verdict, and read by evaluate, compare and export."""

from __future__ import annotations

import dataclasses
import json
import signal

import jax
import numpy as np
import pytest
from helpers import TINY, assert_same_run_dirs

from jaxcart.core.config import ConfigError
from jaxcart.core.evaluation import EVAL_KEY_SEED, greedy_returns
from jaxcart.core.metrics import EVAL_METRICS, METRIC_NAMES
from jaxcart.core.ppo import make_network
from jaxcart.engine.loop import METRIC_COLUMNS, metric_columns, train
from jaxcart.rundir import layout, reader

SMALL = dataclasses.replace(TINY, total_timesteps=1024)  # 8 iterations
EVERY = dataclasses.replace(SMALL, eval_every=3, periodic_eval_episodes=4, keep_best=True)


def test_keep_best_needs_eval_every():
    with pytest.raises(ConfigError, match="keep_best needs eval_every"):
        dataclasses.replace(SMALL, keep_best=True)
    with pytest.raises(ConfigError, match="eval_every must be a non-negative integer"):
        dataclasses.replace(SMALL, eval_every=-1)
    assert metric_columns(SMALL) == METRIC_COLUMNS  # off: no column, nothing in the program
    assert metric_columns(EVERY) == (*METRIC_COLUMNS, *EVAL_METRICS)


@pytest.mark.slow
def test_evaluation_every_n_iterations_keeps_the_best_policy_and_changes_no_training():
    plain = train(SMALL, 2, seed=5, chunk_size=4)
    kept = train(EVERY, 2, seed=5, chunk_size=4)
    for name in METRIC_NAMES:  # evaluating draws no training randomness, changes no update
        np.testing.assert_array_equal(kept.metrics[name], plain.metrics[name], err_msg=name)
    for x, y in zip(jax.tree.leaves(kept.params), jax.tree.leaves(plain.params), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))

    means = kept.metrics["eval/mean_return"]  # [8, 2]: iterations 3 and 6 evaluated
    assert np.isnan(means[[0, 1, 3, 4, 6, 7]]).all() and np.isfinite(means[[2, 5]]).all()
    assert (kept.metrics["eval/min_return"][[2, 5]] <= means[[2, 5]]).all()
    best = kept.runners.best
    for r in range(2):
        at = 2 if means[2, r] > means[5, r] else 5  # ties: the later evaluation
        assert int(best.iteration[r]) == at + 1 and float(best.score[r]) == means[at, r]
        # the kept parameters are the ones that scored it, on the same start states
        params = jax.tree.map(lambda x, r=r: x[r], best.params)
        key = jax.random.PRNGKey(EVAL_KEY_SEED)
        again = greedy_returns(params, key, make_network(SMALL), 4)
        assert float(again.mean()) == pytest.approx(float(means[at, r]), rel=1e-6)


@pytest.mark.slow
def test_best_policies_survive_waves_and_a_resume_and_reach_every_reader(tmp_path, capsys):
    """4 seeds in waves of 2, stopped in wave 1 after a chunk and resumed: bit-identical to
    the run without a stop, params_best.npz included; evaluate, compare and export read it."""
    from jaxcart import compare, evaluate, export
    from jaxcart.engine.signals import StopRequest
    from jaxcart.run import lifecycle
    from jaxcart.run.spec import Hooks, RunOptions, RunSpec
    from jaxcart.rundir.policy import load_policy

    options = RunOptions(eval_episodes=2, compile_cache=False, chunk_size=2, wave_size=2)
    spec = RunSpec(EVERY, num_seeds=4, seed=1)
    whole = lifecycle.run_new(spec, tmp_path / "whole", options)
    assert whole.run.plan.num_waves == 2
    stop, waves = StopRequest(), []

    def on_chunk(progress) -> None:
        if len(waves) == 2 and progress.iteration == 4:
            stop.request(signal.SIGINT)

    hooks = Hooks(on_chunk=on_chunk, on_wave=lambda w, n, runs: waves.append(w))
    assert lifecycle.run_new(spec, tmp_path / "part", options, hooks, stop).stopped
    resumed = lifecycle.resume_run(tmp_path / "part", options)
    assert_same_run_dirs(tmp_path / "whole", tmp_path / "part")
    # the console gives the best policies' verdict too, and watches a best policy next
    from jaxcart import report

    kept = whole.evaluation.best_gym_returns
    assert kept.shape == (4, 2)
    np.testing.assert_array_equal(resumed.evaluation.best_gym_returns, kept)
    recorded = json.loads((tmp_path / "whole" / layout.EVALUATION_FILE).read_text())
    line = report.summary_line(whole, 1.0)
    assert f"(best policies {recorded['best_solved_seeds']}/4) |" in line, line
    assert " --policy best --gif " in report.next_steps_text(whole)
    best = reader.load_params(tmp_path / "whole", policy="best")
    for x, y in zip(
        jax.tree.leaves(best),
        jax.tree.leaves(reader.load_params(tmp_path / "part", policy="best")),
        strict=True,
    ):
        np.testing.assert_array_equal(x, y)
    metrics = reader.read_metrics_csv(tmp_path / "whole" / layout.METRICS_FILE)
    for name in EVAL_METRICS:
        np.testing.assert_array_equal(
            metrics[name],
            reader.read_metrics_csv(tmp_path / "part" / layout.METRICS_FILE)[name],
        )

    manifest = json.loads((tmp_path / "whole" / layout.MANIFEST_FILE).read_text())
    assert layout.PARAMS_BEST_FILE in manifest["files"]
    seeds = json.loads((tmp_path / "whole" / layout.EVALUATION_FILE).read_text())["seeds"]
    for s, seed in enumerate(seeds):  # each best policy's iteration and score, from the curve
        means = metrics["eval/mean_return"][:, s]
        at = max(i for i in (2, 5) if means[i] == np.nanmax(means))
        assert seed["best"]["iteration"] == at + 1
        assert seed["best"]["eval_mean_return"] == pytest.approx(means[at])
        assert len(seed["best"]["gymnasium_returns"]) == 2

    obs = np.random.default_rng(0).normal(size=(8, 4)).astype(np.float32)
    policy = load_policy(tmp_path / "whole", seed_index=3, policy="best")
    final = load_policy(tmp_path / "whole", seed_index=3)
    one = jax.tree.map(lambda x: x[3], best)
    expected = np.asarray(make_network(SMALL).apply(one, obs)[0]).argmax(-1)
    np.testing.assert_array_equal(policy(obs), expected)
    assert final is not None

    capsys.readouterr()
    assert evaluate.main([str(tmp_path / "whole"), "--policy", "best", "--episodes", "2"]) == 0
    table = capsys.readouterr().out
    assert "best policy" in table and "solved" in table
    assert (
        export.main(
            [
                str(tmp_path / "whole"),
                "--policy",
                "best",
                "--to",
                "sb3",
                "--out",
                str(tmp_path / "b.zip"),
            ]
        )
        == 0
    )
    argv = [str(tmp_path / "whole"), str(tmp_path / "part"), "--policy", "best"]
    assert compare.main([*argv, "--out", str(tmp_path / "cmp"), "--reps", "100"]) == 0
    plain = lifecycle.run_new(RunSpec(SMALL, num_seeds=2), tmp_path / "plain", options)
    assert plain.run is not None
    capsys.readouterr()
    assert evaluate.main([str(tmp_path / "plain"), "--policy", "best"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no best policy was kept" in err


@pytest.mark.slow
def test_a_sweep_keeps_each_combinations_best_policies(tmp_path):
    """--eval-every and --keep-best in a sweep: every combination's directory holds its own
    best policies, evaluated, and its metrics record the evaluations (iterations 3 and 6)."""
    from jaxcart.run import lifecycle
    from jaxcart.run.spec import RunOptions, RunSpec
    from jaxcart.rundir.policy import load_policy

    spec = RunSpec(EVERY, num_seeds=2, sweep={"learning_rate": [1e-3, 3e-3]})
    lifecycle.run_new(spec, tmp_path / "sweep", RunOptions(eval_episodes=2))
    for c in range(2):
        combo = layout.combo_dir(tmp_path / "sweep", c)
        info = reader.read_run_config(combo)
        assert info["config"].learning_rate == [1e-3, 3e-3][c] and info["config"].keep_best
        data = json.loads((combo / layout.EVALUATION_FILE).read_text())
        assert {s["best"]["iteration"] for s in data["seeds"]} <= {3, 6}
        assert data["best_solved_seeds"] == sum(s["best"]["solved"] for s in data["seeds"])
        metrics = reader.read_run_metrics(combo, info)
        evaluated = np.isfinite(metrics["eval/mean_return"]).all(axis=1)
        assert list(np.flatnonzero(evaluated) + 1) == [3, 6]
        policy = load_policy(combo, seed_index=1, policy="best")
        assert policy(np.zeros(4, np.float32)) in (0, 1)


@pytest.mark.slow
def test_the_final_cross_check_compiles_beside_training_once_for_both_verdicts(
    tmp_path, monkeypatch
):
    """The JAX cross-check of the final evaluation starts compiling when the training's
    program has compiled (before any Gymnasium episode) and serves the final policies; the
    kept-best policies get their Gymnasium verdict only (nothing records a JAX replay of
    them); its returns are those of a program compiled at the end."""
    from jaxcart.run import greedy, lifecycle
    from jaxcart.run.spec import RunOptions, RunSpec
    from jaxcart.rundir.policy import run_params

    events = []
    compile_for, evaluate_params = greedy.CrossCheck.compile_for, greedy.evaluate_params

    def spy_compile(self, params):
        before = self._program
        compile_for(self, params)
        events.append("compile" if self._program is not before else "reuse")

    def spy_gym(*args, **kwargs):
        events.append("gymnasium")
        return evaluate_params(*args, **kwargs)

    monkeypatch.setattr(greedy.CrossCheck, "compile_for", spy_compile)
    monkeypatch.setattr(greedy, "evaluate_params", spy_gym)
    spec = RunSpec(EVERY, num_seeds=2, seed=3)
    outcome = lifecycle.run_new(spec, tmp_path / "run", RunOptions(eval_episodes=3))
    assert events == ["compile", "reuse", "gymnasium", "gymnasium"]

    monkeypatch.undo()  # a program compiled at the end, as before: the same returns
    params = run_params(tmp_path / "run").params
    fresh = greedy.CrossCheck(EVERY, 3, np.arange(2), 3).returns(params).result()
    np.testing.assert_array_equal(fresh, outcome.evaluation.jax_returns)

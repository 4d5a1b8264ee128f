"""``python -m jaxcart.tune``: search spaces checked before anything compiles, a study that
finishes with exactly its trials (interrupted, resumed, or shared by two processes), trials
grouped by shape, and its top trials trained again on fresh seeds."""

from __future__ import annotations

import importlib
import json
import os
import shlex
import signal
import subprocess
import sys
import time
import types
import uuid
from pathlib import Path

import numpy as np
import pytest

optuna = pytest.importorskip("optuna")

from helpers import TINY, TRAIN_ENV  # noqa: E402

from jaxcart import configfile, train, tune  # noqa: E402
from jaxcart.analysis.stats import iqm  # noqa: E402
from jaxcart.analysis.summary import Score  # noqa: E402
from jaxcart.core.config import TRACED_FIELDS, ConfigError, preset  # noqa: E402
from jaxcart.results.scores import make_entry  # noqa: E402
from jaxcart.run import search  # noqa: E402
from jaxcart.run.spec import Hooks, RunOptions, RunSpec  # noqa: E402
from jaxcart.rundir.reader import load_run, load_runs  # noqa: E402

# 8 iterations of 4 envs x 32 steps: a trial in well under a second once compiled
BASE = [
    "--num-envs=4",
    "--num-steps=32",
    "--total-timesteps=1024",
    "--minibatch-size=64",
    "--update-epochs=2",
    "--eval-episodes=2",
]
SMALL = TINY.__class__(**{**TINY.to_dict(), "total_timesteps": 1024})


def _states(storage: str, name: str) -> list[str]:
    study = optuna.load_study(study_name=name, storage=storage)
    return [t.state.name for t in study.get_trials()]


@pytest.mark.parametrize(
    ("space", "message"),
    [
        ("lerning_rate=log:1e-5:1e-2", "no such config field (did you mean learning_rate?)"),
        ("learning_rate=1e-2:1e-5", "low 0.01 must be below high 1e-05"),
        ("learning_rate=log:0:1e-2", "a log range must be above zero"),
        ("clip_coef", "malformed --space"),
        ("activation=0.1:0.3", "a range needs a number field"),
        ("num_envs=2,3", "--space num_envs=3"),  # 3 x 32 steps do not split into 64s
        ("num_envs=int:2:4", "--space num_envs=3"),  # every value of a small int range
        ("gamma=0.9,0.9", "give distinct choices"),
        ("learning_rate=log:1e-4:1e-2 --score return-at:2048", "some trials end at 1,024"),
    ],
)
def test_bad_space_is_one_line_before_anything_compiles(tmp_path, capsys, space, message):
    db = tmp_path / "study.db"
    space, *rest = space.split()
    code = tune.main([*BASE, "--space", space, *rest, "--storage", f"sqlite:///{db}"])
    err = capsys.readouterr().err
    assert code == 2
    assert message in err and len(err.strip().splitlines()) == 1, err
    assert not db.exists()  # refused before the study, let alone a compile


def test_space_parsing_draws_what_it_says():
    space = search.parse_space(
        [
            "learning_rate=log:1e-5:1e-2",
            "clip_coef=0.1:0.3",
            "num_envs=1,4,8",
            "hidden_sizes=32x32,64",
        ],
        preset("sb3"),
    )
    lr, clip, envs, sizes = space.values()
    assert (lr.low, lr.high, lr.log) == (1e-5, 1e-2, True)
    assert (clip.low, clip.high, clip.log) == (0.1, 0.3, False)
    assert envs.choices == (1, 4, 8) and sizes.choices == ("32x32", "64")
    assert search.config_value("hidden_sizes", "32x32") == (32, 32)
    static, traced = search.split_params(
        {"learning_rate": 1e-3, "clip_coef": 0.2, "num_envs": 4, "hidden_sizes": "64"}
    )
    assert static == {"num_envs": 4, "hidden_sizes": (64,)}
    assert traced == {"learning_rate": 1e-3, "clip_coef": 0.2}


def test_no_space_is_rl_zoo3s_current_float_ranges_and_the_old_one_stays_reachable():
    base = preset("sb3")
    space = search.parse_space([], base)
    assert all(search.field_of(p) in TRACED_FIELDS for p in space)  # every batch one program
    assert "vf_coef" not in space and "gamma" not in space
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=0))
    dists = space
    assert dists["one_minus_gamma"] == optuna.distributions.FloatDistribution(1e-4, 0.03, log=True)
    drawn = [search.split_params(study.ask(dists).params)[1] for _ in range(400)]
    values = {name: np.array([d[name] for d in drawn]) for name in drawn[0]}
    lr, gamma, lam = values["learning_rate"], values["gamma"], values["gae_lambda"]
    assert 1e-5 <= lr.min() and lr.max() <= 0.002 and values["max_grad_norm"].max() <= 2.0
    assert 0.97 <= gamma.min() and gamma.max() <= 0.9999 and 0.9 <= lam.min() <= lam.max() < 1
    # log-uniform: 1 - gamma under 1e-3 in log(10)/log(300) of the draws (uniform: 3%)
    assert abs(np.mean(1 - gamma < 1e-3) - 1 / np.log10(300)) < 0.1
    assert abs(np.mean(1 - lam < 1e-3) - 1 / 3) < 0.1
    assert abs(np.mean(lr < 1e-4) - 1 / np.log10(200)) < 0.1
    old = search.parse_space(["rl-zoo3-v2.5"], base)
    assert old["gamma"].high == 0.9999 and old["vf_coef"].low == 0.1
    assert old["learning_rate"].high == 1e-2 and not old["gamma"].log
    assert configfile.parse_with_config(tune.build_parser(), ["--space", "rl-zoo3-v2.5"]).space == [
        "rl-zoo3-v2.5"
    ]


def test_a_study_of_the_old_space_refuses_the_new_one(tmp_path, capsys):
    storage = f"sqlite:///{tmp_path}/study.db"
    study = optuna.create_study(storage=storage, study_name="old", direction="maximize")
    old = search.parse_space(["rl-zoo3-v2.5"], preset("sb3"))
    study.tell(study.ask(old), 1.0)
    assert tune.main([*BASE, "--storage", storage, "--study-name", "old"]) == 2
    err = capsys.readouterr().err
    assert "--space one_minus_gamma: study 'old' draws gamma as gamma" in err, err
    assert _states(storage, "old") == ["COMPLETE"]


def test_space_with_a_shape_combination_that_cannot_train_is_refused():
    base = preset("sb3", num_steps=64, minibatch_size=64, total_timesteps=10**9)
    with pytest.raises(ConfigError, match="--space group num_envs=8192,num_steps=4096: "):
        search.parse_space(["num_envs=1,8192", "num_steps=64,4096"], base)


def test_explicit_combinations_and_a_sweep_are_exclusive():
    with pytest.raises(ConfigError, match="combinations and sweep"):
        RunSpec(SMALL, sweep={"gamma": [0.9]}, combinations=({"gamma": 0.9},))
    with pytest.raises(ConfigError, match="only float hyperparameters"):
        RunSpec(SMALL, combinations=({"num_envs": 2},))


@pytest.mark.slow
def test_study_finishes_groups_by_shape_then_checks_its_top_trials_on_fresh_seeds(
    tmp_path, capsys, monkeypatch
):
    monkeypatch.chdir(tmp_path)
    storage = f"sqlite:///{tmp_path}/study.db"
    argv = [
        *BASE[1:3],
        "--minibatch-size=32",
        *BASE[4:],
        "--trials",
        "4",
        "--batch-trials",
        "4",
        "--num-seeds",
        "2",
    ]
    argv += [
        "--storage",
        storage,
        "--study-name",
        "demo",
        "--space",
        "learning_rate=log:1e-4:1e-2",
        "--space",
        "num_envs=2,4",
    ]
    argv += ["--sampler", "random", "--sampler-seed", "3", "--heldout-top", "2"]
    assert tune.main(argv) == 0
    out = capsys.readouterr().out
    study = optuna.load_study(study_name="demo", storage=storage)
    trials = study.get_trials()
    assert [t.state.name for t in trials] == ["COMPLETE"] * 4
    assert all(set(t.params) == {"learning_rate", "num_envs"} and t.value > 0 for t in trials)
    # one run directory (one program) per num_envs drawn, each trial a combination of it
    groups = {t.params["num_envs"] for t in trials}
    batch_dirs = sorted((tmp_path / "runs" / "demo").glob("trials-*"))
    assert len(batch_dirs) == len(groups)
    for t in trials:
        run = load_run(t.user_attrs["run_dir"])
        assert run.combination == {"learning_rate": pytest.approx(t.params["learning_rate"])}
        scores = make_entry(run, Score("auc")).scores
        np.testing.assert_allclose(scores, t.user_attrs["scores"])
    assert len(load_runs(batch_dirs)) == 4  # compare and plot read every trial
    # the top 2 trained again from a base seed no trial used, recorded in the study
    heldout = study.user_attrs["heldout"]
    top = sorted(trials, key=lambda t: -t.value)[:2]
    assert heldout["seed"] not in (0, 1) and set(heldout["scores"]) == {str(t.number) for t in top}
    heldout_dirs = sorted((tmp_path / "runs" / "demo").glob(f"heldout-{heldout['seed']}-*"))
    assert len(heldout_dirs) == len({t.params["num_envs"] for t in top})  # a program per shape
    for run in load_runs(heldout_dirs):
        assert json.loads((run.path / "config.json").read_text())["seed"] == heldout["seed"]
        scores = make_entry(run, Score("auc")).scores
        assert any(np.array_equal(scores, s) for s in heldout["scores"].values())
    assert "held-out iqm [range of 2 seeds]" in out and "95% CI" not in out
    # ranked by the held-out IQM; the printed command trains the winner on yet other seeds
    winner = max(top, key=lambda t: iqm(heldout["scores"][str(t.number)]))
    assert f"best on held-out seeds: trial {winner.number};" in out
    line = next(x for x in out.splitlines() if "python -m jaxcart.train" in x)
    words = shlex.split(line)[3:]
    assert words[words.index("--seed") + 1] == str(heldout["seed"] + 1)
    # ... with the trial's own settings: from the held-out seed, it gives its held-out scores
    words[words.index("--seed") + 1] = str(heldout["seed"])
    assert train.main([*words, "--quiet"]) == 0
    again = make_entry(load_run(words[words.index("--out") + 1]), Score("auc")).scores
    np.testing.assert_array_equal(again, heldout["scores"][str(winner.number)])
    assert "range of 2 seeds" in out and "95% CI" not in out  # two seeds: no CI


def _tuner(storage: str, out: Path, hooks: Hooks | None = None) -> search.Tuner:
    study, rdb = search.open_study(storage, "s", sampler="random", sampler_seed=0)
    space = search.parse_space(["learning_rate=log:1e-4:1e-2"], SMALL)
    options = RunOptions(eval_episodes=1)
    spec = RunSpec(SMALL, num_seeds=2)
    return search.Tuner(study, rdb, space, spec, out, options, Score("auc"), hooks or Hooks())


@pytest.mark.slow
def test_interrupted_mid_batch_then_rerun_ends_with_exactly_the_trials(tmp_path):
    storage = f"sqlite:///{tmp_path}/study.db"
    chunks: list[int] = []
    sent: list[int] = []

    def sigterm_in_second_batch(progress) -> None:
        if chunks and progress.iteration <= chunks[-1] and not sent:
            os.kill(os.getpid(), signal.SIGTERM)  # the second batch's first chunk
            sent.append(signal.SIGTERM)
        chunks.append(progress.iteration)

    tuner = _tuner(storage, tmp_path / "runs", Hooks(on_chunk=sigterm_in_second_batch))
    tuner.options = RunOptions(eval_episodes=1, chunk_size=2)
    with pytest.raises(search.BatchStopped) as stopped:
        tuner.run(4, 2)
    assert stopped.value.signum == signal.SIGTERM
    assert sorted(_states(storage, "s")) == ["COMPLETE"] * 2 + ["FAIL"] * 2
    _tuner(storage, tmp_path / "runs").run(4, 2)
    states = _states(storage, "s")
    assert states.count("COMPLETE") == 4 and states.count("RUNNING") == 0
    study = optuna.load_study(study_name="s", storage=storage)
    numbers = [t.number for t in study.get_trials() if t.state.name == "COMPLETE"]
    assert len(set(numbers)) == 4
    # each complete trial has its own run directory and scores
    done = [t for t in study.get_trials() if t.state.name == "COMPLETE"]
    assert len({t.user_attrs["run_dir"] for t in done}) == 4


@pytest.mark.slow
@pytest.mark.parametrize("backend", ["sqlite", "postgresql"])
def test_two_processes_share_one_study_without_duplicates(tmp_path, backend):
    storage, name = f"sqlite:///{tmp_path}/study.db", f"shared-{uuid.uuid4().hex[:8]}"
    if backend == "postgresql":  # a server .ci/run starts: postgresql+psycopg://...
        storage = os.environ.get("JAXCART_TEST_POSTGRES", "")
        if not storage:
            pytest.skip("JAXCART_TEST_POSTGRES not set: no PostgreSQL server to test against")
    argv = [*BASE, "--trials", "6", "--batch-trials", "2", "--num-seeds", "1", "--storage", storage]
    argv += ["--space", "learning_rate=log:1e-4:1e-2", "--study-name", name, "--quiet"]
    argv += ["--heldout-top", "0"]  # the search alone
    # the study exists before both start, as when a first process created it
    search.open_study(storage, name)
    try:
        procs = [
            subprocess.Popen(
                [sys.executable, "-m", "jaxcart.tune", *argv, "--out", str(tmp_path / f"p{i}")],
                env=TRAIN_ENV,
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                text=True,
            )
            for i in range(2)
        ]
        logs = [p.communicate(timeout=300)[0] for p in procs]
        assert [p.returncode for p in procs] == [0, 0], logs
        states = _states(storage, name)
    finally:  # a server database outlives the test
        optuna.delete_study(study_name=name, storage=storage)
    assert states.count("COMPLETE") == 6, states
    assert states.count("RUNNING") == 0
    dirs = [
        d for i in range(2) if (tmp_path / f"p{i}").exists() for d in (tmp_path / f"p{i}").iterdir()
    ]
    assert sum(len(load_runs([d])) for d in dirs) == 6  # every complete trial trained once


def test_space_from_a_config_file(tmp_path, capsys):
    config = tmp_path / "search.toml"
    config.write_text(
        'preset = "fast"\nspace = ["learning_rate=log:1e-5:1e-2", "clip_coef=0.3:0.1"]\n'
    )
    db = tmp_path / "study.db"
    assert tune.main(["--config", str(config), "--storage", f"sqlite:///{db}"]) == 2
    assert "--space clip_coef: low 0.3 must be below high 0.1" in capsys.readouterr().err
    args = configfile.parse_with_config(
        tune.build_parser(), ["--config", str(config), "--space", "gamma=0.9:0.99"]
    )
    assert args.preset == "fast"
    assert args.space == ["learning_rate=log:1e-5:1e-2", "clip_coef=0.3:0.1", "gamma=0.9:0.99"]


@pytest.mark.slow
def test_trials_of_a_killed_process_go_stale_and_are_asked_again(tmp_path, monkeypatch):
    monkeypatch.setattr(search, "STALE_GRACE_SECONDS", 1)
    storage = f"sqlite:///{tmp_path}/study.db"
    tuner = _tuner(storage, tmp_path / "runs")
    orphan = tuner._ask(1, 1)  # a process asked it, sent one heartbeat, and was killed
    with search.heartbeat(tuner.storage, tuner.study, orphan):
        pass
    time.sleep(2.5)  # SQLite keeps heartbeats to the second
    tuner.run(1, 1)
    assert sorted(_states(storage, "s")) == ["COMPLETE", "FAIL"]


def test_python_m_jaxcart_tune_is_the_tune_command(capsys):
    from jaxcart.__main__ import main

    assert main(["tune", "--space", "nope=1:2"]) == 2
    assert capsys.readouterr().err == "error: --space nope: no such config field\n"


@pytest.mark.slow
def test_a_batch_of_explicit_combinations_resumes_as_it_would_have_trained(tmp_path):
    from helpers import assert_same_run_dirs, stopped_run

    from jaxcart.run import lifecycle

    points = ({"learning_rate": 1e-3, "clip_coef": 0.1}, {"learning_rate": 3e-3, "clip_coef": 0.3})
    spec = RunSpec(SMALL, num_seeds=2, combinations=points)
    options = RunOptions(eval_episodes=1, chunk_size=2)
    lifecycle.run_new(spec, tmp_path / "whole", options)
    run, _ = stopped_run(spec, tmp_path / "stopped", options)
    run.close()
    lifecycle.resume_run(tmp_path / "stopped", options)
    for c in range(2):
        assert_same_run_dirs(
            tmp_path / "whole" / f"combo-{c:03d}", tmp_path / "stopped" / f"combo-{c:03d}"
        )
        assert load_run(tmp_path / "stopped" / f"combo-{c:03d}").combination == points[c]


def test_benchmark_reads_best_score_against_wall_time_from_a_study(tmp_path):
    bench = importlib.import_module("benchmarks.tune.__main__")
    storage = f"sqlite:///{tmp_path}/b.db"
    study = optuna.create_study(storage=storage, study_name="b", direction="maximize")
    for value in (10.0, 30.0, 20.0):
        study.tell(study.ask(), value)
    pruned = study.ask()
    pruned.report(99.0, 1)  # a pruned trial's value is its last report: never the best
    study.tell(pruned, state=optuna.trial.TrialState.PRUNED)
    started = study.get_trials()[0].datetime_start.timestamp() - 1.0
    curve = bench.study_curve(storage, "b", started)
    assert [best for _, best in curve] == [10.0, 30.0, 30.0]  # the best so far, in finish order
    assert all(seconds >= 1.0 for seconds, _ in curve)
    trials = bench.study_trials(storage, "b", started)
    assert [t["state"] for t in trials] == ["complete"] * 3 + ["pruned"]
    best = bench.best_curve(trials)
    assert [(score, number) for _, score, number in best] == [(10.0, 0), (30.0, 1)]
    assert bench.best_as_of(best, best[0][0]) == {
        "trial": 0,
        "score": 10.0,
        "found_at": best[0][0],
    }
    assert bench.best_as_of(best, best[0][0] - 0.01) is None
    assert bench.best_as_of(best, float("inf"))["trial"] == 1


def test_benchmark_runs_rl_zoo3_itself_with_the_same_budget(tmp_path):
    bench = importlib.import_module("benchmarks.tune.__main__")
    args = bench.parse_args(["--trials", "8", "--sb3-python", str(tmp_path / "python")])
    jax_cmd, zoo_cmd = bench.commands(args, tmp_path).values()
    assert jax_cmd[jax_cmd.index("--trials") + 1] == zoo_cmd[zoo_cmd.index("--n-trials") + 1]
    assert zoo_cmd[:3] == [str(tmp_path / "python"), "-m", "rl_zoo3.train"]
    zoo_flags = {"--sampler": "tpe", "--pruner": "median", "--study-name": "rl-zoo3"}
    for flag, value in zoo_flags.items():
        assert zoo_cmd[zoo_cmd.index(flag) + 1] == value
    assert "--optimize" in zoo_cmd and "--no-optim-plots" in zoo_cmd
    assert "-n" not in zoo_cmd  # rl-zoo3's own CartPole budget, 100k steps
    assert jax_cmd[jax_cmd.index("--total-timesteps") + 1] == "100000"
    assert jax_cmd[jax_cmd.index("--space") + 1] == "rl-zoo3"
    assert jax_cmd[jax_cmd.index("--heldout-top") + 1] == "0"
    assert "--no-compile-cache" in jax_cmd  # a cold compile, timed, unless --warm-cache
    quick = bench.parse_args(["--quick"])
    zoo_quick = bench.commands(quick, tmp_path)["rl-zoo3"]
    assert zoo_quick[zoo_quick.index("-n") + 1] == str(bench.QUICK["timesteps"])
    # a jaxcart trial trained again: its values, rl-zoo3's shape, the held-out seeds
    params = {"learning_rate": 1e-3, "one_minus_gamma": 0.02, "clip_coef": 0.3}
    words = bench.jaxcart_train_command(quick, params, tmp_path / "h")
    assert words[1:3] == ["-m", "jaxcart.train"]
    assert "--gamma=0.98" in words and "--learning-rate=0.001" in words
    assert "--num-envs=8" in words and "--no-anneal-lr" in words
    assert words[words.index("--num-seeds") + 1] == str(quick.heldout_seeds)
    assert words[words.index("--seed") + 1] == str(quick.heldout_seed)


def test_rl_zoo3_heldout_params_read_back_as_rl_zoo3_converts_them():
    """``-params`` words evaluate (rl-zoo3's StoreDict: ``eval``, ``nn`` torch.nn) to the
    values its converter gave; the greedy episodes start where jaxcart's evaluation's do."""
    from jaxcart.core.solved import EVAL_SEED

    zoo = importlib.import_module("benchmarks.tune.zoo_heldout")
    assert zoo.EVAL_SEED == EVAL_SEED

    class Tanh:
        pass

    converted = {
        "policy_kwargs": {"net_arch": {"pi": [64], "vf": [64]}, "activation_fn": Tanh},
        "gamma": 0.9876,
        "n_steps": 256,
    }
    nn = types.SimpleNamespace(Tanh=Tanh)
    for name, value in converted.items():
        key, _, text = zoo.param_text(name, value).partition(":")
        assert key == name and eval(text, {"nn": nn}) == value


def test_the_pruner_scores_a_partial_run_as_compare_scores_a_whole_one():
    """The rung scores are curves.auc of the iterations so far (one definition): on an
    Acrobot-like curve, an iteration before the first episode ends is -500, not 0."""
    from jaxcart.analysis import stats
    from jaxcart.analysis.summary import auc

    class Trial:
        number, reported = 0, []

        def report(self, value: float, step: int) -> None:
            self.reported.append((step, value))

        def should_prune(self) -> bool:
            return False

    config = types.SimpleNamespace(num_iterations=8, env="Acrobot-v1")
    spec = types.SimpleNamespace(num_seeds=2, config=config)
    reporter = search.RungReporter([Trial()], spec)
    returns = np.linspace(-480, -100, 16).reshape(8, 2)
    returns[:3, 1] = np.nan  # seed 1's first episode ends in iteration 4
    for start in (0, 5):  # two chunks
        rows = returns[start : start + 5]
        chunk = {search.RETURN_METRIC: rows}
        reporter.on_chunk(types.SimpleNamespace(iteration=start + len(rows), metrics=chunk))
    for step, value in Trial.reported:
        so_far = auc(returns[: step * 8 // 1000], "Acrobot-v1")
        assert value == pytest.approx(float(stats.iqm(so_far)))
    assert [s for s, _ in Trial.reported] == [125 * i for i in range(1, 8)]
    assert reporter.last_scores[0][1] < reporter.last_scores[0][0]  # the late seed is lower


@pytest.mark.slow
def test_a_space_of_shape_settings_alone_completes_its_trials(tmp_path, capsys):
    storage = f"sqlite:///{tmp_path}/study.db"
    argv = [*BASE[1:3], "--minibatch-size=32", *BASE[4:], "--trials", "2", "--num-seeds", "1"]
    argv += ["--batch-trials", "2", "--space", "num_envs=2,4", "--heldout-top", "0"]
    argv += ["--storage", storage, "--out", str(tmp_path / "runs"), "--quiet"]
    argv += ["--sampler", "random", "--sampler-seed", "0"]
    assert tune.main(argv) == 0
    assert _states(storage, "jaxcart") == ["COMPLETE"] * 2
    study = optuna.load_study(study_name="jaxcart", storage=storage)
    for t in study.get_trials():  # each trial a combination of no float values
        run = load_run(t.user_attrs["run_dir"])
        np.testing.assert_allclose(make_entry(run, Score("auc")).scores, t.user_attrs["scores"])

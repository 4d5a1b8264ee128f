"""``python -m jaxcart.train`` in-process through ``main(argv)``, and ``load_policy``."""

from __future__ import annotations

import csv
import json
import re
import signal
import time

import gymnasium as gym
import numpy as np
import pytest
from helpers import WAIT_S, assert_same_run_dirs, seal, start_train, tiny_args

import jaxcart
from jaxcart.core.metrics import METRIC_NAMES
from jaxcart.rundir import layout, reader
from jaxcart.rundir.files import RunDirError
from jaxcart.rundir.reader import read_checkpoint_meta
from jaxcart.train import build_parser, main

SMALL = [*tiny_args(1024, eval_episodes=3), "--no-compile-cache"]


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "small"
    code = main([*SMALL, "--num-seeds", "2", "--seed", "7", "--out", str(out)])
    assert code == 0
    return out


def test_run_directory_contents(small_run, capsys):
    info = json.loads((small_run / "config.json").read_text())
    assert info["num_seeds"] == 2 and info["seed"] == 7 and info["preset"] == "sb3"
    assert info["config"]["num_envs"] == 4 and info["config"]["learning_rate"] == 3e-4
    assert info["versions"]["jax"]

    with open(small_run / "metrics.csv") as f:
        rows = list(csv.DictReader(f))
    iterations = 1024 // (4 * 32)
    assert len(rows) == 2 * iterations
    for name in (*METRIC_NAMES, "time/fps"):
        assert name in rows[0]
    assert {r["seed_index"] for r in rows} == {"0", "1"}
    assert [int(r["env_steps"]) for r in rows[:iterations]] == [
        128 * (i + 1) for i in range(iterations)
    ]
    assert all(np.isfinite(float(r["train/value_loss"])) for r in rows)
    assert all(float(r["time/fps"]) > 0 for r in rows)

    params = reader.load_params(small_run)
    assert params["params"]["actor"]["hidden_0"]["kernel"].shape == (2, 4, 64)
    assert not np.allclose(
        params["params"]["actor"]["out"]["kernel"][0], params["params"]["actor"]["out"]["kernel"][1]
    )

    ev = json.loads((small_run / "evaluation.json").read_text())
    assert len(ev["seeds"]) == 2 and len(ev["seeds"][0]["gymnasium_returns"]) == 3
    for seed in ev["seeds"]:
        assert seed["solved"] == all(r == 500 for r in seed["gymnasium_returns"])


@pytest.mark.slow
def test_output_reports_compile_table_and_throughput(tmp_path, capsys):
    code = main([*SMALL, "--out", str(tmp_path / "r")])
    out = capsys.readouterr().out
    assert code == 0
    assert "compiled the fused training step in" in out
    assert "gym mean" in out and "solved" in out
    assert "env steps at" in out and "wall" in out


def test_load_policy_runs_in_gymnasium(small_run):
    policy = jaxcart.load_policy(small_run, seed_index=1)
    env = gym.make("CartPole-v1")
    obs, _ = env.reset(seed=0)
    action = policy(obs)
    assert isinstance(action, int) and env.action_space.contains(action)
    env.step(action)
    batch = policy(np.zeros((5, 4), np.float32))
    assert batch.shape == (5,)
    # the NumPy policy agrees with the JAX network's argmax
    from jaxcart.core.networks import ActorCritic

    params = reader.load_params(small_run)
    one = {
        "params": {
            k: {n: {p: v[1] for p, v in layer.items()} for n, layer in sub.items()}
            for k, sub in params["params"].items()
        }
    }
    obs = np.random.default_rng(0).normal(size=(100, 4)).astype(np.float32)
    logits = np.asarray(ActorCritic().logits(one, obs))
    np.testing.assert_array_equal(policy(obs), logits.argmax(-1))


def test_load_policy_rejects_non_runs(tmp_path, small_run):
    with pytest.raises(RunDirError, match="not a jaxcart run"):
        jaxcart.load_policy(tmp_path)
    with pytest.raises(RunDirError, match="not a directory"):
        jaxcart.load_policy(tmp_path / "missing")
    with pytest.raises(RunDirError, match="seed_index"):
        jaxcart.load_policy(small_run, seed_index=5)


def test_same_seed_same_metrics(small_run, tmp_path):
    """Re-running the same command gives bit-identical metrics and parameters."""
    again = tmp_path / "again"
    assert main([*SMALL, "--num-seeds", "2", "--seed", "7", "--out", str(again)]) == 0
    a, b = (
        reader.read_metrics_csv(small_run / "metrics.csv"),
        reader.read_metrics_csv(again / "metrics.csv"),
    )
    for name in METRIC_NAMES:
        np.testing.assert_array_equal(a[name], b[name])
    pa, pb = reader.load_params(small_run), reader.load_params(again)
    np.testing.assert_array_equal(
        pa["params"]["critic"]["out"]["kernel"], pb["params"]["critic"]["out"]["kernel"]
    )


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--minibatch-size", "100"], "does not divide"),
        (["--learning-rate", "-1"], "learning_rate must be > 0"),
        (["--gamma", "1.5"], "gamma must be in (0, 1]"),
        (["--num-seeds", "0"], "--num-seeds must be a positive integer"),
        (["--preset", "nope"], "unknown preset"),
        (["--bogus-option", "1"], "unrecognized arguments"),
        (["--num-envs", "two"], "--num-envs: expected a whole number"),
        (["--total-timesteps", "1.5e0"], "--total-timesteps: expected a whole number"),
        (["--total-timesteps", "-5"], "--total-timesteps must be a positive integer, got -5"),
        (["--update-epochs", "0"], "--update-epochs must be a positive integer, got 0"),
        (["--lr", "1e-3"], "unrecognized arguments: --lr 1e-3 (did you mean --learning-rate?)"),
        (["--hidden-sizes", "64,x"], "comma-separated integers"),
        (["--hidden-sizes", "64", "64"], "comma-separated list: --hidden-sizes 64,64)"),
        (["--hidden-sizes", "8", "8", "8"], "comma-separated list: --hidden-sizes 8,8,8)"),
    ],
)
def test_bad_input_is_one_line_error(argv, message, capsys, tmp_path):
    code = main([*argv, "--out", str(tmp_path / "never")])
    err = capsys.readouterr().err
    assert code == 2
    assert message in err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "never").exists()


def test_non_empty_out_dir_refused(tmp_path, capsys):
    (tmp_path / "keep.txt").write_text("earlier work")
    assert main([*SMALL, "--out", str(tmp_path)]) == 2
    assert "not empty" in capsys.readouterr().err
    assert (tmp_path / "keep.txt").read_text() == "earlier work"


def test_dry_run_says_what_would_train_and_writes_nothing(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["--dry-run", "--num-seeds", "3", "--total-timesteps", "4096"]) == 0
    out = capsys.readouterr().out
    assert "3 seed(s) x 4,096 env steps (2 iterations of 1 env(s) x 2048 steps)" in out
    assert "the time assumes an otherwise idle machine" in out  # what the estimate rests on
    assert list(tmp_path.iterdir()) == []


def test_run_new_into_a_used_directory_names_the_python_way_to_resume(tmp_path):
    (tmp_path / "keep.txt").write_text("earlier work")
    with pytest.raises(jaxcart.ConfigError, match=r"jaxcart\.resume_run\("):
        jaxcart.run_new(jaxcart.RunSpec(jaxcart.preset("sb3")), out=tmp_path)


def test_help_lists_every_config_field_with_its_docstring():
    text = build_parser().format_help()
    for flag, doc in (
        ("--minibatch-size", "Transitions per gradient step"),
        ("--bootstrap-truncation", "V(final_obs)"),
        ("--preset", "sb3, purejaxrl (annealed lr), fast (annealed lr)"),
        ("--num-seeds", "independent"),
        ("--resume", "anneals over N from the resume on"),
    ):
        assert flag in text and doc in " ".join(text.split())  # help wraps lines


CLI_SMALL = [*tiny_args(12800, num_seeds=2), "--no-compile-cache"]


@pytest.mark.slow
def test_cli_sigterm_then_resume_matches_uninterrupted(tmp_path):
    """SIGTERM mid-run: a checkpoint and a resume hint; --resume finishes bit-identically."""
    reference = tmp_path / "ref"
    assert main([*CLI_SMALL, "--out", str(reference)]) == 0

    out = tmp_path / "interrupted"
    proc = start_train(*CLI_SMALL, "--out", str(out), "--checkpoint-every", "0.05")
    deadline = time.monotonic() + WAIT_S
    while not (out / "checkpoint.npz").exists() and proc.poll() is None:
        assert time.monotonic() < deadline, f"no checkpoint in {WAIT_S:.0f} s"
        time.sleep(0.02)
    proc.send_signal(signal.SIGTERM)
    text, _ = proc.communicate(timeout=120)
    if proc.returncode == 0:
        pytest.skip("the run finished before SIGTERM arrived")
    assert proc.returncode == 128 + signal.SIGTERM, text
    assert "resume with: python -m jaxcart.train --resume" in text
    stopped_at = read_checkpoint_meta(out / "checkpoint.npz")["iteration"]
    assert 0 <= stopped_at < 100

    proc = start_train("--resume", str(out), "--quiet")
    text, _ = proc.communicate(timeout=300)
    assert proc.returncode == 0, text
    assert f"resuming from iteration {stopped_at}/100" in text
    assert_same_run_dirs(reference, out)


def test_resume_errors(tmp_path, capsys):
    assert main(["--resume", str(tmp_path / "missing")]) == 2
    assert "cannot resume" in capsys.readouterr().err
    assert main(["--resume", str(tmp_path), "--learning-rate", "1e-3"]) == 2
    assert "drop --learning-rate" in capsys.readouterr().err


# --- the command line itself: spelling, help, version ------------------------------------


def _commands():
    from jaxcart import compare, evaluate, plot

    return {"train": main, "evaluate": evaluate.main, "plot": plot.main, "compare": compare.main}


def _parsers():
    from jaxcart import compare, evaluate, plot

    return [build_parser(), evaluate.build_parser(), plot.build_parser(), compare.build_parser()]


@pytest.mark.parametrize(
    "command, argv, hint",
    [
        ("train", ["--learn", "1e-3"], "did you mean --learning-rate?"),
        ("train", ["--num_seeds", "2"], "did you mean --num-seeds?"),
        ("train", ["--lerning-rate", "1e-3"], "did you mean --learning-rate?"),
        ("train", ["--epochs", "3"], "did you mean --update-epochs?"),
        ("train", ["--lr", "1e-3"], "did you mean --learning-rate?"),
        ("train", ["--n-envs", "8"], "did you mean --num-envs?"),
        ("train", ["--n_steps", "128"], "did you mean --num-steps?"),
        ("train", ["--batch-size", "64"], "did you mean --minibatch-size?"),
        ("train", ["--clip-range", "0.2"], "did you mean --clip-coef?"),
        ("train", ["--timesteps", "1e5"], "did you mean --total-timesteps?"),
        ("train", ["--seeds", "4"], "did you mean --num-seeds?"),
        ("train", ["--n-eval-episodes", "5"], "did you mean --eval-episodes?"),
        ("evaluate", ["RUN", "--n-eval-episodes", "5"], "did you mean --episodes?"),
        ("plot", ["RUN", "--output-dir", "x"], "did you mean --out?"),
        ("evaluate", ["RUN", "--episode", "3"], "did you mean --episodes?"),
        ("plot", ["RUN", "--lab", "x"], "did you mean --label?"),
        ("compare", ["RUN", "--base", "RUN"], "did you mean --baseline?"),
    ],
)
def test_abbreviations_refused_with_a_suggestion(command, argv, hint, tmp_path, capsys):
    code = _commands()[command]([*argv, "--out", str(tmp_path / "never")])
    err = capsys.readouterr().err
    assert code == 2 and "unrecognized arguments" in err and hint in err, err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert not (tmp_path / "never").exists()


def test_every_alias_names_an_option_of_a_command():
    """Each name of :data:`cli.ALIASES` suggests an option that a command really has, and a
    command suggests the first of its candidates that it has."""
    from jaxcart import cli

    options = {p.prog: list(p._option_string_actions) for p in _parsers()}
    for alias, candidates in cli.ALIASES.items():
        held = {prog: [c for c in candidates if c in opts] for prog, opts in options.items()}
        assert any(held.values()), (alias, candidates)
        for prog, found in held.items():
            if found and f"--{alias}" not in options[prog]:  # else spelled right there
                assert cli.suggestion(f"--{alias}", options[prog]) == found[0], (prog, alias)
    train = options["python -m jaxcart.train"]
    assert cli.suggestion("--lr", train) == "--learning-rate"  # not --anneal-lr by spelling
    assert cli.suggestion("--LR=3e-4", train) == "--learning-rate"


@pytest.mark.parametrize(
    "text, value",
    [("2048", 2048), ("100_000", 100_000), ("1e5", 100_000), ("1.5E5", 150_000), (" 8 ", 8)],
)
def test_counts_read_as_users_write_them(text, value):
    from jaxcart import cli

    assert cli.count(text) == value and type(cli.count(text)) is int


@pytest.mark.parametrize(
    "text, message",
    [
        ("1.5e0", "expected a whole number"),
        ("2.5", "expected a whole number"),
        ("four", "expected a whole number"),
        ("nan", "expected a whole number"),
        ("inf", "expected a whole number"),
        ("0", "must be a positive integer, got 0"),
        ("-1e3", "must be a positive integer, got -1e3"),
        ("1e999999999", "must be at most"),
    ],
)
def test_counts_refused(text, message):
    import argparse

    from jaxcart import cli

    with pytest.raises(argparse.ArgumentTypeError, match=re.escape(message)):
        cli.count(text)


def test_evaluate_episodes_is_a_count(small_run, capsys):
    from jaxcart import evaluate

    assert evaluate.main([str(small_run), "--episodes", "2.5"]) == 2
    err = capsys.readouterr().err
    assert "--episodes: expected a whole number" in err and len(err.splitlines()) == 1
    assert evaluate.main([str(small_run), "--episodes", "2e0"]) == 0
    assert "reset seeds 1000000...1000001" in capsys.readouterr().out


def test_unknown_options_without_a_near_spelling_get_no_hint(capsys):
    assert main(["--zzzz"]) == 2
    err = capsys.readouterr().err
    assert "unrecognized arguments: --zzzz" in err and "did you mean" not in err


def test_help_shows_one_default_per_option():
    from jaxcart.core.config import PPOConfig, config_fields

    for parser in _parsers():
        text = parser.format_help()
        assert "(default: None)" not in text and "%%" not in text, parser.prog
        assert "(default: [])" not in text and "(default: False)" not in text, parser.prog
        for block in re.split(r"\n  (?=-)", text):  # one option's lines
            assert len(re.findall(r"\(default", block)) <= 1, (parser.prog, block)
    text = build_parser().format_help()
    blocks = {b.split()[0]: " ".join(b.split()) for b in re.split(r"\n  (?=-)", text)}
    sb3 = PPOConfig()
    for f in config_fields():  # the PPO group shows the sb3 preset's value of every field
        block = blocks["--" + f.name.replace("_", "-") + ("," if f.type == "bool" else "")]
        assert "(default: " in block, block
    assert "(default: 0.0003)" in blocks["--learning-rate"] and sb3.learning_rate == 3e-4
    assert "(default: 64,64)" in blocks["--hidden-sizes"]
    assert "(default: off)" in blocks["--anneal-lr,"]
    assert "(default: sb3)" in blocks["--preset"] and "(default: 1)" in blocks["--num-seeds"]
    from jaxcart import evaluate, plot

    gif_seed = " ".join(evaluate.build_parser().format_help().split())
    assert "(default: 1000000, the first evaluation episode's)" in gif_seed
    assert "95% bootstrap" in " ".join(plot.build_parser().format_help().split())


@pytest.mark.parametrize("command", ["train", "evaluate", "plot", "compare"])
def test_version_on_every_command(command, capsys):
    assert _commands()[command](["--version"]) == 0
    assert capsys.readouterr().out == f"jaxcart {jaxcart.__version__}\n"


def test_help_returns_zero_in_process(capsys):
    assert main(["--help"]) == 0
    assert "--learning-rate" in capsys.readouterr().out


def test_header_names_what_overrides_the_preset(tmp_path):
    from types import SimpleNamespace

    from jaxcart.core.config import preset
    from jaxcart.report import header_line
    from jaxcart.run.sweep import RunGrid

    def header(config, grid=None, name="sb3"):
        run = SimpleNamespace(grid=grid or RunGrid(2), config=config, preset=name, out=tmp_path)
        return header_line(run, 2, "cpu")

    assert "| preset sb3 | 2 seed(s) x" in header(preset("sb3"))
    changed = header(preset("sb3", learning_rate=1e-3, hidden_sizes=(32, 32)))
    assert "| preset sb3 + learning_rate=0.001, hidden_sizes=32,32 |" in changed
    assert "| preset fast + anneal_lr=False |" in header(
        preset("fast", anneal_lr=False), name="fast"
    )
    one = header(preset("sb3"), RunGrid(2, ({"learning_rate": 1e-3},)))
    assert "| 1 combination x 2 seed(s) x" in one
    two = header(preset("sb3"), RunGrid(2, ({"gamma": 0.9}, {"gamma": 0.99})))
    assert "| 2 combinations x 2 seed(s) x" in two


@pytest.mark.slow
def test_run_header_shows_the_overrides(tmp_path, capsys):
    assert main([*SMALL, "--learning-rate", "1e-3", "--out", str(tmp_path / "r")]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert first.startswith("jaxcart PPO | preset sb3 + num_envs=4, num_steps=32, ")
    assert "learning_rate=0.001 |" in first


# --- what a new user reads after training ------------------------------------------------


def _next_steps(out: str) -> list[list[str]]:
    """The commands of the "next:" block, split as a shell would (comments dropped)."""
    import shlex

    block = out.split("\nnext:\n", 1)[1].splitlines()
    return [shlex.split(line, comments=True) for line in block if line.startswith("  python")]


def _run_printed(command: list[str]) -> int:
    """Runs ``python -m jaxcart.X ARGS`` as printed, in-process through X's ``main``."""
    import importlib

    assert command[:2] == ["python", "-m"], command
    return importlib.import_module(command[2]).main(command[3:])


@pytest.mark.slow
def test_a_run_ends_with_next_steps_that_work(tmp_path, capsys, monkeypatch):
    """Counts in scientific notation, the evaluation table's columns explained, the next
    steps (quoted paths) runnable as printed; resuming the finished run says how to extend
    it, and the extension's summary says which training time is whose."""
    import shlex

    monkeypatch.chdir(tmp_path)
    out = tmp_path / "my run"  # a space: the printed paths must be quoted
    argv = [*tiny_args(1024, eval_episodes=3), "--total-timesteps", "5.12e2", "--num-steps"]
    assert main([*argv, "3.2e1", "--no-compile-cache", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    info = json.loads((out / "config.json").read_text())
    assert info["config"]["total_timesteps"] == 512 and info["config"]["num_steps"] == 32
    columns = text.split("train ep_rew_mean\n", 1)[1].splitlines()[2]  # under the one seed
    assert columns.startswith("gym: 3 greedy episodes in Gymnasium (reset seeds 1000000..1000002)")
    assert "jaxcart mean: 3 greedy episodes in jaxcart's JAX env from other start" in columns
    commands = _next_steps(text)
    assert [c[2] for c in commands] == ["jaxcart.plot", "jaxcart.evaluate", "jaxcart.compare"]
    assert f"python -m jaxcart.plot {shlex.quote(str(out))}" in text
    assert commands[1][3:] == [str(out), "--gif", str(out / "seed0.gif")]
    assert commands[2][3:] == [str(out), "OTHER_RUN"]
    for command in commands[:2]:
        assert _run_printed(command) == 0, command
    assert (out / "curves.png").exists() and (out / "seed0.gif").exists()

    capsys.readouterr()
    assert main(["--resume", str(out)]) == 2
    err = capsys.readouterr().err
    assert "already finished" in err and len(err.splitlines()) == 1
    assert (
        f"python -m jaxcart.train --resume {shlex.quote(str(out))} --total-timesteps N, "
        "with N above its current 512 env steps per seed" in err
    )

    assert main(["--resume", str(out), "--total-timesteps", "1_024", "--quiet"]) == 0
    text = capsys.readouterr().out
    elapsed = read_checkpoint_meta(out / layout.CHECKPOINT_FILE)["elapsed"]
    found = re.search(r"train ([\d.]+) s this session and ([\d.]+) s in all, eval", text)
    assert found and found[2] == f"{elapsed:.1f}", text
    assert float(found[1]) <= float(found[2])
    assert "512 env steps this session at" in text

    from jaxcart.rundir import files

    info = json.loads((out / "config.json").read_text())
    info["config"]["anneal_lr"] = True  # as the fast and purejaxrl presets have it
    info.pop("digest")  # a run made so (a hand edit alone is refused for its digest)
    info["digest"] = files.json_digest(info)
    (out / "config.json").write_text(json.dumps(info))
    seal(out)
    assert main(["--resume", str(out)]) == 2
    err = capsys.readouterr().err
    assert "with N above its current 1,024 env steps per seed; its annealed learning rate" in err
    assert "anneals over N from here on" in err and len(err.splitlines()) == 1


@pytest.mark.slow
def test_a_sweep_table_agrees_with_the_plot_and_ends_with_next_steps(tmp_path, capsys):
    """The sweep table's plain gym mean is the plot's "mean return" (the IQM beside it is
    another statistic, and the line under the table says so); the next steps run as printed."""
    from jaxcart.results import figure
    from jaxcart.rundir.reader import load_runs

    out = tmp_path / "sweep"
    sweep = ["--sweep", "learning_rate=1e-3,3e-4", "--num-seeds", "2", "--no-compile-cache"]
    assert main([*tiny_args(256, eval_episodes=2), *sweep, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "IQM: interquartile mean (middle 50%) of the seeds' scores (each seed's mean" in text
    assert "gym mean: the plain mean of the seeds' mean greedy Gymnasium returns" in text
    table = text.split("Sweep ranking", 1)[1].splitlines()
    header = re.split(r"\s{2,}", table[1].strip())
    column, combo = header.index("gym mean"), header.index("combo")
    for row in table[3:5]:
        cells = re.split(r"\s{2,}", row.strip())
        run = load_runs([out / f"combo-{int(cells[combo]):03d}"])[0]
        summary = " ".join(figure._summary_lines(run))
        found = re.search(r"mean return ([\d.]+)", summary)
        assert found and found[1] == cells[column], (cells, summary)
    best = int(table[3].split()[combo])
    commands = _next_steps(text)
    assert commands[0][3:] == [str(out), "--out", str(out / "curves.png")]
    assert commands[1][3:5] == [str(out), "--combination"] and commands[1][5] == str(best)
    assert commands[2][3:] == [str(out)]
    assert _run_printed(commands[0]) == 0 and (out / "curves.png").exists()


def test_the_second_signal_line_names_the_checkpoints_iteration(tmp_path):
    from types import SimpleNamespace

    from jaxcart.core.config import PPOConfig
    from jaxcart.report import interrupted_text

    (tmp_path / "config.json").write_text("{}")
    config = PPOConfig(total_timesteps=8 * 2048)

    def run(meta, waves=1):
        plan = SimpleNamespace(num_waves=waves)
        directory = SimpleNamespace(checkpoint_meta=meta)
        return SimpleNamespace(out=tmp_path, directory=directory, config=config, plan=plan)

    text = interrupted_text(run({"iteration": 0}), 2)
    assert f"the checkpoint in {tmp_path} (at iteration 0/8) is intact" in text
    assert text.endswith(f"resume with: python -m jaxcart.train --resume {tmp_path}")
    assert "(at iteration 3/8 of wave 2/5)" in interrupted_text(
        run({"iteration": 3, "wave": 1}, waves=5), 2
    )
    assert "before the first checkpoint" in interrupted_text(run(None), 2)
    assert "no run directory" in interrupted_text(None, 2)

"""``python -m jaxcart.train --config FILE``: TOML, YAML, rl-zoo3's ``ppo.yml`` and a run's own
``config.json``; the command line overrides the file; unknown keys get one line each."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from helpers import assert_same_run_dirs, tiny_args

from jaxcart import cli, configfile
from jaxcart.train import TrainOptions, build_parser, main

# rl-zoo3's hyperparams/ppo.yml entry for CartPole-v1, with another env around it and keys
# jaxcart has no equivalent for
ZOO_YML = """\
atari:
  env_wrapper:
    - stable_baselines3.common.atari_wrappers.AtariWrapper
  n_envs: 8
CartPole-v1:
  n_envs: 8
  n_timesteps: !!float 1e5
  policy: 'MlpPolicy'
  n_steps: 32
  batch_size: 256
  gae_lambda: 0.8
  gamma: 0.98
  n_epochs: 20
  ent_coef: 0.0
  learning_rate: lin_0.001
  clip_range: lin_0.2
  normalize: false
  policy_kwargs: "dict(ortho_init=False)"
Pendulum-v1:
  n_envs: 4
"""


def _options(argv: list[str]) -> TrainOptions:
    return TrainOptions.from_args(configfile.parse_with_config(build_parser(), argv), argv)


def _config(argv: list[str]):
    return _options(argv).run_spec().config


@pytest.mark.quick
def test_toml_keys_spelled_either_way_and_the_command_line_wins(tmp_path):
    path = tmp_path / "ppo.toml"
    path.write_text(
        'preset = "fast"\nnum_seeds = 3\nlearning-rate = 1e-3\nhidden_sizes = [32, 32]\n'
        "norm_adv = false\nquiet = true\n[sweep]\nclip_coef = [0.1, 0.3]\n"
    )
    opts = _options(["--config", str(path), "--num-seeds", "5"])
    assert (opts.preset, opts.num_seeds, opts.quiet) == ("fast", 5, True)
    assert opts.sweep == ("clip_coef=0.1,0.3",)
    config = opts.run_spec().config
    assert (config.learning_rate, config.hidden_sizes, config.norm_adv) == (1e-3, (32, 32), False)
    assert config.num_envs == 4  # the fast preset's, not set by the file
    assert _config(["--config", str(path), "--learning-rate", "2e-3"]).learning_rate == 2e-3


@pytest.mark.quick
def test_yaml_file(tmp_path):
    path = tmp_path / "ppo.yaml"
    path.write_text("num_envs: 2\nnum-steps: 64\nactivation: relu\nanneal_lr: true\n")
    config = _config(["--config", str(path)])
    assert (config.num_envs, config.num_steps, config.activation, config.anneal_lr) == (
        2,
        64,
        "relu",
        True,
    )


@pytest.mark.quick
def test_rl_zoo3_ppo_yml_through_sb3s_names(tmp_path, capsys):
    path = tmp_path / "ppo.yml"
    path.write_text(ZOO_YML)
    config = _config(["--config", str(path)])
    assert config.num_envs == 8 and config.num_steps == 32 and config.minibatch_size == 256
    assert config.update_epochs == 20 and config.total_timesteps == 100_000
    assert (config.gamma, config.gae_lambda, config.ent_coef) == (0.98, 0.8, 0.0)
    # lin_X: X annealed to 0 on SB3's progress (tests/test_ppo.py checks the schedule)
    assert (config.learning_rate, config.anneal_lr, config.clip_coef) == (1e-3, True, 0.2)
    assert config.anneal_clip and config.anneal_progress == "sb3"
    notes = capsys.readouterr().err.splitlines()
    assert len(notes) == 2, notes  # normalize, policy_kwargs
    assert any("normalize is not supported by jaxcart; ignored" in n for n in notes)
    assert any("policy_kwargs is not supported by jaxcart; ignored" in n for n in notes)


def test_rl_zoo3_file_without_cartpole_is_refused(tmp_path, capsys):
    path = tmp_path / "ppo.yml"
    path.write_text("Pendulum-v1:\n  n_envs: 4\n")
    assert main(["--config", str(path), "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert err == f"error: --config {path}: no CartPole-v1 entry (it has Pendulum-v1)\n"


@pytest.mark.quick
def test_unknown_keys_get_one_line_each(tmp_path, capsys):
    path = tmp_path / "ppo.toml"
    path.write_text("lr = 1e-3\nnum_seed = 2\nbogus = 1\n")
    assert main(["--config", str(path), "--dry-run"]) == 2
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 3 and all(line.startswith(f"error: --config {path}: ") for line in lines)
    assert "'num_seed' is no option of this command (did you mean --num-seeds?)" in lines[1]
    assert lines[2].endswith("'bogus' is no option of this command")


@pytest.mark.parametrize(
    ("name", "text", "message"),
    [
        ("bad.toml", "learning_rate = ", "not valid TOML"),
        ("bad.yaml", "- a list\n- at the top\n", "expected a mapping of options"),
        ("bad.toml", "num_envs = -2\n", "--num-envs must be a positive integer"),
        ("bad.toml", "norm_adv = 'yes'\n", "--norm-adv in a config file takes true or false"),
        ("bad.ini", "x=1\n", "expected a .toml, .yml, .yaml or .json file"),
    ],
)
def test_bad_files_are_one_line(tmp_path, capsys, name, text, message):
    path = tmp_path / name
    path.write_text(text)
    assert main(["--config", str(path), "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err and str(path) in err, err


def test_missing_file_is_one_line(tmp_path, capsys):
    assert main(["--config", str(tmp_path / "none.toml"), "--dry-run"]) == 2
    assert capsys.readouterr().err.count("\n") == 1


@pytest.mark.slow
def test_a_runs_config_json_trains_the_same_run_again(tmp_path: Path, capsys):
    first, again = tmp_path / "first", tmp_path / "again"
    argv = [*tiny_args(2048, num_seeds=2), "--learning-rate", "2e-3", "--seed", "7"]
    assert main([*argv, "--sweep", "ent_coef=0,0.01", "--out", str(first)]) == 0
    assert main(["--config", str(first / "config.json"), "--out", str(again), "--quiet"]) == 0
    saved = [json.loads((d / "config.json").read_text()) for d in (first, again)]
    for key in ("preset", "num_seeds", "seed", "sweep", "wave_size", "eval_episodes", "config"):
        assert saved[0][key] == saved[1][key], key
    for combo in ("combo-000", "combo-001"):
        assert_same_run_dirs(first / combo, again / combo)
    # the run directory itself works too, and the command line still overrides
    opts = _options(["--config", str(first), "--num-seeds", "1"])
    assert opts.num_seeds == 1 and opts.seed == 7
    assert _config(["--config", str(first), "--learning-rate", "1e-3"]).learning_rate == 1e-3
    with pytest.raises(cli.UsageError, match="--ent-coef and --sweep ent_coef both given"):
        _config(["--config", str(first), "--ent-coef", "0.1"])

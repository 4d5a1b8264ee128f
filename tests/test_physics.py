"""CartPole's physics as the researcher's: set on the command line, recorded, evaluated in
Gymnasium's own env with the same physics, swept in one program and randomised per seed."""

from __future__ import annotations

import json
import math

import gymnasium as gym
import numpy as np
import pytest
from helpers import TINY, assert_same_run_dirs, stopped_run, tiny_args

import jaxcart
from jaxcart import configfile, evaluate, train
from jaxcart.core import physics
from jaxcart.core.cartpole import EnvParams
from jaxcart.core.config import ConfigError, PPOConfig
from jaxcart.core.solved import EVAL_SEED
from jaxcart.engine.loop import train as train_runs
from jaxcart.gym.stock import make_cartpole
from jaxcart.run import lifecycle
from jaxcart.run.spec import RunSpec, parse_randomize
from jaxcart.rundir import layout, reader


def plain_gymnasium_returns(policy, length: float, episodes: int) -> list[float]:
    """Greedy returns in a hand-built Gymnasium CartPole-v1 with another pole: Gymnasium's
    constructor derives polemass_length and total_mass, so they are set again here."""
    env = gym.make("CartPole-v1")
    env.unwrapped.length = length
    env.unwrapped.polemass_length = env.unwrapped.masspole * length
    env.unwrapped.total_mass = env.unwrapped.masspole + env.unwrapped.masscart
    returns = []
    for e in range(episodes):
        obs, _ = env.reset(seed=EVAL_SEED + e)
        total, done = 0.0, False
        while not done:
            obs, reward, terminated, truncated, _ = env.step(policy(obs))
            total += reward
            done = terminated or truncated
        returns.append(total)
    return returns


@pytest.mark.slow
def test_env_param_trains_records_and_evaluates_on_its_own_physics(tmp_path, capsys):
    out = tmp_path / "long-pole"
    args = [*tiny_args(2048, num_seeds=2, eval_episodes=3), "--env-param", "length=1.0"]
    assert train.main([*args, "--out", str(out), "--no-compile-cache"]) == 0
    info = json.loads((out / layout.CONFIG_FILE).read_text())
    assert info["env_params"] == {"length": 1.0}
    evaluation = reader.read_evaluation(out, 2)
    for s in range(2):
        policy = jaxcart.load_policy(out, s)
        assert policy.env_params.length == 1.0
        ours = plain_gymnasium_returns(policy, 1.0, 3)
        assert evaluation["seeds"][s]["gymnasium_returns"] == ours
    # evaluate reads the run's physics; --env-param evaluates on other physics
    capsys.readouterr()
    assert evaluate.main([str(out), "--episodes", "3"]) == 0
    text = capsys.readouterr().out
    assert "length=1" in text
    mean = float(text.split("\n")[3].split()[1])
    assert mean == pytest.approx(np.mean(evaluation["seeds"][0]["gymnasium_returns"]), abs=0.05)
    assert evaluate.main([str(out), "--episodes", "3", "--env-param", "length=0.25"]) == 0
    short = capsys.readouterr().out
    policy = jaxcart.load_policy(out, 0)
    expected = np.mean(plain_gymnasium_returns(policy, 0.25, 3))
    assert "length=0.25" in short
    assert float(short.split("\n")[3].split()[1]) == pytest.approx(expected, abs=0.05)


def test_default_physics_is_recorded_as_nothing():
    plain = RunSpec().record()
    assert "env_params" not in plain and "randomize" not in plain
    assert physics.overrides(EnvParams()) == {}
    spec = RunSpec(env_params=physics.make_env_params({"length": 1.0}))
    assert spec.record() == {**plain, "env_params": {"length": 1.0}}


def test_gymnasium_env_gets_the_physics_and_its_derived_masses():
    env = make_cartpole(EnvParams(masspole=0.2, length=1.0, masscart=2.0))
    cartpole = env.unwrapped
    assert cartpole.polemass_length == 0.2 * 1.0
    assert cartpole.total_mass == 0.2 + 2.0
    default = make_cartpole().unwrapped
    assert (default.length, default.polemass_length) == (0.5, 0.05)


@pytest.mark.slow
def test_a_physics_sweep_is_one_compiled_program():
    config = TINY.__class__(**{**TINY.__dict__, "total_timesteps": 256})
    first = train_runs(config, 3, env_params=EnvParams(length=np.array([0.5, 1.0, 2.0])))
    again = train_runs(config, 3, env_params=EnvParams(length=np.array([0.3, 0.7, 3.0])))
    assert first.compiled and not again.compiled  # other lengths, the same executable
    lengths = first.metrics["rollout/ep_len_mean"][-1]
    assert len(set(lengths.tolist())) == 3  # each run stepped its own pole


@pytest.mark.slow
def test_swept_physics_values_reach_each_run():
    """Run 0 of a length sweep trains as a run given that length as a constant would (the
    same seed index): the array is the per-run value, not a default."""
    config = TINY.__class__(**{**TINY.__dict__, "total_timesteps": 256})
    swept = train_runs(config, 2, env_params=EnvParams(length=np.array([1.0, 2.0])))
    alone = train_runs(config, 2, env_params=EnvParams(length=1.0))
    np.testing.assert_allclose(
        swept.metrics["rollout/ep_len_mean"][:, 0], alone.metrics["rollout/ep_len_mean"][:, 0]
    )


def test_randomised_values_are_drawn_from_the_seed_and_replay():
    r = parse_randomize(["env.length=0.5:1.5"])
    every = physics.randomized_values(r, 7, np.arange(5))["length"]
    assert np.all((every >= 0.5) & (every <= 1.5)) and len(set(every.tolist())) == 5
    # seed index 3 draws its own value whatever runs beside it
    one = physics.randomized_values(r, 7, np.array([3]))["length"]
    assert one[0] == every[3]
    assert physics.randomized_values(r, 8, np.array([3]))["length"][0] != every[3]


@pytest.mark.slow
def test_randomised_run_records_each_seed_and_replays_exactly(tmp_path):
    spec = RunSpec(
        config=TINY.__class__(**{**TINY.__dict__, "total_timesteps": 512}),
        num_seeds=2,
        randomize=parse_randomize(["env.length=0.5:1.5"]),
    )
    outcome = lifecycle.run_new(spec, tmp_path / "rand", lifecycle.RunOptions(eval_episodes=2))
    info = json.loads((tmp_path / "rand" / layout.CONFIG_FILE).read_text())
    assert info["randomize"] == {"length": {"low": 0.5, "high": 1.5, "per": "run"}}
    drawn = physics.randomized_values(spec.randomize, 0, np.arange(2))["length"]
    assert info["env_per_seed"]["length"] == drawn.tolist()
    replay = lifecycle.replay_seed(tmp_path / "rand", 1)
    recorded = reader.read_metrics_csv(tmp_path / "rand" / layout.METRICS_FILE)
    np.testing.assert_array_equal(
        replay.metrics["rollout/ep_len_mean"][:, 0], recorded["rollout/ep_len_mean"][:, 1]
    )
    assert outcome.evaluation is not None
    # evaluated on the nominal physics: the policy's env is CartPole-v1's
    assert jaxcart.load_policy(tmp_path / "rand", 0).env_params == EnvParams()


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--env-param", "lenght=1.0"], "CartPole has no env param 'lenght'"),
        (["--env-param", "masspole=-0.1"], "env param masspole must be > 0"),
        (["--env-param", "tau=0"], "env param tau must be > 0"),
        (["--env-param", "gravity=nan"], "env param gravity must be a finite number"),
        (["--env-param", "length"], "malformed --env-param"),
        (["--env-param", "kinematics_integrator=rk4"], "kinematics_integrator must be"),
        (["--randomize", "env.length=1.5:0.5"], "low 1.5 is above high 0.5"),
        (["--randomize", "env.mass=0.5:1.5"], "CartPole has no env param 'mass'"),
        (["--randomize", "env.length=0:1"], "env param length must be > 0"),
        (["--randomize", "env.length=0.5:1:often"], "must be run or episode"),
        (["--sweep", "env.length=0.5,-1"], "env param length must be > 0"),
        (["--sweep", "env.max_episode_steps=100,200"], "only continuous physics fields"),
        (["--env-param", "length=1", "--sweep", "env.length=0.5,2"], "both given"),
    ],
)
def test_bad_physics_is_one_line(argv, message, capsys, tmp_path):
    code = train.main([*tiny_args(256), *argv, "--out", str(tmp_path / "r"), "--dry-run"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert message in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "r").exists()


def test_physics_from_a_config_file(tmp_path, capsys):
    path = tmp_path / "physics.toml"
    path.write_text('env_param = {length = 1.0}\nrandomize = {"env.masspole" = "0.05:0.2"}\n')
    args = configfile.parse_with_config(train.build_parser(), ["--config", str(path)])
    opts = train.TrainOptions.from_args(args)
    spec = opts.run_spec()
    assert spec.env_params.length == 1.0
    assert spec.randomize == (physics.Randomization("masspole", 0.05, 0.2, "run"),)


def test_corrupted_physics_in_config_json_is_refused():
    info = {"env_params": {"masspole": -1.0}}
    with pytest.raises(ConfigError, match="masspole must be > 0"):
        reader._check_physics_fields(info)
    assert math.isclose(reader.run_env_params({"env_params": {"length": 2.0}}).length, 2.0)


def test_runs_are_labelled_by_their_physics(tmp_path):
    from jaxcart.rundir.reader import default_label

    info = {
        "env_params": {"length": 0.25, "kinematics_integrator": "semi-implicit"},
        "randomize": {"masspole": {"low": 0.05, "high": 0.2, "per": "run"}},
    }
    label = default_label(tmp_path / "short", info)
    assert label == "short (length=0.25,kinematics_integrator=semi-implicit,masspole~U[0.05,0.2])"
    assert default_label(tmp_path / "plain", {}) == "plain"


SMALL = PPOConfig(**{**TINY.to_dict(), "total_timesteps": 1024})  # 8 iterations
OPTIONS = lifecycle.RunOptions(eval_episodes=2, compile_cache=False, chunk_size=2)


@pytest.mark.slow
def test_a_stopped_run_resumes_on_its_physics(tmp_path):
    spec = RunSpec(SMALL, num_seeds=2, env_params=physics.make_env_params({"length": 1.0}))
    lifecycle.run_new(spec, tmp_path / "whole", OPTIONS)
    run, result = stopped_run(spec, tmp_path / "part", OPTIONS, chunks=2)
    run.close()
    lifecycle.resume_run(tmp_path / "part", OPTIONS)
    assert_same_run_dirs(tmp_path / "whole", tmp_path / "part")
    # and the physics mattered: the default pole trains other numbers
    lifecycle.run_new(RunSpec(SMALL, num_seeds=2), tmp_path / "default", OPTIONS)
    with pytest.raises(AssertionError):
        assert_same_run_dirs(tmp_path / "whole", tmp_path / "default")


@pytest.mark.slow
def test_physics_sweep_evaluates_each_combination_on_its_own_physics(tmp_path):
    spec = RunSpec(SMALL, num_seeds=2, sweep={"env.length": [0.25, 1.0]})
    outcome = lifecycle.run_new(spec, tmp_path / "sweep", OPTIONS)
    assert outcome.run.grid.num_runs == 4 and len(outcome.ranking) == 2
    for c, length in enumerate([0.25, 1.0]):
        combo = layout.combo_dir(tmp_path / "sweep", c)
        info = json.loads((combo / layout.CONFIG_FILE).read_text())
        assert info["combination"] == {"env.length": length}
        policy = jaxcart.load_policy(combo, 0)
        assert policy.env_params.length == length
        recorded = reader.read_evaluation(combo, 2)["seeds"][0]["gymnasium_returns"]
        assert recorded == plain_gymnasium_returns(policy, length, 2)
        assert recorded == outcome.evaluation.gym_returns[2 * c].tolist()


@pytest.mark.slow
def test_per_episode_randomisation_trains_resumes_and_replays(tmp_path):
    randomize = parse_randomize(["env.length=0.25:1.0:episode"])
    spec = RunSpec(SMALL, num_seeds=2, randomize=randomize)
    lifecycle.run_new(spec, tmp_path / "whole", OPTIONS)
    info = json.loads((tmp_path / "whole" / layout.CONFIG_FILE).read_text())
    assert info["randomize"] == {"length": {"low": 0.25, "high": 1.0, "per": "episode"}}
    assert "env_per_seed" not in info  # drawn per episode, from the run's keys
    # the env state (each env's current pole) is checkpointed: a resume ends bit-identical
    run, _ = stopped_run(spec, tmp_path / "part", OPTIONS, chunks=2)
    run.close()
    lifecycle.resume_run(tmp_path / "part", OPTIONS)
    assert_same_run_dirs(tmp_path / "whole", tmp_path / "part")
    replay = lifecycle.replay_seed(tmp_path / "whole", 1)
    recorded = reader.read_metrics_csv(tmp_path / "whole" / layout.METRICS_FILE)
    np.testing.assert_array_equal(
        replay.metrics["rollout/ep_len_mean"][:, 0], recorded["rollout/ep_len_mean"][:, 1]
    )
    poles = np.asarray(replay.state.runners.env_state.values["length"])
    assert np.all((poles >= 0.25) & (poles <= 1.0)) and len(np.unique(poles)) == poles.size


def test_per_episode_draws_happen_at_resets_only():
    """Envs whose episode goes on keep their pole; an env that resets draws a new one."""
    import jax.numpy as jnp

    from jaxcart.core.cartpole import state_from_obs
    from jaxcart.core.physics import episode_state, step_batch

    env = state_from_obs(np.array([[0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.5, 0.0]], np.float32))
    lengths = {"length": np.array([0.3, 0.4], np.float32)}
    state = episode_state(env, lengths, {"length": (0.25, 1.0)}, np.float32)
    key = jnp.array([1, 2], jnp.uint32)
    _, new, _, terminated, _, _ = step_batch(key, state, jnp.array([1, 1]), EnvParams())
    assert terminated.tolist() == [False, True]  # the second pole is past 12 degrees
    poles = np.asarray(new.values["length"])
    assert poles[0] == np.float32(0.3) and poles[1] != np.float32(0.4)
    assert 0.25 <= poles[1] <= 1.0


def test_a_runs_config_json_trains_again_with_its_physics(tmp_path):
    randomize = parse_randomize(["env.masspole=0.05:0.2", "env.length=0.3:0.9:episode"])
    gravity = physics.make_env_params({"gravity": 3.7})
    spec = RunSpec(SMALL, preset="sb3", env_params=gravity, randomize=randomize)
    run = lifecycle.create_run(spec, tmp_path / "mars")
    run.close()
    argv = ["--config", str(tmp_path / "mars")]
    again = train.TrainOptions.from_args(configfile.parse_with_config(train.build_parser(), argv))
    rebuilt = again.run_spec()
    assert rebuilt.env_params == spec.env_params and rebuilt.randomize == spec.randomize


def test_the_gif_runs_on_the_policys_physics():
    from jaxcart.results.gif import episode_frames

    def push_left(obs):
        return 0

    (default, _, _), *_ = episode_frames(push_left, max_steps=1, backend="pillow")
    (longer, _, _), *_ = episode_frames(
        push_left, max_steps=1, backend="pillow", env_params=EnvParams(length=1.0)
    )
    assert not np.array_equal(default, longer)  # a pole twice as long is drawn

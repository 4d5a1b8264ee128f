"""Other envs on the same trainer: gymnax's Acrobot-v1 and MountainCar-v0 behind jaxcart's env
protocol (:mod:`jaxcart.core.envs`), their parity with Gymnasium's own ``classic_control``
envs on injected states, their truncation, and the one-line refusals.

Parity: Gymnasium's float64 state is injected into both implementations, both are stepped with
the same action and compared. Under x64 the next states agree to 1e-9 and every flag and
reward exactly; in float32 the observations agree to 1e-4 and the flags wherever the state is
not within float32 rounding of the goal.
"""

from __future__ import annotations

import dataclasses
import json
import sys

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxcart.core import envs
from jaxcart.core.config import ConfigError, PPOConfig
from jaxcart.core.solved import EPISODE_LIMITS, is_solved

gymnax = pytest.importorskip("gymnax")

NUM_STATES = 2_000


def acrobot_states(rng: np.random.Generator, n: int) -> np.ndarray:
    """Angles anywhere, velocities up to their bounds (some beyond, to exercise the clip),
    and half of the states with the tip near the goal height. ``[n, 4]`` float64."""
    states = rng.uniform(-1, 1, (n, 4)) * [np.pi, np.pi, 4 * np.pi * 1.1, 9 * np.pi * 1.1]
    near = n // 2
    # -cos(a1) - cos(a1 + a2) > 1: with a2 = 0 the tip is at height 1 when cos(a1) = -1/2
    a1 = rng.choice([-1, 1], near) * (2 * np.pi / 3 + rng.uniform(-0.3, 0.3, near))
    states[:near, 0], states[:near, 1] = a1, rng.uniform(-0.3, 0.3, near)
    states[:near, 2:] *= 0.05
    return states


def mountain_car_states(rng: np.random.Generator, n: int) -> np.ndarray:
    """Positions over the whole track (a quarter at its left wall, a quarter near the goal)
    and velocities within the speed limit. ``[n, 2]`` float64."""
    states = np.stack([rng.uniform(-1.2, 0.6, n), rng.uniform(-0.07, 0.07, n)], axis=1)
    q = n // 4
    states[:q, 0], states[:q, 1] = -1.2 + rng.uniform(0, 0.01, q), -np.abs(states[:q, 1])
    states[q : 2 * q, 0] = 0.5 + rng.uniform(-0.05, 0.05, q)
    return states


CASES = {
    "Acrobot-v1": (acrobot_states, 4),
    "MountainCar-v0": (mountain_car_states, 2),
}


def gymnasium_steps(env_id: str, states: np.ndarray, actions: np.ndarray):
    """Gymnasium's unwrapped env stepped once from each injected state."""
    env = gym.make(env_id).unwrapped
    env.reset(seed=0)
    obs, next_states, rewards, terminated = [], [], [], []
    for s, a in zip(states, actions):
        env.state = s.copy()
        o, r, term, trunc, _ = env.step(int(a))
        assert not trunc  # the unwrapped env never truncates: TimeLimit does
        obs.append(o)
        next_states.append(np.array(env.state, np.float64))
        rewards.append(r)
        terminated.append(term)
    return np.array(obs), np.array(next_states), np.array(rewards), np.array(terminated)


def gymnax_state(env_id: str, states: np.ndarray, time: int = 0):
    """gymnax's state pytree (fields ``[N]``) holding Gymnasium's states."""
    module = sys.modules[type(gymnax.make(env_id)[0]).__module__]
    time = jnp.full((len(states),), time, jnp.int32)
    names = [f.name for f in dataclasses.fields(module.EnvState) if f.name != "time"]
    return module.EnvState(**dict(zip(names, map(jnp.asarray, states.T))), time=time)


def jaxcart_steps(env_id: str, states: np.ndarray, actions: np.ndarray, time: int = 0):
    env = envs.make(env_id)
    step = jax.jit(env.step_batch)
    out = step(
        jax.random.PRNGKey(0), gymnax_state(env_id, states, time), actions, env.default_params()
    )
    obs, state, reward, terminated, truncated, info = out
    return jax.tree.map(np.asarray, (info["final_obs"], reward, terminated, truncated))


@pytest.fixture(scope="module", params=sorted(CASES))
def reference(request):
    env_id = request.param
    sample, _ = CASES[env_id]
    rng = np.random.default_rng(28)
    states = sample(rng, NUM_STATES)
    actions = rng.integers(0, 3, NUM_STATES)
    return env_id, states, actions, gymnasium_steps(env_id, states, actions)


@pytest.mark.parametrize("x64", [False, True], ids=["float32", "x64"])
def test_step_matches_gymnasium(reference, x64):
    env_id, states, actions, (g_obs, g_state, g_reward, g_terminated) = reference
    # the sample must exercise both outcomes
    assert 0.05 < g_terminated.mean() < 0.95
    with jax.enable_x64(x64):
        obs, reward, terminated, truncated = jaxcart_steps(
            env_id, states.astype(np.float64 if x64 else np.float32), jnp.asarray(actions)
        )
    assert obs.dtype == (np.float64 if x64 else np.float32)
    assert not truncated.any()
    if x64:
        # Gymnasium's observation is its float64 state made float32; compare the state itself
        expected = g_obs.astype(np.float64) if env_id == "MountainCar-v0" else None
        if expected is None:
            a1, a2, v1, v2 = g_state.T
            expected = np.stack([np.cos(a1), np.sin(a1), np.cos(a2), np.sin(a2), v1, v2], 1)
        else:
            expected = g_state
        np.testing.assert_allclose(obs, expected, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(terminated, g_terminated)
        np.testing.assert_array_equal(reward, g_reward)
        return
    # Acrobot's float32 RK4 step over dt=0.2 amplifies rounding: fast velocities differ by up
    # to about 1e-3 relative (in x64 they agree to 1e-9)
    rtol = 2e-3 if env_id == "Acrobot-v1" else 0
    np.testing.assert_allclose(obs, g_obs, rtol=rtol, atol=1e-4 if rtol else 1e-6)
    differ = terminated != g_terminated
    # float32 rounding moves only states within a hair of the goal to the other side
    assert differ.mean() < 0.01
    np.testing.assert_array_equal(reward[~differ], g_reward[~differ])


@pytest.mark.parametrize("env_id", sorted(CASES))
def test_truncates_at_gymnasiums_time_limit(env_id):
    """A step from the state with ``limit - 1`` steps taken truncates (the episode's reward
    counted, its last observation kept) and resets, as Gymnasium's TimeLimit ends it; one
    step earlier it does not."""
    limit = EPISODE_LIMITS[env_id]
    assert gym.spec(env_id).max_episode_steps == limit
    sample, _ = CASES[env_id]
    states = sample(np.random.default_rng(1), 64)
    g_obs, _, g_reward, g_terminated = gymnasium_steps(env_id, states, np.ones(64, int))
    running = ~g_terminated
    for taken, expect in ((limit - 1, True), (limit - 2, False)):
        final_obs, reward, terminated, truncated = jaxcart_steps(
            env_id, states.astype(np.float32), jnp.ones(64, jnp.int32), time=taken
        )
        assert (truncated == expect).all()
        np.testing.assert_array_equal(terminated[running], False)
        np.testing.assert_array_equal(reward[running], g_reward[running])
        np.testing.assert_allclose(final_obs, g_obs, atol=1e-4)


@pytest.mark.parametrize("env_id", sorted(CASES))
def test_sizes_and_thresholds_are_gymnasiums(env_id):
    env, spec = envs.make(env_id), gym.spec(env_id)
    made = gym.make(env_id)
    assert env.obs_dim == made.observation_space.shape[0]
    assert env.num_actions == made.action_space.n == envs.ACTION_COUNTS[env_id]
    assert env.reward_threshold == spec.reward_threshold
    threshold = spec.reward_threshold
    assert is_solved(np.full(20, threshold), env_id)
    assert not is_solved(np.full(20, threshold - 1), env_id)


def test_reset_draws_the_envs_own_start_states():
    env = envs.make("MountainCar-v0")
    obs, state = jax.vmap(env.reset, in_axes=(0, None))(
        jax.random.split(jax.random.PRNGKey(0), 256), env.default_params()
    )
    assert obs.shape == (256, 2)
    assert ((obs[:, 0] >= -0.6) & (obs[:, 0] < -0.4)).all() and (obs[:, 1] == 0).all()
    assert (state.time == 0).all()


@pytest.mark.parametrize(
    "env_id, message",
    [
        ("Pong-v5", "unknown env 'Pong-v5'; choose one of: CartPole-v1, Acrobot-v1"),
        ("Pendulum-v1", "env Pendulum-v1 has continuous actions"),
        ("MountainCarContinuous-v0", "has continuous actions"),
        ("Catch-bsuite", "which Gymnasium lacks for it"),
    ],
)
def test_refused_in_one_line(env_id, message):
    with pytest.raises(ConfigError, match=message) as caught:
        PPOConfig(env=env_id)
    assert "\n" not in str(caught.value) and caught.value.option == "env"


def test_without_gymnax_says_the_pip_command(monkeypatch):
    monkeypatch.setitem(sys.modules, "gymnax", None)  # import gymnax raises ImportError
    envs.make.cache_clear()
    try:
        with pytest.raises(envs.EnvError, match=r"pip install -e '\.\[gymnax\]'"):
            envs.make("Acrobot-v1")
        assert envs.make("CartPole-v1") is envs.CARTPOLE  # the default needs no gymnax
    finally:
        envs.make.cache_clear()


def test_cli_refuses_with_one_line_and_exit_2(capsys):
    from jaxcart import train

    assert train.main(["--env", "Pendulum-v1", "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert (
        err.startswith("error: --env Pendulum-v1 has continuous actions") and err.count("\n") == 1
    )


def test_config_json_names_the_env_only_when_not_cartpole():
    assert "env" not in PPOConfig().to_dict()
    data = PPOConfig(env="Acrobot-v1").to_dict()
    assert data["env"] == "Acrobot-v1"
    assert PPOConfig.from_dict(data).env == "Acrobot-v1"
    assert PPOConfig.from_dict(PPOConfig().to_dict()).env == "CartPole-v1"


def test_network_and_runners_take_their_sizes_from_the_env():
    from jaxcart.core.ppo import make_network
    from jaxcart.engine.loop import init_runners

    config = PPOConfig(env="Acrobot-v1", num_envs=3, num_steps=8, minibatch_size=8)
    runners = init_runners(config, 0, np.arange(2))
    assert runners.obs.shape == (2, 3, 6)
    assert runners.env_state.time.shape == (2, 3) and runners.env_state.time.dtype == np.int32
    logits, value = make_network(config).apply(
        jax.tree.map(lambda x: x[0], runners.params), runners.obs[0]
    )
    assert logits.shape == (3, 3) and value.shape == (3,)


def test_gymnax_params_are_constants_of_the_program():
    """gymnax's params may hold arrays (Acrobot's ``available_torque [3]``): not a run axis,
    which training 2 seeds on 2 devices once took them for (a vmap size error)."""
    from jaxcart.engine.chunk import env_axes

    for env_id in ("Acrobot-v1", "MountainCar-v0"):
        assert env_axes(envs.make(env_id).default_params()) is None


@pytest.mark.slow
def test_acrobot_run_stops_resumes_and_reads_back(tmp_path, capsys):
    """An Acrobot run stopped after two chunks resumes bit-identical to an uninterrupted one;
    its config.json names the env and evaluate, load_policy and the reader use it."""
    from helpers import TINY, assert_same_run_dirs, stopped_run

    import jaxcart
    from jaxcart.run import lifecycle
    from jaxcart.run.greedy import evaluate_params
    from jaxcart.run.spec import RunOptions, RunSpec
    from jaxcart.rundir.policy import run_params

    config = PPOConfig(**{**TINY.to_dict(), "total_timesteps": 1024, "env": "Acrobot-v1"})
    options = RunOptions(eval_episodes=2, compile_cache=False, chunk_size=2)
    spec = RunSpec(config, num_seeds=2, seed=3)
    whole = lifecycle.run_new(spec, tmp_path / "whole", options)
    run, _ = stopped_run(spec, tmp_path / "part", options, chunks=2)
    run.close()
    lifecycle.resume_run(tmp_path / "part", options)
    assert_same_run_dirs(tmp_path / "whole", tmp_path / "part")

    info = json.loads((tmp_path / "whole" / "config.json").read_text())
    assert info["config"]["env"] == "Acrobot-v1"
    trained = run_params(tmp_path / "whole")
    returns = evaluate_params(trained, 2)
    np.testing.assert_array_equal(returns, whole.evaluation.gym_returns)
    assert trained.config.env == "Acrobot-v1" and (returns <= 0).all()
    from jaxcart.rundir import reader

    evaluation = reader.read_evaluation(tmp_path / "whole", 2)  # negative returns accepted
    assert "reward_threshold, -100" in evaluation["solved_definition"]
    policy = jaxcart.load_policy(tmp_path / "whole")
    assert policy.env_id == "Acrobot-v1" and policy(np.zeros(6, np.float32)) in (0, 1, 2)

    from jaxcart import evaluate, export

    out = str(tmp_path / "p.onnx")
    assert export.main([str(tmp_path / "whole"), "--to", "onnx", "--out", out]) == 2
    gif = str(tmp_path / "a.gif")
    err = capsys.readouterr().err.splitlines()
    assert err[-1] == (
        f"error: --to onnx exports CartPole-v1 policies only; {tmp_path / 'whole'} trained Acrobot-v1"
    )
    # Gymnasium's renderer (pygame, a test dependency) draws Acrobot's own episode
    assert evaluate.main([str(tmp_path / "whole"), "--episodes", "1", "--gif", gif]) == 0
    assert "wrote" in capsys.readouterr().out and (tmp_path / "a.gif").stat().st_size > 0


def test_metric_bounds_follow_the_env(tmp_path):
    """Acrobot's returns are negative: a reader refuses them for CartPole, takes them for
    Acrobot, and refuses a positive one there."""
    from jaxcart.rundir.files import RunDirError
    from jaxcart.rundir.reader import check_metrics

    negative = {"rollout/ep_rew_mean": np.array([[-480.0]])}
    check_metrics(negative, tmp_path, "Acrobot-v1")
    with pytest.raises(RunDirError, match=r"outside \[0, 500\]"):
        check_metrics(negative, tmp_path)
    with pytest.raises(RunDirError, match=r"outside \[-500, 0\]"):
        check_metrics({"rollout/ep_rew_mean": np.array([[10.0]])}, tmp_path, "Acrobot-v1")


def test_compare_states_each_envs_notion_of_solved():
    from types import SimpleNamespace

    from jaxcart.compare import solved_text

    def comparison(*env_ids):
        return SimpleNamespace(env_ids=list(env_ids))

    assert solved_text(comparison("CartPole-v1")).startswith(
        "solved: every greedy episode scored 500"
    )
    mixed = solved_text(comparison("CartPole-v1", "MountainCar-v0", "Acrobot-v1"))
    assert "Acrobot-v1 >= -100, MountainCar-v0 >= -110" in mixed

"""The Gymnasium adapters against Gymnasium's own CartPole-v1 and its checkers.

``gymnasium.make("CartPole-v1")`` is the reference: the same start state (from the seed or
injected), the same actions, then observations within 1e-5 and rewards and flags identical on
every step. The vector env is checked step by step against one Gymnasium CartPole per
sub-environment, re-injected at each same-step autoreset.
"""

from __future__ import annotations

import os
import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from gymnasium.utils.env_match import check_environments_match
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from jaxcart.gym_adapter import ENV_ID, JaxCartPoleEnv, JaxCartPoleVectorEnv

try:
    import pygame  # noqa: F401  (rendering draws with Gymnasium's pygame renderer)

    HAVE_PYGAME = True
except ImportError:
    HAVE_PYGAME = False

OBS_TOL = 1e-5


def balancing_action(obs: np.ndarray) -> int:
    """A controller that keeps the pole up for all 500 steps."""
    return int(obs[2] + 0.5 * obs[3] > 0)


def gym_messages(caught: list[warnings.WarningMessage]) -> list[str]:
    """The messages of warnings raised through Gymnasium's logger (its checkers' findings)."""
    return [str(w.message) for w in caught if "WARN" in str(w.message)]


def check_env_warnings(env: gym.Env) -> list[str]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        # The render check builds the env with each declared render mode and draws a frame.
        check_env(env, skip_render_check=not HAVE_PYGAME)
    return gym_messages(caught)


def test_passes_gymnasium_check_env_with_no_more_warnings_than_gymnasiums_cartpole():
    env = gym.make(ENV_ID).unwrapped
    assert isinstance(env, JaxCartPoleEnv)
    found = check_env_warnings(env)
    # The unbounded velocities of CartPole's observation Box draw the same two warnings for
    # Gymnasium's own CartPole; nothing else may appear.
    assert found == check_env_warnings(gym.make("CartPole-v1").unwrapped)
    assert len(found) == 2 and all("infinity" in m for m in found)


def test_make_and_make_vec():
    env = gym.make(ENV_ID)
    reference = gym.make("CartPole-v1")
    assert isinstance(env, gym.wrappers.TimeLimit)
    assert env.spec.max_episode_steps == 500
    assert env.spec.reward_threshold == reference.spec.reward_threshold
    assert env.observation_space == reference.observation_space
    assert env.action_space == reference.action_space

    envs = gym.make_vec(ENV_ID, num_envs=8, vectorization_mode="vector_entry_point")
    assert isinstance(envs, JaxCartPoleVectorEnv)
    assert envs.num_envs == 8
    assert envs.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP
    assert envs.params.max_episode_steps == 500
    assert envs.single_observation_space == reference.observation_space
    assert envs.observation_space == batch_space(reference.observation_space, 8)
    assert envs.action_space == batch_space(reference.action_space, 8)
    obs, info = envs.reset(seed=0)
    assert obs.shape == (8, 4) and obs.dtype == np.float32 and info == {}
    assert obs in envs.observation_space

    # The default vectorisation of an env with a vector entry point is that entry point, and
    # Gymnasium's own SyncVectorEnv over the single env works too.
    assert isinstance(gym.make_vec(ENV_ID, num_envs=2), JaxCartPoleVectorEnv)
    sync = gym.make_vec(ENV_ID, num_envs=2, vectorization_mode="sync")
    sync.reset(seed=0)
    assert sync.step(np.array([0, 1]))[0].shape == (2, 4)


def test_make_by_module_id_in_a_fresh_interpreter():
    """``gym.make("jaxcart.gym_adapter:jaxcart/CartPole-v1")`` imports and registers the env
    itself; importing the adapter does not import JAX (it loads when an env is built)."""
    code = (
        "import sys, gymnasium as gym\n"
        "import jaxcart.gym_adapter\n"
        "assert 'jax' not in sys.modules, 'the adapter imported JAX'\n"
        "env = gym.make('jaxcart.gym_adapter:jaxcart/CartPole-v1')\n"
        "obs, _ = env.reset(seed=0)\n"
        "assert obs.tolist() == gym.make('CartPole-v1').reset(seed=0)[0].tolist()\n"
        "print(type(env.unwrapped).__name__)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "JAX_PLATFORMS": "cpu"},
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "JaxCartPoleEnv"


@pytest.mark.parametrize("options", [None, {"low": -0.2, "high": 0.3}])
def test_seeded_resets_equal_gymnasiums(options):
    env, reference = gym.make(ENV_ID), gym.make("CartPole-v1")
    for seed in (0, 1, 12345):
        obs, info = env.reset(seed=seed, options=options)
        ref_obs, ref_info = reference.reset(seed=seed, options=options)
        np.testing.assert_array_equal(obs, ref_obs)
        assert obs.dtype == np.float32 and info == ref_info == {}
        np.testing.assert_array_equal(env.unwrapped.state, reference.unwrapped.state)
        # Unseeded resets continue the seeded generator, as in Gymnasium.
        np.testing.assert_array_equal(env.reset()[0], reference.reset()[0])


@pytest.mark.parametrize("float64", [True, False])
@pytest.mark.parametrize("sutton_barto", [False, True])
def test_episodes_from_injected_states_match_gymnasium(float64, sutton_barto):
    rng = np.random.default_rng(0)
    env = gym.make(ENV_ID, float64=float64, sutton_barto_reward=sutton_barto)
    reference = gym.make("CartPole-v1", sutton_barto_reward=sutton_barto)
    env.reset(seed=0)
    reference.reset(seed=0)
    lengths = []
    for _ in range(12):
        start = rng.uniform(-1, 1, 4) * [1.0, 0.5, 0.1, 0.5]
        env.unwrapped.state = start.copy()
        reference.unwrapped.state = start.copy()
        for t in range(1, 501):
            action = int(rng.integers(0, 2))
            obs, reward, terminated, truncated, info = env.step(action)
            ref_obs, ref_reward, ref_terminated, ref_truncated, ref_info = reference.step(action)
            np.testing.assert_allclose(obs, ref_obs, rtol=0, atol=OBS_TOL)
            assert obs.dtype == ref_obs.dtype == np.float32
            assert (reward, terminated, truncated, info) == (
                ref_reward,
                ref_terminated,
                ref_truncated,
                ref_info,
            )
            assert type(reward) is type(ref_reward) and type(terminated) is type(ref_terminated)
            if terminated or truncated:
                break
        assert terminated
        lengths.append(t)
        env.reset()
        reference.reset()
    assert min(lengths) < max(lengths)  # a mix of episodes, not one repeated


def test_balanced_episode_is_truncated_at_500_like_gymnasium():
    """Float64 physics tracks Gymnasium for hundreds of steps of a balanced episode (the
    unstable pendulum amplifies ~1e-16 differences from fused multiply-adds after that), and
    ``TimeLimit`` truncates both on step 500."""
    env, reference = gym.make(ENV_ID), gym.make("CartPole-v1")
    obs, _ = env.reset(seed=3)
    ref_obs, _ = reference.reset(seed=3)
    for t in range(1, 501):
        obs, reward, terminated, truncated, _ = env.step(balancing_action(obs))
        ref_obs, ref_reward, ref_terminated, ref_truncated, _ = reference.step(
            balancing_action(ref_obs)
        )
        if t <= 300:
            np.testing.assert_allclose(obs, ref_obs, rtol=0, atol=OBS_TOL)
        assert (reward, terminated, truncated) == (ref_reward, ref_terminated, ref_truncated)
        assert truncated == (t == 500) and not terminated


def test_gymnasium_check_environments_match():
    """Gymnasium's own env-matching check: seeded resets, 150 sampled actions over several
    episodes, observations, rewards, flags, infos and rendered frames compared."""
    render_mode = "rgb_array" if HAVE_PYGAME else None
    env = gym.make(ENV_ID, render_mode=render_mode)
    reference = gym.make("CartPole-v1", render_mode=render_mode)
    check_environments_match(env, reference, num_steps=150, seed=7)


@pytest.mark.parametrize("sutton_barto", [False, True])
def test_steps_past_termination_pay_and_warn_as_in_gymnasium(sutton_barto):
    envs = [
        gym.make(ENV_ID, sutton_barto_reward=sutton_barto).unwrapped,
        gym.make("CartPole-v1", sutton_barto_reward=sutton_barto).unwrapped,
    ]
    rewards, warned = [], []
    for env in envs:
        env.reset(seed=0)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            results = [env.step(1)[1:3] for _ in range(40)]
        rewards.append(results)
        warned.append([m for m in gym_messages(caught) if "already returned terminated" in m])
    assert rewards[0] == rewards[1]
    assert sum(terminated for _, terminated in rewards[0]) > 2  # stepped on past the end
    assert len(warned[0]) == len(warned[1]) == 1


INVALID_ACTIONS = [2, -1, 0.5, "a", None, 1.0, np.float32(0.0), np.array([1]), [0], (1,)]


@pytest.mark.parametrize("action", INVALID_ACTIONS, ids=repr)
def test_invalid_actions_raise_as_in_gymnasium(action):
    for wrapped in (False, True):
        envs = [gym.make(ENV_ID), gym.make("CartPole-v1")]
        if not wrapped:
            envs = [e.unwrapped for e in envs]
        messages = []
        for env in envs:
            env.reset(seed=0)
            with pytest.raises(AssertionError, match="invalid") as raised:
                env.step(action)
            messages.append(str(raised.value))
        assert messages[0] == messages[1]


def test_valid_action_types_are_accepted_as_in_gymnasium():
    env, reference = gym.make(ENV_ID), gym.make("CartPole-v1")
    env.reset(seed=0)
    reference.reset(seed=0)
    for action in (1, 0, np.int64(1), np.int32(0), np.array(1), True, False):
        obs, *_ = env.step(action)
        ref_obs, *_ = reference.step(action)
        np.testing.assert_allclose(obs, ref_obs, rtol=0, atol=OBS_TOL)


def test_step_before_reset_raises():
    with pytest.raises(AssertionError, match="Call reset before using step method"):
        JaxCartPoleEnv().step(0)


def test_vector_env_matches_gymnasium_with_same_step_autoreset():
    num_envs = 8
    envs = gym.make_vec(ENV_ID, num_envs=num_envs, vectorization_mode="vector_entry_point")
    envs = gym.wrappers.vector.RecordEpisodeStatistics(envs)
    obs, _ = envs.reset(seed=42)
    np.testing.assert_array_equal(obs, envs.reset(seed=42)[0])  # seeded resets repeat
    assert not np.array_equal(obs, envs.reset(seed=43)[0])
    obs, _ = envs.reset(seed=42)

    # One Gymnasium CartPole per sub-environment, started from the same state.
    references = [gym.make("CartPole-v1").unwrapped for _ in range(num_envs)]
    for ref, o in zip(references, obs):
        ref.reset(seed=0)
        ref.state = o.astype(np.float64)
    lengths = np.zeros(num_envs, dtype=int)
    rng = np.random.default_rng(1)
    episodes = 0
    for _ in range(120):
        actions = rng.integers(0, 2, num_envs)
        obs, rewards, terminated, truncated, info = envs.step(actions)
        assert obs.dtype == np.float32 and rewards.dtype == np.float32
        lengths += 1
        done = terminated | truncated
        assert not truncated.any()  # random actions drop the pole long before 500 steps
        if done.any():
            np.testing.assert_array_equal(info["_final_obs"], done)
            np.testing.assert_array_equal(info["_final_info"], done)
            np.testing.assert_array_equal(info["_episode"], done)
            np.testing.assert_array_equal(info["episode"]["l"][done], lengths[done])
            np.testing.assert_array_equal(info["episode"]["r"][done], lengths[done])
        else:
            assert "final_obs" not in info
        for i, ref in enumerate(references):
            ref_obs, ref_reward, ref_terminated, _, _ = ref.step(int(actions[i]))
            assert (rewards[i], terminated[i]) == (ref_reward, ref_terminated)
            if done[i]:
                episodes += 1
                np.testing.assert_allclose(info["final_obs"][i], ref_obs, rtol=0, atol=OBS_TOL)
                # Same-step autoreset: obs already starts the next episode.
                assert np.all(np.abs(obs[i]) <= 0.05)
                ref.reset()
                ref.state = obs[i].astype(np.float64)
                lengths[i] = 0
            else:
                if done.any():
                    assert info["final_obs"][i] is None
                np.testing.assert_allclose(obs[i], ref_obs, rtol=0, atol=OBS_TOL)
    assert episodes >= num_envs


def test_vector_env_truncates_and_reports_final_obs():
    envs = gym.make_vec(
        ENV_ID, num_envs=4, vectorization_mode="vector_entry_point", max_episode_steps=5
    )
    first, _ = envs.reset(seed=0)
    actions = np.array([0, 1, 0, 1])
    for t in range(1, 6):
        obs, rewards, terminated, truncated, info = envs.step(actions)
        actions = 1 - actions  # alternate pushes: the pole stays up
        assert not terminated.any()
        np.testing.assert_array_equal(rewards, np.ones(4, np.float32))
        assert truncated.all() == (t == 5)
    final = np.stack(info["final_obs"])
    assert final.shape == (4, 4) and not np.allclose(final, first)
    assert not np.allclose(obs, final) and np.all(np.abs(obs) <= 0.05)  # already reset
    # The step after a truncation counts from one again.
    assert not envs.step(actions)[3].any()


def test_vector_env_rejects_invalid_actions():
    envs = JaxCartPoleVectorEnv(num_envs=4)
    envs.reset(seed=0)
    for actions in ([0, 1, 2, 0], [0, -1, 1, 0], np.array([0, 1]), [0.5, 1, 0, 0], 1):
        with pytest.raises(AssertionError, match="invalid"):
            envs.step(actions)
    assert envs.step([0, 1, 1, 0])[0].shape == (4, 4)


@pytest.mark.skipif(not HAVE_PYGAME, reason="rendering needs pygame")
def test_render_matches_gymnasium_and_vector_render():
    env = gym.make(ENV_ID, render_mode="rgb_array")
    reference = gym.make("CartPole-v1", render_mode="rgb_array")
    env.reset(seed=5)
    reference.reset(seed=5)
    for action in (1, 1, 0):
        env.step(action)
        reference.step(action)
    frame = env.render()
    assert frame.shape == (400, 600, 3) and frame.dtype == np.uint8
    np.testing.assert_array_equal(frame, reference.render())

    envs = JaxCartPoleVectorEnv(num_envs=4, render_mode="rgb_array")
    envs.reset(seed=0)
    frames = envs.render()
    assert len(frames) == 4 and all(f.shape == (400, 600, 3) for f in frames)
    assert not np.array_equal(frames[0], frames[1])
    envs.close()
    env.close()


def test_sb3_check_env_and_short_ppo_run():
    pytest.importorskip("stable_baselines3")
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sb3_check_env(gym.make(ENV_ID).unwrapped)
    assert [str(w.message) for w in caught if "stable_baselines3" in w.filename] == []

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        # One epoch over the 2048-step rollout keeps this quick; the rest is SB3's defaults.
        model = PPO("MlpPolicy", gym.make(ENV_ID), n_epochs=1, seed=0, device="cpu", verbose=0)
        model.learn(2048)
    finally:
        torch.set_num_threads(threads)
    assert model.num_timesteps == 2048
    episodes = list(model.ep_info_buffer)  # SB3's Monitor: return and length per episode
    assert len(episodes) >= 20
    assert all(e["r"] == e["l"] for e in episodes)  # +1 per step, terminating step included
    assert all(8 <= e["l"] <= 500 for e in episodes)

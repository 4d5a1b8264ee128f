"""Parity of jaxcart's CartPole with Gymnasium's own ``classic_control`` CartPole.

Gymnasium's float64 state is injected into both implementations, both are stepped with the
same action and the results compared: flags and rewards exactly, observations to 1e-5
(float32) or 1e-12 (x64). Gymnasium's ``phys2d`` JAX CartPole is not a reference (its
``polemass_length`` differs).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from episode_parity import run_episodes

from jaxcart.core import cartpole

NUM_STATES = 10_000
X_LIM = 2.4
THETA_LIM = 12 * 2 * np.pi / 360


def sample_states(rng: np.random.Generator, n: int) -> np.ndarray:
    """A mixture of typical states, states whose next x or theta lands within 1e-2 of a
    threshold (either side), and states with large velocities. ``[n, 4]`` float64."""
    q = n // 4
    typical = rng.uniform(-1, 1, (q, 4)) * [X_LIM, 2.0, THETA_LIM, 2.0]
    near_x = rng.uniform(-1, 1, (q, 4)) * [X_LIM, 3.0, THETA_LIM, 3.0]
    target = rng.choice([-X_LIM, X_LIM], q) + rng.uniform(-1e-2, 1e-2, q)
    near_x[:, 0] = target - 0.02 * near_x[:, 1]  # x' = x + tau * x_dot lands near the edge
    near_theta = rng.uniform(-1, 1, (q, 4)) * [X_LIM, 3.0, THETA_LIM, 3.0]
    target = rng.choice([-THETA_LIM, THETA_LIM], q) + rng.uniform(-1e-2, 1e-2, q)
    near_theta[:, 2] = target - 0.02 * near_theta[:, 3]
    fast = rng.uniform(-1, 1, (n - 3 * q, 4)) * [X_LIM * 1.2, 50.0, THETA_LIM * 1.5, 50.0]
    return np.concatenate([typical, near_x, near_theta, fast])


def gymnasium_steps(states, actions, integrator, sutton_barto):
    env = gym.make("CartPole-v1", sutton_barto_reward=sutton_barto).unwrapped
    env.kinematics_integrator = integrator
    env.reset(seed=0)
    obs, next_states, rewards, terminated = [], [], [], []
    for s, a in zip(states, actions):
        env.state = s.copy()
        env.steps_beyond_terminated = None
        o, r, term, trunc, _ = env.step(int(a))
        assert not trunc  # the unwrapped env never truncates: TimeLimit does
        obs.append(o)
        next_states.append(env.state.copy())  # float64; the observation is rounded to float32
        rewards.append(r)
        terminated.append(term)
    return np.array(obs), np.array(next_states), np.array(rewards), np.array(terminated)


@pytest.fixture(scope="module")
def states_and_actions():
    rng = np.random.default_rng(2024)
    states = sample_states(rng, NUM_STATES)
    actions = rng.integers(0, 2, NUM_STATES)
    return states, actions


@pytest.fixture(scope="module")
def gym_reference(states_and_actions):
    states, actions = states_and_actions
    cache = {}

    def get(integrator, sutton_barto):
        if (integrator, sutton_barto) not in cache:
            cache[integrator, sutton_barto] = gymnasium_steps(
                states, actions, integrator, sutton_barto
            )
        return cache[integrator, sutton_barto]

    return get


@pytest.mark.parametrize("x64", [False, True], ids=["float32", "x64"])
@pytest.mark.parametrize("integrator", ["euler", "semi-implicit"])
@pytest.mark.parametrize("sutton_barto", [False, True], ids=["reward+1", "sutton-barto"])
def test_step_matches_gymnasium(states_and_actions, gym_reference, x64, integrator, sutton_barto):
    states, actions = states_and_actions
    g_obs, g_state, g_reward, g_terminated = gym_reference(integrator, sutton_barto)
    # the sample must actually exercise both outcomes near the thresholds
    assert 0.2 < g_terminated.mean() < 0.8
    params = cartpole.EnvParams(kinematics_integrator=integrator, sutton_barto_reward=sutton_barto)
    with jax.enable_x64(x64):
        step = jax.jit(jax.vmap(cartpole.step_env, in_axes=(0, 0, None)))
        obs, state, reward, terminated, truncated = step(
            cartpole.state_from_obs(states), jnp.asarray(actions), params
        )
        assert obs.dtype == (jnp.float64 if x64 else jnp.float32)
        obs, reward, terminated, truncated = map(np.asarray, (obs, reward, terminated, truncated))
    np.testing.assert_array_equal(terminated, g_terminated)
    np.testing.assert_array_equal(reward, g_reward)
    assert not truncated.any()
    atol = 1e-12 if x64 else 1e-5
    np.testing.assert_allclose(obs, g_state if x64 else g_obs, rtol=0, atol=atol)


def _time_limited(seed=0):
    env = gym.make("CartPole-v1")
    env.reset(seed=seed)
    return env


def _set_gym(env, state, elapsed):
    env.unwrapped.state = np.array(state, np.float64)
    env.unwrapped.steps_beyond_terminated = None
    # TimeLimit is the outermost wrapper that counts steps
    w = env
    while not isinstance(w, gym.wrappers.TimeLimit):
        w = w.env
    w._elapsed_steps = elapsed


@pytest.mark.parametrize(
    "state, action, expect_terminated",
    [([0.0, 0.0, 0.01, 0.0], 1, False), ([2.39, 1.0, 0.0, 0.0], 1, True)],
    ids=["truncation-only", "fall-on-500"],
)
def test_truncation_at_500_matches_time_limit(state, action, expect_terminated):
    env = _time_limited()
    _set_gym(env, state, elapsed=499)
    g_obs, g_r, g_term, g_trunc, _ = env.step(action)
    assert (g_term, g_trunc) == (expect_terminated, True)

    params = cartpole.EnvParams()
    s = cartpole.state_from_obs(np.array(state), step_count=499)
    obs, s2, r, term, trunc, info = cartpole.step(jax.random.PRNGKey(0), s, action, params)
    assert (bool(term), bool(trunc)) == (g_term, g_trunc)
    assert float(r) == g_r
    np.testing.assert_allclose(np.asarray(info["final_obs"]), g_obs, atol=1e-5)
    # same-step autoreset: a fresh episode within the reset bounds, step count back to 0
    assert int(s2.step_count) == 0
    assert np.all(np.abs(np.asarray(obs)) <= 0.05)
    assert not np.allclose(np.asarray(obs), np.asarray(info["final_obs"]))


def test_step_499_is_not_truncated():
    s = cartpole.state_from_obs(np.array([0.0, 0.0, 0.01, 0.0]), step_count=498)
    obs, s2, r, term, trunc, info = cartpole.step(jax.random.PRNGKey(0), s, 1, cartpole.EnvParams())
    assert not bool(trunc) and not bool(term)
    assert int(s2.step_count) == 499
    np.testing.assert_array_equal(np.asarray(obs), np.asarray(info["final_obs"]))


def test_autoreset_on_termination_keeps_final_obs():
    params = cartpole.EnvParams()
    s = cartpole.state_from_obs(np.array([2.399, 1.0, 0.0, 0.0]), step_count=17)
    final, _, _, term, trunc = cartpole.step_env(s, 1, params)
    obs, s2, r, term, trunc, info = cartpole.step(jax.random.PRNGKey(3), s, 1, params)
    assert bool(term) and not bool(trunc)
    np.testing.assert_array_equal(np.asarray(info["final_obs"]), np.asarray(final))
    expected_obs, expected_state = cartpole.reset(jax.random.PRNGKey(3), params)
    np.testing.assert_array_equal(np.asarray(obs), np.asarray(expected_obs))
    assert int(s2.step_count) == 0


@pytest.mark.parametrize("low, high", [(-0.05, 0.05), (-0.3, 0.2)], ids=["default", "custom"])
def test_reset_bounds_match_gymnasium(low, high):
    params = cartpole.EnvParams(reset_low=low, reset_high=high)
    obs, state = jax.vmap(cartpole.reset, in_axes=(0, None))(
        jax.random.split(jax.random.PRNGKey(0), 20_000), params
    )
    obs = np.asarray(obs)
    assert obs.dtype == np.float32 and obs.shape == (20_000, 4)
    assert obs.min() >= np.float32(low) and obs.max() < np.float32(high)
    # uniform over the whole interval: the extremes come close to both bounds
    assert obs.min() < low + 0.01 * (high - low) and obs.max() > high - 0.01 * (high - low)
    assert abs(obs.mean() - (low + high) / 2) < 0.01 * (high - low)
    assert np.all(np.asarray(state.step_count) == 0)

    env = gym.make("CartPole-v1")
    options = None if (low, high) == (-0.05, 0.05) else {"low": low, "high": high}
    g = np.array([env.reset(seed=i, options=options)[0] for i in range(2000)])
    assert g.min() >= low and g.max() <= high
    # same distribution: both spread over the same interval
    assert abs(g.min() - obs.min()) < 0.02 * (high - low) and abs(g.max() - obs.max()) < 0.02 * (
        high - low
    )


def test_reset_dtype_follows_x64():
    with jax.enable_x64(True):
        obs, state = cartpole.reset(jax.random.PRNGKey(0), cartpole.EnvParams())
        assert obs.dtype == jnp.float64 and state.x.dtype == jnp.float64
    obs, _ = cartpole.reset(jax.random.PRNGKey(0), cartpole.EnvParams())
    assert obs.dtype == jnp.float32


@pytest.mark.quick
@pytest.mark.parametrize("integrator", ["euler", "semi-implicit"])
def test_whole_random_episodes_match_in_x64(integrator):
    """Same start state and action sequence: same trajectory (1e-12), flags and lengths."""
    worst, lengths, mismatched = run_episodes(integrator, "random", episodes=50)
    assert mismatched == 0
    assert worst <= 1e-12
    assert sum(lengths) > 50 * 10  # real episodes, not immediate failures


def test_whole_500_step_episodes_bit_identical_without_fma():
    """Balanced episodes run to the time limit (truncated at 500) and match bit for bit once
    XLA is kept from fusing multiply-adds (see tests/episode_parity.py)."""
    script = Path(__file__).with_name("episode_parity.py")
    env = {**os.environ, "XLA_FLAGS": "--xla_cpu_max_isa=AVX", "JAX_PLATFORMS": "cpu"}
    proc = subprocess.run(
        [sys.executable, str(script)], env=env, capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert proc.stdout.count("max |diff| 0,") == 2, proc.stdout


@pytest.mark.quick
def test_spaces_match_gymnasium():
    env = gym.make("CartPole-v1")
    assert cartpole.observation_space() == env.observation_space
    assert cartpole.action_space() == env.action_space
    assert env.spec.max_episode_steps == cartpole.EnvParams().max_episode_steps
    u = env.unwrapped
    p = cartpole.EnvParams()
    for name in (
        "gravity",
        "masscart",
        "masspole",
        "length",
        "force_mag",
        "tau",
        "x_threshold",
        "theta_threshold_radians",
        "kinematics_integrator",
    ):
        assert getattr(p, name) == getattr(u, name), name


def test_derived_constants_follow_params():
    """Changing masspole changes total mass and pole-mass-length inside the step."""
    s = cartpole.state_from_obs(np.array([0.0, 0.0, 0.1, 0.5]))
    heavy = cartpole.EnvParams(masspole=0.5)
    env = gym.make("CartPole-v1").unwrapped
    env.masspole = 0.5
    env.total_mass = env.masspole + env.masscart
    env.polemass_length = env.masspole * env.length
    env.reset(seed=0)
    env.state = np.array([0.0, 0.0, 0.1, 0.5])
    g_obs, *_ = env.step(1)
    obs, *_ = cartpole.step_env(s, 1, heavy)
    np.testing.assert_allclose(np.asarray(obs), g_obs, atol=1e-6)


def test_invalid_integrator_rejected():
    with pytest.raises(ValueError, match="kinematics_integrator"):
        cartpole.EnvParams(kinematics_integrator="rk4")


def test_describe_lists_bounds_and_limits(capsys):
    from jaxcart import env as env_command

    assert env_command.main([]) == 0
    out = capsys.readouterr().out
    for text in ("Discrete(2)", "2.4", "0.209440", "500", "-0.05"):
        assert text in out


def test_step_batch_matches_step_semantics():
    """step_batch = vmapped step up to the reset draws: same physics, flags, final_obs."""
    rng = np.random.default_rng(3)
    states = np.concatenate([sample_states(rng, 400), [[0.0, 0.0, 0.01, 0.0]] * 4])
    steps = np.concatenate([rng.integers(0, 499, 400), [499] * 4]).astype(np.int32)
    actions = rng.integers(0, 2, len(states))
    params = cartpole.EnvParams()
    s = cartpole.state_from_obs(states, steps)
    obs, s2, r, term, trunc, info = jax.jit(cartpole.step_batch)(
        jax.random.PRNGKey(0), s, jnp.asarray(actions), params
    )
    ref = jax.jit(jax.vmap(cartpole.step, in_axes=(0, 0, 0, None)))(
        jax.random.split(jax.random.PRNGKey(0), len(states)), s, jnp.asarray(actions), params
    )
    for a, b in zip((r, term, trunc), (ref[2], ref[3], ref[4])):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    # same math; XLA may contract multiply-adds differently in the two programs
    np.testing.assert_allclose(
        np.asarray(info["final_obs"]), np.asarray(ref[5]["final_obs"]), rtol=0, atol=1e-6
    )
    done = np.asarray(term | trunc)
    assert done.sum() > 50 and np.asarray(trunc)[-4:].all()
    obs = np.asarray(obs)
    np.testing.assert_array_equal(obs[~done], np.asarray(info["final_obs"])[~done])
    assert np.all(np.abs(obs[done]) < 0.05) and np.all(np.asarray(s2.step_count)[done] == 0)
    np.testing.assert_array_equal(np.asarray(s2.step_count)[~done], steps[~done] + 1)


@pytest.mark.parametrize("x64", [False, True], ids=["float32", "x64"])
def test_hash_uniform_is_uniform_and_independent(x64):
    from scipy import stats

    with jax.enable_x64(x64):
        u = np.asarray(cartpole.hash_uniform(jax.random.PRNGKey(1), (200_000,)))
        v = np.asarray(cartpole.hash_uniform(jax.random.PRNGKey(2), (200_000,)))
        b = np.asarray(cartpole.hash_uniform(jax.random.PRNGKey(1), (1000, 4), None, -0.05, 0.05))
        assert u.dtype == (np.float64 if x64 else np.float32)
    assert u.min() >= 0.0 and u.max() < 1.0
    assert stats.kstest(u, "uniform").pvalue > 1e-3
    assert stats.kstest(v, "uniform").pvalue > 1e-3
    # neighbouring counters and different keys are uncorrelated
    assert abs(np.corrcoef(u[:-1], u[1:])[0, 1]) < 0.01
    assert abs(np.corrcoef(u, v)[0, 1]) < 0.01
    # 2-d uniformity of successive pairs: chi-square over a 16 x 16 grid
    grid = np.histogram2d(u[0::2], u[1::2], bins=16, range=[[0, 1], [0, 1]])[0]
    assert stats.chisquare(grid.ravel()).pvalue > 1e-3
    assert b.min() >= -0.05 and b.max() < 0.05 and b.shape == (1000, 4)

"""``evaluate_gymnasium`` steps every policy x episode at once, and each return is
bit-identical to stepping one ``gymnasium.make("CartPole-v1")`` per episode (the reference
loop below, which the package used before)."""

from __future__ import annotations

from collections.abc import Callable

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.envs.classic_control.cartpole import CartPoleEnv

from jaxcart.core import networks
from jaxcart.core.cartpole import EnvParams, gymnasium_step
from jaxcart.core.solved import EVAL_SEED, SOLVED_RETURN
from jaxcart.engine.signals import Stopped
from jaxcart.run.greedy import evaluate_gymnasium
from jaxcart.rundir.policy import Policy

NUM_POLICIES, NUM_EPISODES = 64, 20


def reference_evaluation(
    policy: Callable[[np.ndarray], np.ndarray],
    num_policies: int,
    num_episodes: int,
    seed: int = EVAL_SEED,
    env_id: str = "CartPole-v1",
) -> np.ndarray:
    """One ``gymnasium.make(env_id)`` per policy and episode, stepped one at a time, all in
    lockstep with one batched policy call per step: returns ``[num_policies, num_episodes]``."""
    envs = [[gym.make(env_id) for _ in range(num_episodes)] for _ in range(num_policies)]
    obs = np.zeros((num_policies, num_episodes, 4), np.float32)
    for p, row in enumerate(envs):
        for e, env_ in enumerate(row):
            obs[p, e], _ = env_.reset(seed=seed + e)
    returns = np.zeros((num_policies, num_episodes))
    alive = np.ones((num_policies, num_episodes), bool)
    while alive.any():
        actions = np.asarray(policy(obs))
        for p, e in zip(*np.nonzero(alive)):
            o, r, terminated, truncated, _ = envs[p][e].step(int(actions[p, e]))
            obs[p, e] = o
            returns[p, e] += r
            if terminated or truncated:
                alive[p, e] = False
    for row in envs:
        for env_ in row:
            env_.close()
    return returns


def mixed_policy(num_policies: int) -> Callable[[np.ndarray], np.ndarray]:
    """Stacked policies ``[num_policies, N, 4] -> [num_policies, N]`` of three kinds: random
    tanh MLPs (a NumPy Policy, as the package evaluates trained runs), the two constant
    actions, and linear controllers ``obs @ w > 0`` around a balancing one, some of which
    solve every episode, some a few, some none."""
    rng = np.random.default_rng(0)
    num_mlps, num_constant = num_policies // 3, 4
    num_linear = num_policies - num_mlps - num_constant
    sizes = [4, 64, 64, 2]
    names = networks.layer_names(len(sizes) - 2)
    actor = {
        name: {
            "kernel": rng.normal(0.0, 1.0 / np.sqrt(n_in), (num_mlps, n_in, n_out)),
            "bias": rng.normal(0.0, 0.1, (num_mlps, n_out)),
        }
        for name, n_in, n_out in zip(names, sizes[:-1], sizes[1:])
    }
    mlps = Policy(actor, activation="tanh", stacked=True)
    weights = np.array([0.0, 0.0, 1.0, 1.0]) + rng.normal(0.0, 0.6, (num_linear, 4))
    weights[:, 2] = np.abs(weights[:, 2]) + 0.2  # push towards the side the pole leans
    weights = weights.astype(np.float32)

    def policy(obs: np.ndarray) -> np.ndarray:
        constant = np.broadcast_to(
            np.arange(num_constant)[:, None] % 2, (num_constant, obs.shape[1])
        )
        linear = np.einsum("pni,pi->pn", obs[num_mlps + num_constant :], weights) > 0
        return np.concatenate([mlps(obs[:num_mlps]), constant, linear.astype(np.int64)])

    return policy


class Recorder:
    """A policy that also keeps a copy of every observation batch it is given."""

    def __init__(self, policy: Callable[[np.ndarray], np.ndarray]) -> None:
        self.policy = policy
        self.seen: list[np.ndarray] = []

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        self.seen.append(obs.copy())
        return self.policy(obs)


@pytest.fixture(scope="module")
def reference() -> tuple[np.ndarray, list[np.ndarray]]:
    """The reference loop's returns, and the observations the policies were given."""
    policy = Recorder(mixed_policy(NUM_POLICIES))
    return reference_evaluation(policy, NUM_POLICIES, NUM_EPISODES), policy.seen


def test_the_policies_cover_solved_partly_solved_and_failed(reference):
    returns, _ = reference
    solved = returns == SOLVED_RETURN
    assert solved.all(axis=1).any(), "no policy solves every episode"
    assert (solved.any(axis=1) & ~solved.all(axis=1)).any(), "no policy solves only some"
    assert (~solved.any(axis=1)).any(), "every policy solves some episode"
    assert len(np.unique(returns)) > 50  # episodes end at many different steps


def test_batched_evaluation_is_bit_identical_to_one_env_per_episode(reference):
    """The same returns, and the same float32 observations given to the policies at every
    step (a trajectory that drifted by an ulp would show there long before in a return)."""
    expected_returns, expected_seen = reference
    policy = Recorder(mixed_policy(NUM_POLICIES))
    returns = evaluate_gymnasium(policy, NUM_POLICIES, NUM_EPISODES)
    assert returns.dtype == np.float64 and returns.shape == (NUM_POLICIES, NUM_EPISODES)
    np.testing.assert_array_equal(returns, expected_returns)
    assert len(policy.seen) == len(expected_seen) == SOLVED_RETURN
    for step, (seen, expected) in enumerate(zip(policy.seen, expected_seen)):
        assert seen.dtype == np.float32
        np.testing.assert_array_equal(seen, expected, err_msg=f"step {step}")


@pytest.mark.parametrize("integrator", ["euler", "semi-implicit"])
def test_the_batched_step_is_gymnasiums_step_bit_for_bit(integrator):
    """Next states (float64) and terminations of the batched step equal ``CartPoleEnv.step``'s
    one state at a time, over states spread across (and beyond) the episode bounds."""
    env = CartPoleEnv()
    env.kinematics_integrator = integrator
    rng, n = np.random.default_rng(1), 20_000
    bounds = np.array([2.6, 3.0, 0.25, 3.5])[:, None]
    states = rng.uniform(-bounds, bounds, (4, n))
    actions = rng.integers(0, 2, n)
    stepped, terminated = gymnasium_step(env, states, actions)
    expected = np.empty_like(states)
    expected_terminated = np.empty(n, bool)
    for i in range(n):
        env.state, env.steps_beyond_terminated = states[:, i].copy(), None
        _, _, expected_terminated[i], _, _ = env.step(int(actions[i]))
        expected[:, i] = env.state
    np.testing.assert_array_equal(stepped, expected)
    np.testing.assert_array_equal(terminated, expected_terminated)
    assert 0 < expected_terminated.sum() < n


def semi_implicit_cartpole(**kwargs) -> CartPoleEnv:
    """Gymnasium's CartPole with its other integrator (an attribute, not an argument)."""
    env = CartPoleEnv(**kwargs)
    env.kinematics_integrator = "semi-implicit"
    return env


VARIANTS = {  # id: (entry point, time limit, kwargs, the same CartPole as jaxcart's physics)
    "jaxcart-test/CartPole-semi-implicit-v0": (
        semi_implicit_cartpole,
        200,
        {},
        EnvParams(kinematics_integrator="semi-implicit", max_episode_steps=200),
    ),
    "jaxcart-test/CartPole-sutton-barto-v0": (
        CartPoleEnv,
        500,
        {"sutton_barto_reward": True},
        EnvParams(sutton_barto_reward=True),
    ),
}


@pytest.mark.parametrize("env_id", sorted(VARIANTS))
def test_other_cartpoles_and_seeds_match_too(env_id):
    """The other integrator with a 200-step limit, and Sutton and Barto's rewards (0 per
    step, -1 on failure), from other reset seeds: set as physics on CartPole-v1 (the batched
    step), and under an id of Gymnasium's alone (one env per episode)."""
    entry_point, limit, kwargs, physics = VARIANTS[env_id]
    if env_id not in gym.registry:
        gym.register(env_id, entry_point, max_episode_steps=limit, kwargs=kwargs)
    args = (mixed_policy(24), 24, 6)
    expected = reference_evaluation(*args, seed=7, env_id=env_id)
    if "sutton" in env_id:
        assert set(np.unique(expected)) == {-1.0, 0.0}
    else:
        assert expected.max() == limit and (expected < limit).any()
    np.testing.assert_array_equal(evaluate_gymnasium(*args, seed=7, env_params=physics), expected)
    np.testing.assert_array_equal(evaluate_gymnasium(*args, seed=7, env_id=env_id), expected)


def test_should_stop_interrupts_the_evaluation():
    polls = []

    def should_stop() -> bool:
        polls.append(None)
        return len(polls) == 3

    with pytest.raises(Stopped):
        evaluate_gymnasium(mixed_policy(6), 6, 2, should_stop=should_stop)
    assert len(polls) == 3


def test_other_envs_step_one_gymnasium_env_per_episode():
    """Any other discrete-action env runs in the same loop on its own ``step`` (Acrobot: a
    constant torque never swings up, so every episode is truncated at -500)."""
    returns = evaluate_gymnasium(
        lambda obs: np.zeros(obs.shape[:2], int), 2, 2, env_id="Acrobot-v1"
    )
    np.testing.assert_array_equal(returns, np.full((2, 2), -500.0))


def test_refuses_actions_outside_the_action_space():
    with pytest.raises(ValueError, match=r"actions must be in 0\.\.1, got \[2\]"):
        evaluate_gymnasium(lambda obs: np.full(obs.shape[:2], 2), 2, 2)
    with pytest.raises(ValueError, match=r"actions must be in 0\.\.2"):
        evaluate_gymnasium(lambda obs: np.full(obs.shape[:2], 3), 2, 1, env_id="Acrobot-v1")

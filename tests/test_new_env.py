"""The env protocol is the only path: an env defined here, in a few lines, trains and is
evaluated in JAX through the public API, without touching the package."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxcart
from jaxcart.core.envs import EnvError

LIMIT = 50
DEVICE = jax.devices()[:1]


def reset(key: jax.Array, params: None) -> tuple[jax.Array, tuple]:
    """A point on a line, at rest, somewhere in [-0.5, 0.5]."""
    x = jax.random.uniform(key, (), minval=-0.5, maxval=0.5)
    state = (x, jnp.zeros(()), jnp.zeros((), jnp.int32))
    return jnp.stack([x, 0.0]), state


def step(key: jax.Array, state: tuple, action: jax.Array, params: None) -> tuple:
    """Push left, nothing, push right; +1 a step while |x| <= 1, for at most LIMIT steps."""
    x, v, t = state
    v = v + 0.05 * (action - 1)
    x, t = x + 0.1 * v, t + 1
    return jnp.stack([x, v]), (x, v, t), jnp.ones(()), jnp.abs(x) > 1.0, t >= LIMIT


def point_mass(step_fn=step, reward_threshold: float = 45.0) -> jaxcart.Env:
    """The point mass as a registered env ``PointMass-v0``, stepping with ``step_fn``."""
    return jaxcart.register_env(
        jaxcart.env_from_step(
            "PointMass-v0",
            obs_dim=2,
            num_actions=3,
            reset=reset,
            step=step_fn,
            max_episode_steps=LIMIT,
            reward_threshold=reward_threshold,
        )
    )


POINT_MASS = point_mass()

CONFIG = jaxcart.PPOConfig(
    env="PointMass-v0", num_envs=4, num_steps=32, minibatch_size=64, total_timesteps=128 * 8
)


@pytest.mark.slow
def test_a_registered_env_trains_and_evaluates_in_jax():
    from jaxcart.core.evaluation import greedy_returns
    from jaxcart.core.ppo import make_network

    result = jaxcart.train_runs(CONFIG, num_runs=2, seed=3, runs_per_device=2, devices=DEVICE)
    assert result.state.iteration == CONFIG.num_iterations == 8
    assert result.runners.obs.shape == (2, 4, 2)  # [runs, envs, obs_dim]
    assert result.params["params"]["actor"]["out"]["kernel"].shape[-1] == 3  # num_actions
    assert np.isfinite(result.metrics["train/loss"]).all()
    # every episode pays 1 a step: finished episodes' mean return is within [1, LIMIT]
    finished = result.metrics["rollout/ep_rew_mean"]
    finished = finished[np.isfinite(finished)]
    assert finished.size and ((finished >= 1) & (finished <= LIMIT)).all()

    network = make_network(CONFIG)
    evaluate = jax.jit(
        jax.vmap(lambda p, k: greedy_returns(p, k, network, 5, None, "PointMass-v0"))
    )
    returns = np.asarray(evaluate(result.params, jax.random.split(jax.random.PRNGKey(1), 2)))
    assert returns.shape == (2, 5)
    assert ((returns >= 1) & (returns <= LIMIT)).all()


def test_training_is_reproducible_and_per_seed():
    """Seed index 1 replays bit for bit alone (padded to the same width: a run's numbers
    depend on the width of the program only)."""
    both = jaxcart.train_runs(CONFIG, num_runs=2, seed=3, runs_per_device=2, devices=DEVICE)
    again = jaxcart.train_runs(
        CONFIG, num_runs=1, seed=3, seed_indices=np.array([1]), runs_per_device=2, devices=DEVICE
    )
    np.testing.assert_array_equal(
        both.params["params"]["actor"]["out"]["kernel"][1],
        again.params["params"]["actor"]["out"]["kernel"][0],
    )


def test_own_ids_cannot_be_taken():
    import dataclasses

    with pytest.raises(EnvError, match="CartPole-v1 is one of jaxcart's own"):
        jaxcart.register_env(dataclasses.replace(POINT_MASS, id="CartPole-v1"))


@pytest.mark.slow
def test_an_env_registered_again_under_its_id_trains_anew():
    """The compiled program is the env's: one registered again under the same id (here paying
    2 a step) is not run by the program compiled for the first."""
    import dataclasses

    def step_paying_two(key, state, action, params):
        obs, state, reward, terminated, truncated = step(key, state, action, params)
        return obs, state, 2 * reward, terminated, truncated

    config = dataclasses.replace(CONFIG, total_timesteps=128)
    first = jaxcart.train_runs(config, num_runs=1, seed=0, devices=DEVICE).runners
    assert np.all(first.episode_return == first.episode_length)
    try:
        point_mass(step_paying_two, reward_threshold=90.0)
        again = jaxcart.train_runs(config, num_runs=1, seed=0, devices=DEVICE).runners
        assert np.all(again.episode_return == 2 * again.episode_length)
    finally:
        jaxcart.register_env(POINT_MASS)

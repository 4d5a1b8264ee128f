"""train_speed's rejax contenders, S seeds as a ``vmap`` over ``train`` sharded over the CPU
devices like jaxcart's:

- ``rejax-sb3-xS``: rejax's PPO at SB3's hyperparameters;
- ``rejax-cartpole-xS``: rejax's PPO at its own CartPole-v1 configuration, the ``ppo`` entry of
  ``configs/gymnax/cartpole.yaml`` in rejax's repository (``REJAX_CARTPOLE``; the pip package
  ships no configs);
- ``rejax-acrobot-xS``: rejax's PPO at its own Acrobot-v1 configuration, the ``ppo`` entry of
  ``configs/gymnax/acrobot.yaml`` (``REJAX_ACROBOT``), which normalises observations: its
  greedy policy applies the learned running mean and variance before the network.

rejax 0.1.3 needs gymnax 0.0.x, so these run in their own virtualenv (``--rejax-python``).
"""

from __future__ import annotations

import copy
import os
import sys
import time

import numpy as np

from benchmarks.train_speed.common import (
    QUICK_TIMESTEPS,
    SB3_TIMESTEPS,
    ChildUnavailable,
    configure_jax_cache,
)

# The greedy policy taken out of rejax's train state must pick rejax's own actions on at least
# this share of sampled observations (an exact tie in the logits may break either way).
CHECK_OBSERVATIONS = 64  # per seed; few, as the check runs inside the timed process
CHECK_AGREEMENT = 0.99

# Where rejax's PPO differs from SB3's at these settings (it has no options for them).
REJAX_DIFFERENCES = (
    "Adam eps 1e-8 (SB3 1e-5), separate Adam optimisers and gradient clipping for actor and "
    "critic, clipped value loss, default (lecun-normal) rather than orthogonal init, and "
    "time-limit truncation treated as termination"
)


# keraJLi/rejax configs/gymnax/cartpole.yaml, ppo (the same values as the older
# configs/cartpole.yaml); its eval_freq (1000) is left out: evaluation is a no-op here.
REJAX_CARTPOLE = dict(
    num_envs=5,
    num_steps=100,
    num_epochs=5,
    num_minibatches=5,
    learning_rate=0.00075,
    max_grad_norm=0.5,
    total_timesteps=100_000,
    gamma=0.99,
    gae_lambda=0.95,
    clip_eps=0.2,
    ent_coef=0.01,
    vf_coef=0.5,
    agent_kwargs={"activation": "tanh"},  # hidden layers: rejax's default (64, 64)
)


# keraJLi/rejax configs/gymnax/acrobot.yaml, ppo: the CartPole entry's values, on
# Acrobot-v1, with observations normalised by a running mean and variance; its eval_freq
# (1000) is left out as for CartPole.
REJAX_ACROBOT = dict(REJAX_CARTPOLE, normalize_observations=True)


def own_config(values: dict, env: str, total: int) -> dict:
    """rejax ``PPO.create`` arguments: one of rejax's own configurations on ``env``, run for
    ``total`` steps with its periodic evaluation out of the way."""
    return dict(
        copy.deepcopy(values),  # PPO.create pops from agent_kwargs
        env=env,
        total_timesteps=total,
        eval_freq=total,  # one evaluation period, and the evaluation a no-op (see run)
        skip_initial_evaluation=True,
    )


def rejax_cartpole_config(quick: bool) -> dict:
    """rejax ``PPO.create`` arguments of rejax's own CartPole-v1 configuration."""
    total = QUICK_TIMESTEPS["cartpole"] if quick else REJAX_CARTPOLE["total_timesteps"]
    return own_config(REJAX_CARTPOLE, "CartPole-v1", total)


def rejax_acrobot_config(quick: bool) -> dict:
    """rejax ``PPO.create`` arguments of rejax's own Acrobot-v1 configuration."""
    total = QUICK_TIMESTEPS["acrobot-rejax"] if quick else REJAX_ACROBOT["total_timesteps"]
    return own_config(REJAX_ACROBOT, "Acrobot-v1", total)


def rejax_config(quick: bool) -> dict:
    """rejax ``PPO.create`` arguments for SB3's PPO defaults on CartPole-v1."""
    iterations = -(-(QUICK_TIMESTEPS["sb3"] if quick else SB3_TIMESTEPS) // 2048)
    total = iterations * 2048
    return dict(
        env="CartPole-v1",
        num_envs=1,
        num_steps=2048,
        num_epochs=10,
        num_minibatches=32,  # 2048 / 64
        learning_rate=3e-4,
        max_grad_norm=0.5,
        gamma=0.99,
        gae_lambda=0.95,
        clip_eps=0.2,
        ent_coef=0.0,
        vf_coef=0.5,
        total_timesteps=total,
        # One evaluation "period" spanning the whole run, and the evaluation itself replaced
        # by a no-op below, so rejax's in-training evaluation costs nothing.
        eval_freq=total,
        skip_initial_evaluation=True,
        agent_kwargs={"activation": "tanh", "hidden_layer_sizes": (64, 64)},
    )


class NormalizedPolicy:
    """A stacked greedy policy whose observations are first normalised as rejax's
    ``NormalizeObservationsMixin.normalize_obs`` does, ``(obs - mean) / sqrt(var + 1e-8)``,
    with each seed's running ``mean`` and ``var`` ``[S, obs_dim]`` from its train state."""

    def __init__(self, policy, mean: np.ndarray, var: np.ndarray) -> None:
        self.policy = policy  # a stacked jaxcart Policy (NumPy) over the seeds' actors
        # [S, obs_dim] -> [S, 1, obs_dim]: broadcast over each seed's N observations
        self.mean = np.asarray(mean, np.float32)[:, None, :]
        self.scale = np.sqrt(np.asarray(var, np.float32) + np.float32(1e-8))[:, None, :]

    @property
    def num_seeds(self) -> int:
        return self.policy.num_seeds

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """Greedy actions ``[S, N]`` for observations ``[S, N, obs_dim]``."""
        return self.policy((np.asarray(obs, np.float32) - self.mean) / self.scale)


def greedy_policy(ts, env_id: str, obs_dim: int, normalized: bool):
    """jaxcart's NumPy greedy policy over the seeds' stacked rejax train states ``ts`` (on
    the host): the actor's layers, after rejax's observation normalisation when the run
    ``normalized`` (its train state holds the running statistics either way)."""
    from jaxcart.rundir.policy import Policy

    p = ts.actor_ts.params["params"]
    layers = {
        "hidden_0": p["features"]["Dense_0"],
        "hidden_1": p["features"]["Dense_1"],
        "out": p["action_logits"],
    }
    policy = Policy(layers, activation="tanh", stacked=True)
    policy.env_id, policy.obs_dim = env_id, obs_dim
    if not normalized:
        return policy
    return NormalizedPolicy(policy, ts.obs_rms_state.mean, ts.obs_rms_state.var)


def sample_observations(env_id: str, num_seeds: int) -> np.ndarray:
    """Plausible observations ``[num_seeds, CHECK_OBSERVATIONS, obs_dim]`` float32 of the env,
    within its observation bounds (random, seeded)."""
    rng = np.random.default_rng(0)
    shape = (num_seeds, CHECK_OBSERVATIONS)
    if env_id == "Acrobot-v1":  # cos, sin of both angles, then the two angular velocities
        t1, t2 = rng.uniform(-np.pi, np.pi, (2, *shape))
        v1 = rng.uniform(-4 * np.pi, 4 * np.pi, shape)
        v2 = rng.uniform(-9 * np.pi, 9 * np.pi, shape)
        obs = np.stack([np.cos(t1), np.sin(t1), np.cos(t2), np.sin(t2), v1, v2], axis=-1)
    else:  # CartPole-v1: position, velocity, angle, angular velocity
        scale = np.array([2.4, 3.0, 0.21, 3.0])
        obs = rng.uniform(-1, 1, (*shape, 4)) * scale
    return obs.astype(np.float32)


def check_policy(algo, ts, policy, env_id: str) -> float:
    """The share of sampled observations on which ``policy`` picks the action of rejax's own
    actor (the mode of its action distribution) applied after rejax's own ``normalize_obs``;
    raises when under :data:`CHECK_AGREEMENT`."""
    import jax

    def rejax_greedy(seed_ts, obs):
        if algo.normalize_observations:
            obs = algo.normalize_obs(seed_ts.obs_rms_state, obs)
        mode = lambda actor, x: actor._action_dist(x).mode()
        return algo.actor.apply(seed_ts.actor_ts.params, obs, method=mode)

    obs = sample_observations(env_id, policy.num_seeds)
    # not jitted: a few small ops, and no whole program to compile inside the timed process
    theirs = np.asarray(jax.vmap(rejax_greedy)(ts, obs))
    agree = float(np.mean(policy(obs) == theirs))
    if agree < CHECK_AGREEMENT:
        raise RuntimeError(f"the NumPy policy agrees with rejax's actor on only {agree:.1%}")
    return agree


def run(
    preset_name: str,
    num_seeds: int,
    quick: bool,
    cache_dir: str | None,
    timesteps: int | None = None,
):
    """Trains ``num_seeds`` rejax PPO agents at SB3's settings (``preset_name`` ``sb3``) or at
    rejax's own CartPole or Acrobot configuration (``cartpole``, ``acrobot``), for
    ``timesteps`` env steps each when given (the configuration's otherwise), and checks the
    normalised greedy policy taken out of them (Acrobot's) against rejax's own actor
    (:func:`check_policy`, timed apart as ``policy_check_seconds``, inside the process's wall
    time).

    Returns:
        ``(data, policy)``: the timings and settings, and the seeds' stacked greedy policy
        for the harness to evaluate.
    """
    flag = "--xla_force_host_platform_device_count"
    if flag not in os.environ.get("XLA_FLAGS", ""):
        cores = len(os.sched_getaffinity(0))
        os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {flag}={cores}".strip()
    try:
        import jax
        import jax.numpy as jnp
        from jax.sharding import Mesh, NamedSharding, PartitionSpec
        from rejax import PPO
    except ImportError as e:
        raise ChildUnavailable(f"rejax not installed in {sys.executable} ({e})") from None
    configure_jax_cache(cache_dir)

    configs = {
        "sb3": rejax_config,
        "cartpole": rejax_cartpole_config,
        "acrobot": rejax_acrobot_config,
    }
    if preset_name not in configs:
        raise ValueError(f"unknown rejax configuration {preset_name!r}")
    config = configs[preset_name](quick)
    if timesteps:  # one evaluation period still spans the run (see own_config)
        config = dict(config, total_timesteps=timesteps, eval_freq=timesteps)
    t0 = time.perf_counter()
    algo = PPO.create(**config)
    algo = algo.replace(eval_callback=lambda algo, ts, rng: jnp.zeros(()))
    devs = jax.devices()
    count = max(d for d in range(1, len(devs) + 1) if num_seeds % d == 0)
    sharding = NamedSharding(Mesh(np.array(devs[:count]), ("seed",)), PartitionSpec("seed"))
    base = jax.random.PRNGKey(0)
    keys = jax.vmap(lambda i: jax.random.fold_in(base, i))(jnp.arange(num_seeds, dtype=jnp.uint32))
    keys = jax.device_put(keys, sharding)
    train = jax.jit(jax.vmap(algo.train))
    c0 = time.perf_counter()
    compiled = train.lower(keys).compile()
    t1, cpu1 = time.perf_counter(), time.process_time()
    ts, _ = compiled(keys)
    jax.block_until_ready(ts)
    t2, cpu2 = time.perf_counter(), time.process_time()
    normalized = bool(getattr(algo, "normalize_observations", False))
    obs_dim = int(ts.last_obs.shape[-1])
    policy = greedy_policy(jax.device_get(ts), config["env"], obs_dim, normalized)
    # Only the normalised policy is checked (its NumPy normalisation is this module's own);
    # the others keep the wall times they were published with.
    agree = check_policy(algo, ts, policy, config["env"]) if normalized else None
    t3 = time.perf_counter()

    data = {
        "num_seeds": num_seeds,
        "env_steps": int(np.sum(jax.device_get(ts.global_step))),
        "setup_seconds": t1 - t0,
        "compile_seconds": t1 - c0,
        "train_seconds": t2 - t1,
        "train_cpu_seconds": cpu2 - cpu1,
        "jax_devices": [str(d) for d in devs],
        "devices_used": count,
        "config": {k: v for k, v in config.items() if k != "env"},
        **(
            {"policy_check_agreement": agree, "policy_check_seconds": t3 - t2} if normalized else {}
        ),
        **({"differences_from_sb3": REJAX_DIFFERENCES} if preset_name == "sb3" else {}),
    }
    return data, policy

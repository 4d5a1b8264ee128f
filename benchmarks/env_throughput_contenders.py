"""The contenders of env_throughput.py: how each one is built and stepped.

A contender at N envs is a :class:`Runner` whose ``call()`` runs a fixed number of env steps
with uniformly random actions and blocks until they are done. Imported by env_throughput.py
after it has exposed the host's cores as JAX devices.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

import jaxcart.env as cartpole

CONTENDERS = ("jaxcart", "gymnax", "gymnasium-vector", "gymnasium-sync", "envpool")
LABELS = {
    "jaxcart": "jaxcart (jit/scan/vmap)",
    "gymnax": "gymnax 1.x (jit/scan/vmap)",
    "gymnasium-vector": "Gymnasium CartPoleVectorEnv (NumPy)",
    "gymnasium-sync": "Gymnasium SyncVectorEnv",
    "envpool": "EnvPool (C++)",
}
# Env steps per compiled call (num_steps x num_envs) aimed at; a call is a scan this long.
STEPS_PER_CALL = 2**19
MAX_SCAN_LENGTH = 2000


class Unavailable(Exception):
    """A contender cannot run here (not installed, or fails to start); the message says why."""


@dataclass
class Runner:
    """One contender at one size: ``call()`` runs ``steps_per_call`` env steps and blocks."""

    call: Callable[[], None]
    steps_per_call: int
    setup_seconds: float
    notes: dict = field(default_factory=dict)
    close: Callable[[], None] = lambda: None


def env_sharding(num_envs: int) -> NamedSharding:
    """Shards a leading env axis over all JAX devices when ``num_envs`` divides evenly,
    otherwise keeps it on the first device."""
    devs = jax.devices()
    if num_envs % len(devs) != 0:
        devs = devs[:1]
    return NamedSharding(Mesh(np.array(devs), ("env",)), PartitionSpec("env"))


def scan_length(num_envs: int) -> int:
    """Steps per compiled call: about :data:`STEPS_PER_CALL` env steps, at most
    :data:`MAX_SCAN_LENGTH` and at least 4."""
    return int(min(MAX_SCAN_LENGTH, max(4, STEPS_PER_CALL // num_envs)))


def initial_carry(reset, params, num_envs: int, sharding: NamedSharding) -> tuple:
    """A rollout's first carry, ``(env states, per-env keys, finished-episode counts)``, with
    every env reset from its own key (all split from key 0), placed with ``sharding``."""
    keys = jax.random.split(jax.random.PRNGKey(0), num_envs + 1)
    _, env_state = jax.vmap(reset, in_axes=(0, None))(keys[1:], params)
    step_keys = jax.random.split(keys[0], num_envs)
    state = (env_state, step_keys, jnp.zeros((num_envs,), jnp.int32))
    return jax.device_put(state, sharding)


def jaxcart_random_rollout(num_envs: int, num_steps: int):
    """jaxcart's contender: ``num_steps`` steps of ``num_envs`` envs with uniform random actions.

    The batch steps with :func:`jaxcart.env.step_batch` (one key per step for the whole
    batch; reset states from jaxcart's counter hash). Uniform random actions are 32 to a word:
    one ``jax.random.bits`` word per 32 envs per step, unpacked bit by bit. The carry's leaves
    have a leading env axis, sharded over the devices by :func:`env_sharding`; each env keeps
    its own key so shards draw independent numbers.

    Returns:
        ``(rollout, state)``: ``rollout(state) -> state`` is jitted (state donated) and runs
        ``num_steps x num_envs`` env steps; ``state`` is the initial carry, on the devices.
        The carry counts finished episodes per env, so the result depends on every step.
    """
    params = cartpole.EnvParams()
    sharding = env_sharding(num_envs)
    local_envs = num_envs // sharding.mesh.size  # each device steps its own share

    def one_step(carry, t):
        env_state, keys, episodes = carry
        # Per step: one action word per 32 envs and one reset key, folded from the env's key.
        key = jax.random.fold_in(keys[0], t)
        action_key, reset_key = jax.random.split(key)
        words = jax.random.bits(action_key, ((local_envs + 31) // 32,), jnp.uint32)
        shifts = jnp.arange(32, dtype=jnp.uint32)
        actions = ((words[:, None] >> shifts) & 1).reshape(-1)[:local_envs].astype(jnp.int32)
        _, env_state, _, terminated, truncated, _ = cartpole.step_batch(
            reset_key, env_state, actions, params
        )
        episodes = episodes + (terminated | truncated).astype(jnp.int32)
        return (env_state, keys, episodes), None

    def rollout(carry):
        carry, _ = jax.lax.scan(one_step, carry, jnp.arange(num_steps, dtype=jnp.uint32))
        return carry

    state = initial_carry(cartpole.reset, params, num_envs, sharding)
    # shard_map: every device runs the whole scan on its own envs, no cross-device traffic.
    spec = sharding.spec
    local = jax.shard_map(rollout, mesh=sharding.mesh, in_specs=(spec,), out_specs=spec)
    fn = jax.jit(local, out_shardings=sharding, donate_argnums=0)
    return fn, state


def gymnax_random_rollout(num_envs: int, num_steps: int):
    """gymnax 1.x ``CartPole-v1`` driven exactly like :func:`jaxcart_random_rollout`."""
    try:
        import gymnax
    except ImportError as e:
        raise Unavailable(f"gymnax is not installed ({e})") from None
    env, params = gymnax.make("CartPole-v1")
    sharding = env_sharding(num_envs)

    def one_step(carry, _):
        env_state, keys, episodes = carry
        split = jax.vmap(lambda k: jax.random.split(k, 3))(keys)
        keys, action_keys, step_keys = split[:, 0], split[:, 1], split[:, 2]
        actions = jax.vmap(jax.random.bernoulli)(action_keys).astype(jnp.int32)
        out = jax.vmap(env.step, in_axes=(0, 0, 0, None))(step_keys, env_state, actions, params)
        if len(out) == 6:  # gymnax >= 1.0: obs, state, reward, terminated, truncated, info
            _, env_state, _, terminated, truncated, _ = out
            done = terminated | truncated
        else:  # gymnax 0.0.x: obs, state, reward, done, info
            _, env_state, _, done, _ = out
        episodes = episodes + done.astype(jnp.int32)
        return (env_state, keys, episodes), None

    def rollout(carry):
        carry, _ = jax.lax.scan(one_step, carry, None, length=num_steps)
        return carry

    state = initial_carry(env.reset, params, num_envs, sharding)
    fn = jax.jit(rollout, out_shardings=sharding, donate_argnums=0)
    return fn, state


def jax_runner(make_rollout, num_envs: int) -> Runner:
    """Compiles (timed) a rollout of :func:`scan_length` steps; each call continues the state."""
    num_steps = scan_length(num_envs)
    start = time.perf_counter()
    fn, state = make_rollout(num_envs, num_steps)
    compiled = fn.lower(state).compile()
    compile_seconds = time.perf_counter() - start
    holder = [state]

    def call():
        holder[0] = compiled(holder[0])
        jax.block_until_ready(holder[0])

    devices_used = len(env_sharding(num_envs).mesh.devices.flat)
    return Runner(
        call=call,
        steps_per_call=num_envs * num_steps,
        setup_seconds=compile_seconds,
        notes={"scan_length": num_steps, "devices": devices_used},
    )


def gymnasium_runner(num_envs: int, mode: str) -> Runner:
    """Gymnasium's vector env (``mode``: ``vector_entry_point`` or ``sync``), one step a call."""
    try:
        import gymnasium as gym
    except ImportError as e:
        raise Unavailable(f"gymnasium is not installed ({e})") from None
    start = time.perf_counter()
    envs = gym.make_vec("CartPole-v1", num_envs=num_envs, vectorization_mode=mode)
    envs.reset(seed=0)
    setup = time.perf_counter() - start
    rng = np.random.default_rng(0)

    def call():
        envs.step(rng.integers(0, 2, size=num_envs))

    return Runner(
        call=call,
        steps_per_call=num_envs,
        setup_seconds=setup,
        notes={"env": type(envs).__name__, "autoreset": str(envs.metadata.get("autoreset_mode"))},
        close=envs.close,
    )


def envpool_runner(num_envs: int) -> Runner:
    """EnvPool's CartPole-v1 (synchronous: each call steps all envs), one step a call."""
    try:
        import envpool
    except ImportError as e:
        raise Unavailable(f"envpool is not installed ({e})") from None
    start = time.perf_counter()
    envs = envpool.make("CartPole-v1", env_type="gymnasium", num_envs=num_envs, seed=0)
    envs.reset()
    setup = time.perf_counter() - start
    rng = np.random.default_rng(0)

    def call():
        envs.step(rng.integers(0, 2, size=num_envs, dtype=np.int32))

    spec = envs.spec.config
    return Runner(
        call=call,
        steps_per_call=num_envs,
        setup_seconds=setup,
        notes={"num_threads": getattr(spec, "num_threads", None)},
        close=envs.close,
    )


def make_runner(name: str, num_envs: int) -> Runner:
    if name == "jaxcart":
        return jax_runner(jaxcart_random_rollout, num_envs)
    if name == "gymnax":
        return jax_runner(gymnax_random_rollout, num_envs)
    if name == "gymnasium-vector":
        return gymnasium_runner(num_envs, "vector_entry_point")
    if name == "gymnasium-sync":
        return gymnasium_runner(num_envs, "sync")
    if name == "envpool":
        return envpool_runner(num_envs)
    raise ValueError(name)

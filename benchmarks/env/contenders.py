"""The contenders of the env throughput benchmark: how each one is built and stepped.

A contender at N envs is a :class:`Runner` whose ``call()`` runs a fixed number of env steps
with uniformly random actions and blocks until they are done. Every contender is driven by the
same harness code: the same action generator (one random bit per env and step:
:func:`jax_actions`, :func:`host_actions`) and the same consumed outputs (:func:`consume`, a
checksum of observations, rewards, terminations and truncations); the JAX contenders also share
one rollout (:func:`jax_rollout`), so they differ only in their env's ``step``. Imported by
``throughput``'s worker after it has set the process's cores and JAX devices.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

import jaxcart.core.cartpole as cartpole

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


# The harness: every contender gets the same actions and has every output consumed.


def jax_actions(key: jax.Array, num_envs: int) -> jax.Array:
    """Uniform random actions ``[num_envs]`` int32: one ``jax.random.bits`` word per 32 envs,
    unpacked bit by bit (the cheapest exact fair coin; used for every JAX contender)."""
    words = jax.random.bits(key, ((num_envs + 31) // 32,), jnp.uint32)
    shifts = jnp.arange(32, dtype=jnp.uint32)
    return ((words[:, None] >> shifts) & 1).reshape(-1)[:num_envs].astype(jnp.int32)


def host_actions(rng: np.random.Generator, num_envs: int) -> np.ndarray:
    """:func:`jax_actions` for the host contenders: one random bit per env, from random bytes."""
    packed = rng.integers(0, 256, size=(num_envs + 7) // 8, dtype=np.uint8)
    return np.unpackbits(packed, count=num_envs).astype(np.int32)


def consume(obs, reward, terminated, truncated, xp=jnp):
    """What the harness keeps of a step: a checksum of every output (observations, rewards,
    terminations, truncations), so no contender can skip computing any of them."""
    return (
        xp.sum(obs, dtype=xp.float32)
        + xp.sum(reward, dtype=xp.float32)
        + xp.sum(terminated, dtype=xp.float32)
        + 2 * xp.sum(truncated, dtype=xp.float32)
    )


def jax_rollout(step, reset_state, num_envs: int, num_steps: int):
    """The one rollout of every JAX contender: ``num_steps`` steps of ``num_envs`` envs.

    Per step and device: one key ``fold_in(key, t)``, split into an action key
    (:func:`jax_actions`) and an env key that ``step(env_key, state, actions)`` uses as its API
    needs (for its autoreset draws); the step's outputs go into :func:`consume`'s checksum.
    The env axis is sharded over the devices by :func:`env_sharding` with ``shard_map``, so
    every device runs the whole scan on its own envs with no cross-device traffic.

    Args:
        step: ``(key, state [n], actions [n]) -> (obs [n, 4], state, reward, terminated,
            truncated)`` for a device's ``n`` envs.
        reset_state: ``(key, n) -> state [n]``, the first states.

    Returns:
        ``(rollout, carry)``: ``rollout(carry) -> carry`` (jitted, carry donated) runs
        ``num_steps x num_envs`` env steps; ``carry = (state, key [devices], checksum
        [devices])`` on the devices.
    """
    sharding = env_sharding(num_envs)
    num_devices = sharding.mesh.size
    local_envs = num_envs // num_devices

    def one_step(carry, t):
        state, key, total = carry
        action_key, env_key = jax.random.split(jax.random.fold_in(key[0], t))
        obs, state, reward, terminated, truncated = step(
            env_key, state, jax_actions(action_key, local_envs)
        )
        return (state, key, total + consume(obs, reward, terminated, truncated)), None

    def rollout(carry):
        carry, _ = jax.lax.scan(one_step, carry, jnp.arange(num_steps, dtype=jnp.uint32))
        return carry

    keys = jax.random.split(jax.random.PRNGKey(0), num_devices + 1)
    state = reset_state(keys[0], num_envs)
    carry = (state, keys[1:], jnp.zeros((num_devices,), jnp.float32))
    carry = jax.device_put(carry, sharding)
    spec = sharding.spec
    local = jax.shard_map(rollout, mesh=sharding.mesh, in_specs=(spec,), out_specs=spec)
    return jax.jit(local, out_shardings=sharding, donate_argnums=0), carry


def jaxcart_random_rollout(num_envs: int, num_steps: int):
    """jaxcart in :func:`jax_rollout`: :func:`jaxcart.core.cartpole.step_batch` (its API takes one key
    per step for the whole batch; reset states from jaxcart's counter hash)."""
    params = cartpole.EnvParams()

    def step(key, state, actions):
        return cartpole.step_batch(key, state, actions, params)[:5]

    def reset_state(key, n):
        return jax.vmap(cartpole.reset, in_axes=(0, None))(jax.random.split(key, n), params)[1]

    return jax_rollout(step, reset_state, num_envs, num_steps)


def gymnax_random_rollout(num_envs: int, num_steps: int):
    """gymnax ``CartPole-v1`` in :func:`jax_rollout`: ``vmap(env.step)``, whose API takes a key
    per env, given ``jax.random.split(env_key, n)`` (the cheapest way to make them)."""
    try:
        import gymnax
    except ImportError as e:
        raise Unavailable(f"gymnax is not installed ({e})") from None
    env, params = gymnax.make("CartPole-v1")

    def step(key, state, actions):
        keys = jax.random.split(key, actions.shape[0])
        out = jax.vmap(env.step, in_axes=(0, 0, 0, None))(keys, state, actions, params)
        if len(out) == 6:  # gymnax >= 1.0: obs, state, reward, terminated, truncated, info
            obs, state, reward, terminated, truncated, _ = out
        else:  # gymnax 0.0.x: obs, state, reward, done, info (no truncation flag)
            obs, state, reward, terminated, _ = out
            truncated = jnp.zeros_like(terminated)
        return obs, state, reward, terminated, truncated

    def reset_state(key, n):
        return jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(key, n), params)[1]

    return jax_rollout(step, reset_state, num_envs, num_steps)


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
        notes={"scan_length": num_steps, "threads": devices_used},
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
    total = [0.0]

    def call():
        obs, reward, terminated, truncated, _ = envs.step(host_actions(rng, num_envs))
        total[0] += float(consume(obs, reward, terminated, truncated, np))

    return Runner(
        call=call,
        steps_per_call=num_envs,
        setup_seconds=setup,
        notes={
            "env": type(envs).__name__,
            "autoreset": str(envs.metadata.get("autoreset_mode")),
            "threads": 1,
        },
        close=envs.close,
    )


def envpool_runner(num_envs: int, threads: int) -> Runner:
    """EnvPool's CartPole-v1 (synchronous: each call steps all envs) on ``threads`` threads,
    one step a call."""
    try:
        import envpool
    except ImportError as e:
        raise Unavailable(f"envpool is not installed ({e})") from None
    start = time.perf_counter()
    envs = envpool.make(
        "CartPole-v1", env_type="gymnasium", num_envs=num_envs, seed=0, num_threads=threads
    )
    envs.reset()
    setup = time.perf_counter() - start
    rng = np.random.default_rng(0)
    total = [0.0]

    def call():
        obs, reward, terminated, truncated, _ = envs.step(host_actions(rng, num_envs))
        total[0] += float(consume(obs, reward, terminated, truncated, np))

    spec = envs.spec.config
    return Runner(
        call=call,
        steps_per_call=num_envs,
        setup_seconds=setup,
        notes={"threads": getattr(spec, "num_threads", threads)},
        close=envs.close,
    )


def make_runner(name: str, num_envs: int, cores: int) -> Runner:
    """Contender ``name`` at ``num_envs`` envs; ``cores`` is how many the process may use (the
    JAX contenders use every JAX device, EnvPool that many threads, Gymnasium one thread)."""
    if name == "jaxcart":
        return jax_runner(jaxcart_random_rollout, num_envs)
    if name == "gymnax":
        return jax_runner(gymnax_random_rollout, num_envs)
    if name == "gymnasium-vector":
        return gymnasium_runner(num_envs, "vector_entry_point")
    if name == "gymnasium-sync":
        return gymnasium_runner(num_envs, "sync")
    if name == "envpool":
        return envpool_runner(num_envs, cores)
    raise ValueError(name)

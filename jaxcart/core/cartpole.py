"""CartPole-v1 as pure JAX functions, numerically matching Gymnasium's classic-control CartPole.

The ground truth is ``gymnasium/envs/classic_control/cartpole.py`` wrapped in ``TimeLimit``
(what ``gymnasium.make("CartPole-v1")`` returns):

- reward +1 on every step, the terminating one included (Sutton-Barto mode: 0, and -1 on the
  terminating step);
- ``terminated`` when ``|x| > x_threshold`` or ``|theta| > theta_threshold_radians`` after
  the step;
- ``truncated`` when the episode's step count reaches ``max_episode_steps``; both flags are
  true when the pole falls on that last step.

:func:`step` resets finished episodes on the same step (the convention of vectorised
training loops): the returned observation is the first of the next episode and the last
observation of the finished one is kept in ``info["final_obs"]``. :func:`step_env` is the
transition alone, without the reset.

Everything is float32 unless JAX's x64 mode is on, in which case it is float64.

Actions: ``1`` pushes right, anything else pushes left. The functional env does not check
actions (a check inside a compiled program could not raise); the Gymnasium adapter does.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxcart.core import pytree
from jaxcart.core.pytree import float_dtype

Array = jax.Array


@pytree.dataclass
class EnvParams:
    """Constants of CartPole-v1, named and valued as in Gymnasium's ``CartPoleEnv``.

    Derived quantities (total mass, pole mass times length) are computed in :func:`step_env`
    from these, so changing ``masspole`` or ``length`` changes the dynamics consistently.
    The float fields that enter the step as numbers may differ between runs
    (:func:`~jaxcart.core.pytree.per_run_field`: ``--sweep env.NAME``, ``--randomize``); the
    others shape the program (the integrator, the episode limit, the reward mode) or are
    drawn on the host (the reset bounds), so they are one value for a whole run.
    """

    gravity: float = pytree.per_run_field(9.8)
    masscart: float = pytree.per_run_field(1.0)
    masspole: float = pytree.per_run_field(0.1)
    length: float = pytree.per_run_field(0.5)  # half the pole's length, as in Gymnasium
    force_mag: float = pytree.per_run_field(10.0)
    tau: float = pytree.per_run_field(0.02)  # seconds between state updates
    x_threshold: float = pytree.per_run_field(2.4)
    theta_threshold_radians: float = pytree.per_run_field(12 * 2 * math.pi / 360)
    max_episode_steps: int = 500
    sutton_barto_reward: bool = False
    reset_low: float = -0.05
    reset_high: float = 0.05
    # A string selects code, so it is static: changing it recompiles.
    kinematics_integrator: str = pytree.static_field("euler")

    def __post_init__(self) -> None:
        if self.kinematics_integrator not in ("euler", "semi-implicit"):
            raise ValueError(
                f"kinematics_integrator must be 'euler' or 'semi-implicit', "
                f"got {self.kinematics_integrator!r}"
            )


@pytree.dataclass
class EnvState:
    """Physical state of one cart-pole plus the number of steps taken in this episode.

    All fields are scalars for one env; ``jax.vmap`` adds leading batch axes.
    """

    x: Array
    x_dot: Array
    theta: Array
    theta_dot: Array
    step_count: Array  # int32


def get_obs(state: EnvState) -> Array:
    """Observation ``[x, x_dot, theta, theta_dot]``, shape ``(4,)`` (plus batch axes)."""
    return jnp.stack([state.x, state.x_dot, state.theta, state.theta_dot], axis=-1)


def state_from_obs(obs: Any, step_count: Any = 0) -> EnvState:
    """Builds an :class:`EnvState` from an array ``(..., 4)``, e.g. Gymnasium's ``env.state``."""
    obs = jnp.asarray(obs, dtype=float_dtype())
    return EnvState(
        x=obs[..., 0],
        x_dot=obs[..., 1],
        theta=obs[..., 2],
        theta_dot=obs[..., 3],
        step_count=jnp.broadcast_to(jnp.asarray(step_count, jnp.int32), obs.shape[:-1]),
    )


def reset(key: Array, params: EnvParams) -> tuple[Array, EnvState]:
    """Starts an episode: each state variable uniform in ``[reset_low, reset_high)``.

    Returns:
        ``(obs, state)`` with ``obs`` of shape ``(4,)``.
    """
    obs = jax.random.uniform(
        key, (4,), dtype=float_dtype(), minval=params.reset_low, maxval=params.reset_high
    )
    return obs, state_from_obs(obs)


def host_reset(
    rng: np.random.Generator, params: EnvParams, num_envs: int, dtype: np.dtype
) -> tuple[np.ndarray, EnvState]:
    """``num_envs`` first episodes drawn on the host from ``rng`` (no program to compile): the
    observations ``[num_envs, 4]`` (each state variable uniform in ``[reset_low,
    reset_high)``, in ``dtype``) and their states (fields ``[num_envs]``, step counters 0)."""
    obs = rng.uniform(params.reset_low, params.reset_high, (num_envs, 4)).astype(dtype)
    steps = np.zeros((num_envs,), np.int32)
    return obs, EnvState(obs[:, 0], obs[:, 1], obs[:, 2], obs[:, 3], steps)


def gymnasium_step(c: Any, state: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``CartPoleEnv.step`` for every state at once, with the constants of ``c`` (a
    ``CartPoleEnv``, or its attributes with some one value per policy ``[P, 1]``): float64
    ``state [4, ...]`` (rows x, x_dot, theta, theta_dot) and actions ``[...]`` -> ``(next state
    [4, ...], terminated [...])``.

    :func:`transition` in NumPy: every line is ``CartPoleEnv.step``'s, in its order of
    operations, and NumPy's element-wise float64 arithmetic rounds each operation as on the
    single env's scalars, so each next state is bit-identical to the single env's.
    """
    trig = lambda theta: (np.sin(theta), np.cos(theta))
    x, x_dot, theta, theta_dot = transition(*state, actions, c, trig, np)
    return np.stack([x, x_dot, theta, theta_dot]), out_of_bounds(x, theta, c)


PHYSICS = (*pytree.per_run_names(EnvParams()), "kinematics_integrator")
"""The ``CartPoleEnv`` attributes an :class:`EnvParams` sets (same names)."""


def make_cartpole(
    params: EnvParams | None = None, env_id: str = "CartPole-v1", **kwargs: Any
) -> Any:
    """``gymnasium.make(env_id, **kwargs)`` with ``params``' physics, episode limit and
    reward mode (default params: exactly ``gymnasium.make(env_id)``).

    The reset bounds are not an attribute of Gymnasium's env: pass :func:`reset_options`
    to ``env.reset``.
    """
    import gymnasium as gym

    params = params or EnvParams()
    default = EnvParams()
    if params.max_episode_steps != default.max_episode_steps:
        kwargs.setdefault("max_episode_steps", int(params.max_episode_steps))
    if params.sutton_barto_reward:
        kwargs.setdefault("sutton_barto_reward", True)
    env = gym.make(env_id, **kwargs)
    if params == default:
        return env
    cartpole = env.unwrapped
    for name in PHYSICS:
        value = getattr(params, name)
        setattr(cartpole, name, value if isinstance(value, str) else float(value))
    # what CartPoleEnv.__init__ derives from them, recomputed in its own order of operations
    cartpole.total_mass = cartpole.masspole + cartpole.masscart
    cartpole.polemass_length = cartpole.masspole * cartpole.length
    cartpole.observation_space = observation_space(params)
    return env


def reset_options(params: EnvParams | None = None) -> dict | None:
    """``env.reset``'s options for ``params``' reset bounds (None for Gymnasium's own)."""
    params = params or EnvParams()
    default = EnvParams()
    if (params.reset_low, params.reset_high) == (default.reset_low, default.reset_high):
        return None
    return {"low": float(params.reset_low), "high": float(params.reset_high)}


def gymnasium_grid(
    env_id: str, params: EnvParams | None, shape: tuple[int, int], seed: int, stack: Any
) -> tuple[np.ndarray, Callable, int]:
    """Gymnasium's own ``CartPoleEnv`` (``gymnasium.make(env_id)`` with ``params``' physics:
    :func:`make_cartpole`, entered in the ``contextlib.ExitStack``
    ``stack``) for a grid of episodes ``shape = (P, E)`` in float64 NumPy arrays, stepped at
    once by :func:`gymnasium_step`: the env's :attr:`~jaxcart.core.envs.Env.gymnasium_grid`.
    Episode ``e``'s start is ``env.reset(seed=seed + e)``'s, drawn by Gymnasium; a continuous
    field of ``params`` may hold one value per policy ``[P]`` (the masses Gymnasium derives
    from them recomputed as its constructor does). Each return is bit-identical to stepping
    one ``gymnasium.make(env_id)`` per episode (the same start states, float64 dynamics,
    float32 observations).

    Returns:
        ``(obs [P, E, 4] float32, step, num_actions)``, ``step`` as
        :data:`jaxcart.run.greedy.Step`.
    """
    from types import SimpleNamespace

    static, per_run = (None, {}) if params is None else pytree.split_per_run(params)
    env = stack.enter_context(make_cartpole(static, env_id))
    c = SimpleNamespace(**vars(env.unwrapped))  # the masses it derives: see transition
    for name, values in per_run.items():
        setattr(c, name, np.asarray(values, np.float64)[:, None])  # [P, 1]: over the episodes
    limit = env.spec.max_episode_steps
    starts, first_obs = [], []
    for e in range(shape[1]):
        first_obs.append(env.reset(seed=seed + e, options=reset_options(static))[0])
        starts.append(np.array(env.unwrapped.state, dtype=np.float64))
    state = np.broadcast_to(np.stack(starts, axis=1)[:, None, :], (4, *shape)).copy()
    obs = np.broadcast_to(np.stack(first_obs), (*shape, 4)).copy()  # rows contiguous
    steps = 0

    def step(actions: np.ndarray, alive: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        nonlocal steps
        stepped, terminated = gymnasium_step(c, state, actions)
        steps += 1
        # Only the running episodes move on; the finished keep their state and observation.
        np.copyto(state, stepped, where=alive)
        np.copyto(obs, np.moveaxis(stepped, 0, -1), casting="same_kind", where=alive[..., None])
        if getattr(c, "_sutton_barto_reward", False):
            reward = np.where(terminated, -1.0, 0.0)
        else:
            reward = np.ones(shape)
        truncated = limit is not None and steps >= limit
        return reward, terminated | truncated  # TimeLimit: every running episode truncated

    return obs, step, int(env.action_space.n)


def sin_and_cos(theta: Array) -> tuple[Array, Array]:
    """``(jnp.sin(theta), jnp.cos(theta))``, the pair training's :func:`step_env` uses."""
    costheta = jnp.cos(theta)
    sintheta = jnp.sin(theta)
    return sintheta, costheta


def step_env(
    state: EnvState,
    action: Array,
    params: EnvParams,
    trig: Callable[[Array], tuple[Array, Array]] = sin_and_cos,
) -> tuple[Array, EnvState, Array, Array, Array]:
    """One physics step without autoreset, in Gymnasium's order of operations.

    ``trig(theta)`` computes ``(sin, cos)`` of the pole angle; it must return exactly
    ``jnp.sin(theta)`` and ``jnp.cos(theta)``, and may change only how XLA computes them. The
    Gymnasium vector adapter passes :func:`jaxcart.gym.kernels.sin_cos_once`, which makes
    XLA:CPU evaluate them once per env instead of once per fusion that uses them. Training
    keeps :func:`sin_and_cos`: the adapter's way changes which multiply-adds XLA fuses into
    FMAs in training's programs, so its numbers would no longer be bit-identical
    (``benchmarks/RESULTS.md``, env throughput).

    Args:
        state: current state (scalar fields).
        action: int scalar; ``1`` pushes right, anything else left.
        params: environment constants.
        trig: ``theta -> (sin(theta), cos(theta))``.

    Returns:
        ``(obs, state, reward, terminated, truncated)``; obs ``(4,)``, the rest scalars.
    """
    x, x_dot, theta, theta_dot = transition(
        state.x, state.x_dot, state.theta, state.theta_dot, action, params, trig
    )
    step_count = state.step_count + 1
    new_state = EnvState(x=x, x_dot=x_dot, theta=theta, theta_dot=theta_dot, step_count=step_count)

    terminated = out_of_bounds(x, theta, params)
    # TimeLimit truncates on the step that reaches the limit, whether or not the pole fell.
    truncated = step_count >= params.max_episode_steps
    dtype = x.dtype
    # Gymnasium pays +1 on every step, the terminating one included; Sutton-Barto pays 0 and
    # -1 on the terminating step.
    reward = jnp.where(
        params.sutton_barto_reward,
        jnp.where(terminated, -1.0, 0.0),
        1.0,
    ).astype(dtype)
    return get_obs(new_state), new_state, reward, terminated, truncated


def transition(
    x: Any, x_dot: Any, theta: Any, theta_dot: Any, action: Any, p: Any, trig: Callable, xp=jnp
) -> tuple[Any, Any, Any, Any]:
    """The state after one push, ``CartPoleEnv.step``'s physics line for line in its order of
    operations, for JAX (``xp=jnp``: :func:`step_env`) or NumPy arrays (``xp=np``:
    :func:`gymnasium_step`).

    Args:
        x, x_dot, theta, theta_dot: the state variables (any matching shapes).
        action: ``1`` pushes right, anything else left.
        p: CartPole's constants as attributes (an :class:`EnvParams` or a ``CartPoleEnv``);
            the total mass and pole mass times length are derived here from them, in the
            order of operations of ``CartPoleEnv.__init__``.
        trig: ``theta -> (sin(theta), cos(theta))``.
    """
    total_mass = p.masspole + p.masscart
    polemass_length = p.masspole * p.length
    force = xp.where(action == 1, p.force_mag, -p.force_mag)
    sintheta, costheta = trig(theta)

    temp = (force + polemass_length * xp.square(theta_dot) * sintheta) / total_mass
    thetaacc = (p.gravity * sintheta - costheta * temp) / (
        p.length * (4.0 / 3.0 - p.masspole * xp.square(costheta) / total_mass)
    )
    xacc = temp - polemass_length * thetaacc * costheta / total_mass

    tau = p.tau
    if p.kinematics_integrator == "euler":
        x = x + tau * x_dot
        x_dot = x_dot + tau * xacc
        theta = theta + tau * theta_dot
        theta_dot = theta_dot + tau * thetaacc
    else:  # semi-implicit Euler: velocities first, then positions from the new velocities
        x_dot = x_dot + tau * xacc
        x = x + tau * x_dot
        theta_dot = theta_dot + tau * thetaacc
        theta = theta + tau * theta_dot
    return x, x_dot, theta, theta_dot


def out_of_bounds(x: Any, theta: Any, p: Any) -> Any:
    """CartPole's termination: the cart or the pole past its threshold (``p``'s)."""
    return (
        (x < -p.x_threshold)
        | (x > p.x_threshold)
        | (theta < -p.theta_threshold_radians)
        | (theta > p.theta_threshold_radians)
    )


def step(
    key: Array, state: EnvState, action: Array, params: EnvParams
) -> tuple[Array, EnvState, Array, Array, Array, dict[str, Array]]:
    """One step with same-step autoreset.

    When the episode ends (terminated or truncated), the returned ``obs``/``state`` are those of
    a fresh episode drawn with ``key``, and the episode's last observation is in
    ``info["final_obs"]``. When it does not end, ``info["final_obs"]`` equals ``obs``.

    Returns:
        ``(obs, state, reward, terminated, truncated, info)``; obs and ``final_obs`` ``(4,)``.
    """
    final_obs, next_state, reward, terminated, truncated = step_env(state, action, params)
    reset_obs, reset_state = reset(key, params)
    done = terminated | truncated
    obs, state_out = pytree.where(done, (reset_obs, reset_state), (final_obs, next_state))
    return obs, state_out, reward, terminated, truncated, {"final_obs": final_obs}


def _fmix32(x: Array) -> Array:
    """MurmurHash3's 32-bit finaliser: a bijection with full avalanche."""
    x = x ^ (x >> 16)
    x = x * jnp.uint32(0x85EBCA6B)
    x = x ^ (x >> 13)
    x = x * jnp.uint32(0xC2B2AE35)
    return x ^ (x >> 16)


def hash_uniform(
    key: Array, shape: tuple[int, ...], dtype=None, minval: float = 0.0, maxval: float = 1.0
) -> Array:
    """Uniform numbers in ``[minval, maxval)`` from a keyed counter hash (the env's reset noise).

    Plain version: ``jax.random.uniform`` (Threefry). Why: drawing 4 Threefry uniforms per env
    and step cost about three times CartPole's physics, so the env was RNG-bound; with the hash
    the draw is under a quarter of an env step (``benchmarks/RESULTS.md``, env throughput;
    ``benchmarks/results/env_step_ablation.md``, ``fixed-reset``). Same distribution, other
    numbers: every run's reset states depend on it, so it cannot change without changing them.

    Element ``i`` is ``fmix32(fmix32(i * golden + k0) ^ k1)`` for the key's two words
    ``(k0, k1)``: counter-based like Threefry, with about 12 integer operations per number
    instead of ~80 (``tests/test_env_parity.py`` checks uniformity and independence). float32
    gets 24 random bits, float64 53 (two hashes); the default dtype is JAX's default float.
    """
    dtype = dtype or jax.dtypes.canonicalize_dtype(jnp.float64)
    words = jax.random.key_data(key) if jnp.issubdtype(key.dtype, jax.dtypes.prng_key) else key
    words = words.astype(jnp.uint32)
    size = math.prod(shape)
    counter = jnp.arange(size, dtype=jnp.uint32)

    def bits(c: Array) -> Array:
        return _fmix32(_fmix32(c * jnp.uint32(0x9E3779B9) + words[0]) ^ words[1])

    if jnp.dtype(dtype) == jnp.float64:
        hi = (bits(2 * counter) >> 6).astype(dtype)  # 26 bits
        lo = (bits(2 * counter + 1) >> 5).astype(dtype)  # 27 bits
        unit = (hi * 2.0**27 + lo) * 2.0**-53
    else:
        unit = (bits(counter) >> 8).astype(dtype) * jnp.asarray(2.0**-24, dtype)
    return (minval + (maxval - minval) * unit).reshape(shape).astype(dtype)


def step_batch(
    key: Array, state: EnvState, action: Array, params: EnvParams
) -> tuple[Array, EnvState, Array, Array, Array, dict[str, Array]]:
    """:func:`step` for a batch of envs (state fields ``[N]``, actions ``[N]``) with one key.

    Same semantics as ``jax.vmap(step)`` with per-env keys, but the reset states of the whole
    batch come from :func:`hash_uniform` keyed by ``key`` (a counter hash:
    on CPU, 4 Threefry uniforms per env and step cost about three times the physics). The
    physics is elementwise, so no vmap is needed.

    Returns:
        ``(obs [N, 4], state, reward [N], terminated [N], truncated [N], {"final_obs": [N, 4]})``.
    """
    final_obs, next_state, reward, terminated, truncated = step_env(state, action, params)
    done = terminated | truncated
    noise = hash_uniform(
        key, (done.shape[0], 4), final_obs.dtype, params.reset_low, params.reset_high
    )
    obs, state_out = pytree.where(done, (noise, state_from_obs(noise)), (final_obs, next_state))
    return obs, state_out, reward, terminated, truncated, {"final_obs": final_obs}


def observation_space(params: EnvParams | None = None):
    """Gymnasium's ``Box`` for CartPole observations (twice the termination thresholds)."""
    from gymnasium import spaces

    p = params or EnvParams()
    high = np.array(
        [p.x_threshold * 2, np.inf, p.theta_threshold_radians * 2, np.inf], dtype=np.float32
    )
    return spaces.Box(-high, high, dtype=np.float32)


def action_space(params: EnvParams | None = None):
    """Gymnasium's ``Discrete(2)``: 0 pushes the cart left, 1 pushes it right."""
    from gymnasium import spaces

    return spaces.Discrete(2)


def draw_frame(state: Any, params: EnvParams | None = None) -> np.ndarray:
    """One ``(400, 600, 3)`` uint8 frame of ``state = (x, x_dot, theta, theta_dot)``, drawn with
    Pillow in the geometry and colours of Gymnasium's CartPole renderer (no anti-aliasing), for
    the pole length and track of ``params`` (default CartPole-v1's): the env's frames where
    Gymnasium's renderer (pygame) is missing (:attr:`jaxcart.core.envs.Env.draw_frame`)."""
    from PIL import Image, ImageDraw

    params = params or EnvParams()
    width, height = 600, 400  # Gymnasium's canvas
    scale = width / (2 * float(params.x_threshold))
    pole_width, pole_len = 10.0, scale * 2 * float(params.length)
    cart_width, cart_height = 50.0, 30.0
    axle_offset = cart_height / 4.0
    cart_x = float(state[0]) * scale + width / 2.0
    cart_y = 100.0  # top of the cart, measured from the bottom like Gymnasium (flipped below)
    theta = float(state[2])

    def to_image(x: float, y: float) -> tuple[float, float]:
        return x, height - 1 - y  # pygame.transform.flip maps row y to H - 1 - y

    image = Image.new("RGB", (width, height), (255, 255, 255))
    draw = ImageDraw.Draw(image)
    left, right, top, bottom = -cart_width / 2, cart_width / 2, cart_height / 2, -cart_height / 2
    cart = [(left, bottom), (left, top), (right, top), (right, bottom)]
    draw.polygon([to_image(cart_x + x, cart_y + y) for x, y in cart], fill=(0, 0, 0))

    left, right = -pole_width / 2, pole_width / 2
    top, bottom = pole_len - pole_width / 2, -pole_width / 2
    # pygame's Vector2.rotate_rad(-theta) in y-up coordinates: the pole leans right for theta > 0.
    cos, sin = math.cos(-theta), math.sin(-theta)
    pole = [
        to_image(cart_x + x * cos - y * sin, cart_y + axle_offset + x * sin + y * cos)
        for x, y in [(left, bottom), (left, top), (right, top), (right, bottom)]
    ]
    draw.polygon(pole, fill=(202, 152, 101))

    ax, ay = to_image(int(cart_x), int(cart_y + axle_offset))
    r = int(pole_width / 2)
    draw.ellipse([ax - r, ay - r, ax + r, ay + r], fill=(129, 132, 203))
    draw.line([to_image(0, cart_y), to_image(width, cart_y)], fill=(0, 0, 0))
    return np.asarray(image)

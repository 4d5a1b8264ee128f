"""The compiled programs behind jaxcart's Gymnasium front-ends, and the vector env's packed rows.

Each ``step`` of :class:`~jaxcart.gym.adapter.JaxCartPoleEnv` and
:class:`~jaxcart.gym.adapter.JaxCartPoleVectorEnv` is one call of a program compiled ahead of
time: the state stays on the JAX device as one array, donated to the call (XLA writes the new
state over the old), and comes back to NumPy in one copy. A program is compiled once per (size,
autoreset mode, precision, non-float parameters) and shared by every env instance; the float
parameters are an argument.

Only NumPy is imported with this module; JAX loads when a program is first compiled.
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING, Any

import numpy as np
from gymnasium.vector import AutoresetMode

if TYPE_CHECKING:
    from jaxcart.core.cartpole import EnvParams


def precision(x64: bool):
    """JAX's x64 mode set to ``x64`` for the adapter's own calls (the global setting is kept)."""
    import jax

    return jax.enable_x64(x64)


def make_params(
    params: EnvParams | None, sutton_barto_reward: bool | None, max_episode_steps: int | None
) -> EnvParams:
    """``params`` (default: CartPole-v1's) with the explicitly given options applied, and every
    leaf a Python scalar, so that :func:`compile_key` can key the cache of compiled programs."""
    import jax

    from jaxcart.core import cartpole

    params = cartpole.EnvParams() if params is None else params
    if sutton_barto_reward is not None:
        params = params.replace(sutton_barto_reward=bool(sutton_barto_reward))
    if max_episode_steps is not None:
        params = params.replace(max_episode_steps=int(max_episode_steps))
    return jax.tree.map(lambda v: v.item() if hasattr(v, "item") else v, params)


# The float parameters go to the compiled programs as one runtime array, (low, high) of the
# reset draws last, rather than as constants: XLA would fold constants, e.g. turn
# ``x / total_mass`` into ``x * (1 / total_mass)``, which rounds differently from Gymnasium's
# division. The programs are compiled and cached for the rest of the parameters only.
FLOAT_PARAMS = (
    "gravity",
    "masscart",
    "masspole",
    "length",
    "force_mag",
    "tau",
    "x_threshold",
    "theta_threshold_radians",
    "reset_low",
    "reset_high",
)


def float_values(params: EnvParams, low: float, high: float) -> np.ndarray:
    """The float parameters as an array ``[len(FLOAT_PARAMS)]``, reset bounds ``(low, high)``."""
    values = [getattr(params, name) for name in FLOAT_PARAMS[:-2]]
    return np.array([*values, low, high], dtype=np.float64)


def compile_key(params: EnvParams) -> EnvParams:
    """``params`` without its float values (they travel at run time): the compilation key."""
    return params.replace(**{name: 0.0 for name in FLOAT_PARAMS})


def with_floats(params: EnvParams, values) -> EnvParams:
    """``params`` with the float parameters taken from ``values`` (traced)."""
    return params.replace(**{name: values[i] for i, name in enumerate(FLOAT_PARAMS)})


# The compiled programs. Their state argument is donated: XLA writes the new state into the
# old one's buffer.


def single_step(packed, action, floats, params: EnvParams):
    """One physics step of one env: ``packed`` is ``[x, x_dot, theta, theta_dot, terminated]``
    (``(5,)``; the flag is ignored on input) and so is the result; ``floats``: the float
    parameters (see :func:`float_values`)."""
    import jax.numpy as jnp

    from jaxcart.core import cartpole

    state = cartpole.state_from_obs(packed[:4])
    params = with_floats(params, floats)
    obs, _, _, terminated, _ = cartpole.step_env(state, action, params)
    return jnp.append(obs, terminated.astype(obs.dtype))


# The vector env's device state is one array ``[rows, num_envs]`` in the env's float dtype,
# which each step donates and gets back whole, and which comes to the host in one copy: one
# buffer in, one buffer out, one transfer. Its rows:
STATE_ROWS = slice(0, 4)  # x, x_dot, theta, theta_dot after the last step (and its reset,
# except in SAME_STEP, where an env that ended restarts from its START_ROWS on the next step)
STEP_COUNT = 4  # steps taken in the current episode (exact in float32 up to 2**24)
REWARD = 5  # of the last step
ENDED = 6  # how the last step ended the episode: terminated + 2 * truncated (0: it did not)
START_ROWS = slice(7, 11)  # SAME_STEP only: a fresh start state, used where the episode ended
# Few rows on purpose: XLA:CPU fuses a concatenation of at most 8 operands only, and the
# step's output is one (4 state rows, step count, reward, ended, start rows).


def start_states(key, floats, num_envs: int, dtype):
    """Fresh start states ``[4, num_envs]``, uniform in ``[low, high)`` (the last two floats).

    Drawn with jaxcart's counter hash (:func:`jaxcart.core.cartpole.hash_uniform`) in float32 (one
    hash per number; the values are then exact in float64 too); Threefry would cost more than
    the physics.
    """
    import jax.numpy as jnp

    from jaxcart.core.cartpole import hash_uniform

    low, high = floats[-2:].astype(jnp.float32)
    return hash_uniform(key, (4, num_envs), jnp.float32, low, high).astype(dtype)


def vector_reset(rows, key, floats, mask):
    """Starts new episodes where ``mask`` (bool ``[num_envs]``): fresh states, every other row
    of those envs zero."""
    import jax.numpy as jnp

    fresh = start_states(key, floats, rows.shape[1], rows.dtype)
    fresh = jnp.concatenate([fresh, jnp.zeros((rows.shape[0] - 4, rows.shape[1]), rows.dtype)])
    return jnp.where(mask, fresh, rows)


def sin_cos_once(theta):
    """``(jnp.sin(theta), jnp.cos(theta))``, bit for bit, evaluated once per element by XLA:CPU.

    XLA:CPU counts sin and cos as cheap and recomputes them in every fusion that uses them: the
    vector step held four float64 evaluations per env (two sin, two cos), each a call into libm.
    Here they leave as one complex number ``cos + i sin`` divided by ``1 + 0i``, a division
    (which XLA will not duplicate) by a one it cannot fold (``1 + 0 * theta``): one fusion
    computes both (one ``sincos`` call) and the others read them. The division is exact:
    ``(cos + i sin) / (1 + 0i)`` is ``cos + i sin`` in every formula XLA uses for it, as the
    products are by 1 and 0 and ``cos`` is never zero; a non-finite theta gives NaNs either way.
    """
    import jax.numpy as jnp
    from jax import lax

    one = 1 + 0 * theta
    z = lax.complex(jnp.cos(theta), jnp.sin(theta)) / lax.complex(one, jnp.zeros_like(theta))
    return jnp.imag(z), jnp.real(z)


def vector_step(rows, spare, inputs, floats, params: EnvParams, mode: AutoresetMode):
    """Steps every env, resetting as ``mode`` says; ``rows`` in, ``rows`` out (see the layout above).
    ``inputs``: uint32 ``[num_envs + 2]``, the actions then this step's key (one transfer).
    ``spare``: a buffer like ``rows`` (donated, never read), into which XLA writes the result.

    NEXT_STEP: the envs whose episode ended on the previous step start a new one instead of
    stepping (reward 0, not terminated or truncated), as Gymnasium's ``CartPoleVectorEnv``.
    SAME_STEP: the envs whose episode ended on the previous step step from the start state
    drawn then (the host returned it as their observation), and every env gets a fresh start
    state in case its episode ends now; the state rows keep the stepped state, the host's
    ``final_obs``. DISABLED: no reset.

    The physics is :func:`jaxcart.core.cartpole.step_env`'s, with sin and cos evaluated once per env
    (:func:`sin_cos_once`). The output is stacked row by row (each row its own select): XLA:CPU
    emits a fused concatenation of whole rows as vector code, where a select over a stacked
    ``[4, num_envs]`` block came out as scalar code.
    """
    import jax.numpy as jnp

    from jaxcart.core import cartpole

    del spare
    actions, key = inputs[:-2], inputs[-2:]
    ended = rows[ENDED] != 0  # on the previous step
    start, steps = list(rows[STATE_ROWS]), rows[STEP_COUNT].astype(jnp.int32)
    if mode is AutoresetMode.SAME_STEP:
        start = [jnp.where(ended, s, x) for s, x in zip(rows[START_ROWS], start)]
        steps = jnp.where(ended, 0, steps)
    state = cartpole.EnvState(*start, step_count=steps)
    params = with_floats(params, floats)
    _, state, reward, terminated, truncated = cartpole.step_env(
        state, actions, params, sin_cos_once
    )
    new = [state.x, state.x_dot, state.theta, state.theta_dot]
    steps = state.step_count
    fresh = start_states(key, floats, rows.shape[1], rows.dtype)
    if mode is AutoresetMode.NEXT_STEP:
        new = [jnp.where(ended, f, x) for f, x in zip(fresh, new)]
        steps = jnp.where(ended, 0, steps)
        reward = jnp.where(ended, jnp.zeros_like(reward), reward)
        terminated, truncated = terminated & ~ended, truncated & ~ended
    code = terminated.astype(rows.dtype) + 2 * truncated.astype(rows.dtype)
    out = [*new, steps, reward, code]
    if mode is AutoresetMode.SAME_STEP:
        out.extend(fresh)
    return jnp.stack([r.astype(rows.dtype) for r in out])


def _compile(fn, x64: bool, *shapes: tuple, **jit_options):
    """``fn`` jitted with ``jit_options`` and compiled ahead of time, in precision ``x64``, for
    arguments of ``shapes``: ``(shape, dtype)`` pairs, dtype ``None`` for the float dtype."""
    import jax
    import jax.numpy as jnp

    with precision(x64):
        float_dtype = jnp.float64 if x64 else jnp.float32
        specs = [jax.ShapeDtypeStruct(shape, dtype or float_dtype) for shape, dtype in shapes]
        return jax.jit(fn, **jit_options).lower(*specs).compile()


FLOATS = ((len(FLOAT_PARAMS),), None)  # the float parameters' argument (see float_values)


def rows_shape(num_envs: int, mode: AutoresetMode) -> tuple[int, int]:
    """The vector env's device state: ``[rows, num_envs]`` in the env's float dtype."""
    return (11 if mode is AutoresetMode.SAME_STEP else 7, num_envs)


@functools.cache
def compiled_single_step(params: EnvParams, x64: bool):
    """:func:`single_step` for ``params`` (a :func:`compile_key`), compiled ahead of time in
    that precision (the state donated)."""
    step = functools.partial(single_step, params=params)
    return _compile(step, x64, ((5,), None), ((), np.int32), FLOATS, donate_argnums=0)


@functools.cache
def compiled_vector_reset(num_envs: int, mode: AutoresetMode, x64: bool):
    """:func:`vector_reset` compiled ahead of time (the rows donated)."""
    rows, key, mask = (rows_shape(num_envs, mode), None), ((2,), np.uint32), ((num_envs,), bool)
    return _compile(vector_reset, x64, rows, key, FLOATS, mask, donate_argnums=0)


@functools.cache
def compiled_vector_step(params: EnvParams, num_envs: int, mode: AutoresetMode, x64: bool):
    """:func:`vector_step` for ``params`` (a :func:`compile_key`) and ``mode``, compiled ahead
    of time, called as ``step(rows, spare, inputs, floats)``: the new rows are written into the
    buffer of ``spare`` (donated; the rows of the step before), not over ``rows``. Writing over
    ``rows`` would cost a copy of the whole state per step, as XLA cannot compute the new rows
    in place (each row reads others)."""
    step = functools.partial(vector_step, params=params, mode=mode)
    rows, inputs = (rows_shape(num_envs, mode), None), ((num_envs + 2,), np.uint32)
    return _compile(step, x64, rows, rows, inputs, FLOATS, donate_argnums=1, keep_unused=True)


def step_inputs(actions: np.ndarray, key: np.ndarray) -> np.ndarray:
    """:func:`vector_step`'s ``inputs``: uint32 ``[num_envs + 2]``, the actions ``[num_envs]``
    then the step's key ``[2]``."""
    inputs = np.empty(len(actions) + 2, dtype=np.uint32)
    inputs[:-2] = actions
    inputs[-2:] = key
    return inputs


def with_states(rows, states: Any, mode: AutoresetMode):
    """The device ``rows`` with the physical states set to ``states`` ``[4, num_envs]`` (read
    as float64); in ``SAME_STEP`` the start rows too, as they are the state where an episode
    has just ended. Call it in the rows' precision (:func:`precision`)."""
    states = np.asarray(states, dtype=np.float64)
    if states.shape != (4, rows.shape[1]):
        raise ValueError(f"state must have shape (4, {rows.shape[1]}), got {states.shape}")
    rows = rows.at[STATE_ROWS].set(states)
    if mode is AutoresetMode.SAME_STEP:
        rows = rows.at[START_ROWS].set(states)
    return rows


def observations(rows: np.ndarray) -> np.ndarray:
    """float32 ``[num_envs, 4]`` from the host copy of the rows: the transposed state rows, in
    Fortran order like the ``state.T.astype(np.float32)`` of Gymnasium's ``CartPoleVectorEnv``
    (a straight cast, several times cheaper than a transposing one)."""
    return rows[STATE_ROWS].T.astype(np.float32)

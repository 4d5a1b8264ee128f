"""Gymnasium front-ends for jaxcart's CartPole: a ``gymnasium.Env`` and a ``VectorEnv``.

``import jaxcart`` registers ``"jaxcart/CartPole-v1"`` with Gymnasium (as soon as Gymnasium is
imported, before or after jaxcart; see ``jaxcart/__init__.py``)::

    import gymnasium as gym
    import jaxcart

    env = gym.make("jaxcart/CartPole-v1")  # TimeLimit(500), like gym.make("CartPole-v1")
    envs = gym.make_vec("jaxcart/CartPole-v1", num_envs=8)  # JaxCartPoleVectorEnv, NEXT_STEP

:class:`JaxCartPoleEnv` is a drop-in for Gymnasium's ``CartPoleEnv``: the same spaces, the same
``reset(seed=...)`` start states (drawn from ``self.np_random`` exactly as Gymnasium draws
them), the same reward, ``terminated`` and ``{}`` info, ``truncated`` always ``False`` (the
``TimeLimit`` from registration truncates at 500 steps, as for ``CartPole-v1``), the same
``AssertionError`` for an invalid action, and a ``state`` attribute to read or inject the
physical state. The physics step is jaxcart's :func:`jaxcart.core.env.step_env`.

:class:`JaxCartPoleVectorEnv` is a drop-in for Gymnasium's ``CartPoleVectorEnv``, with a choice
of autoreset mode (``autoreset_mode=``: ``NEXT_STEP`` by default, as Gymnasium's; ``SAME_STEP``
with ``SyncVectorEnv``'s ``final_obs``/``final_info`` layout; ``DISABLED`` with
``reset(options={"reset_mask": mask})``).

Each ``step`` is one call of a program compiled ahead of time: the state stays on the JAX
device as one array, donated to the call (XLA writes the new state over the old), and comes
back to NumPy in one copy, from which the observations, rewards, flags and info dict are built
on the host. A program is compiled once per (size, autoreset mode, precision, non-float
parameters) and shared by every env instance; the float parameters are an argument.

Both step the physics in float64 by default (JAX's x64 mode switched on for the adapters' own
calls only), as Gymnasium's CartPole keeps its state in float64, so that whole episodes track
Gymnasium's; ``float64=False`` uses JAX's global precision (float32 unless x64 is on).

Only NumPy and Gymnasium are imported with this module; JAX loads when an env is built.
Rendering (``render_mode="rgb_array"``) draws with Gymnasium's own CartPole renderer and needs
pygame (``pip install "gymnasium[classic-control]"``); ``gym.make(..., render_mode="human")``
wraps it in Gymnasium's ``HumanRendering``.
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING, Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from jaxcart.gym import ENV_ID

if TYPE_CHECKING:
    from jaxcart.core.env import EnvParams


def _precision(x64: bool):
    """JAX's x64 mode set to ``x64`` for the adapter's own calls (the global setting is kept)."""
    import jax

    return jax.enable_x64(x64)


def _uses_x64(float64: bool) -> bool:
    """Whether an env built with ``float64`` computes in float64: always when asked, otherwise
    as JAX's global setting says."""
    import jax

    return bool(float64) or bool(jax.config.jax_enable_x64)


def _make_params(
    params: EnvParams | None, sutton_barto_reward: bool | None, max_episode_steps: int | None
) -> EnvParams:
    """``params`` (default: CartPole-v1's) with the explicitly given options applied, and every
    leaf a Python scalar, so that :func:`_compile_key` can key the cache of compiled programs."""
    import jax

    from jaxcart.core import env as cartpole

    params = cartpole.EnvParams() if params is None else params
    if sutton_barto_reward is not None:
        params = params.replace(sutton_barto_reward=bool(sutton_barto_reward))
    if max_episode_steps is not None:
        params = params.replace(max_episode_steps=int(max_episode_steps))
    return jax.tree.map(lambda v: v.item() if hasattr(v, "item") else v, params)


def _reset_bounds(options: dict | None, params: EnvParams) -> tuple[float, float]:
    """Gymnasium's ``options={"low": ..., "high": ...}`` reset bounds, else the params' ones."""
    from gymnasium.envs.classic_control import utils

    return utils.maybe_parse_reset_bounds(options, params.reset_low, params.reset_high)


# The float parameters go to the compiled programs as one runtime array, (low, high) of the
# reset draws last, rather than as constants: XLA would fold constants, e.g. turn
# ``x / total_mass`` into ``x * (1 / total_mass)``, which rounds differently from Gymnasium's
# division. The programs are compiled and cached for the rest of the parameters only.
_FLOAT_PARAMS = (
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


def _float_values(params: EnvParams, low: float, high: float) -> np.ndarray:
    """The float parameters as an array ``[len(_FLOAT_PARAMS)]``, reset bounds ``(low, high)``."""
    values = [getattr(params, name) for name in _FLOAT_PARAMS[:-2]]
    return np.array([*values, low, high], dtype=np.float64)


def _compile_key(params: EnvParams) -> EnvParams:
    """``params`` without its float values (they travel at run time): the compilation key."""
    return params.replace(**{name: 0.0 for name in _FLOAT_PARAMS})


def _with_floats(params: EnvParams, values) -> EnvParams:
    """``params`` with the float parameters taken from ``values`` (traced)."""
    return params.replace(**{name: values[i] for i, name in enumerate(_FLOAT_PARAMS)})


def _autoreset_mode(mode: AutoresetMode | str) -> AutoresetMode:
    """``mode`` as an :class:`AutoresetMode`; a clear error for anything that is not one."""
    if isinstance(mode, AutoresetMode):
        return mode
    valid = ", ".join(repr(m.value) for m in AutoresetMode)
    if not isinstance(mode, str):
        raise TypeError(
            f"autoreset_mode must be a gymnasium.vector.AutoresetMode or one of {valid}, "
            f"got {mode!r} ({type(mode).__name__})"
        )
    try:
        return AutoresetMode(mode)
    except ValueError:
        raise ValueError(
            f"autoreset_mode must be a gymnasium.vector.AutoresetMode or one of {valid}, "
            f"got {mode!r}"
        ) from None


# The compiled programs. Their state argument is donated: XLA writes the new state into the
# old one's buffer.


def _single_step(packed, action, floats, params: EnvParams):
    """One physics step of one env: ``packed`` is ``[x, x_dot, theta, theta_dot, terminated]``
    (``(5,)``; the flag is ignored on input) and so is the result; ``floats``: the float
    parameters (see :func:`_float_values`)."""
    import jax.numpy as jnp

    from jaxcart.core import env as cartpole

    state = cartpole.state_from_obs(packed[:4])
    params = _with_floats(params, floats)
    obs, _, _, terminated, _ = cartpole.step_env(state, action, params)
    return jnp.append(obs, terminated.astype(obs.dtype))


# The vector env's device state is one array ``[rows, num_envs]`` in the env's float dtype,
# which each step donates and gets back whole, and which comes to the host in one copy: one
# buffer in, one buffer out, one transfer. Its rows:
_STATE_ROWS = slice(0, 4)  # x, x_dot, theta, theta_dot after the last step (and its reset,
# except in SAME_STEP, where an env that ended restarts from its _START_ROWS on the next step)
_STEP_COUNT = 4  # steps taken in the current episode (exact in float32 up to 2**24)
_REWARD = 5  # of the last step
_ENDED = 6  # how the last step ended the episode: terminated + 2 * truncated (0: it did not)
_START_ROWS = slice(7, 11)  # SAME_STEP only: a fresh start state, used where the episode ended
# Few rows on purpose: XLA:CPU fuses a concatenation of at most 8 operands only, and the
# step's output is one (4 state rows, step count, reward, ended, start rows).
_KEY_BLOCK = 1024  # step keys drawn from np_random at a time


def _num_rows(mode: AutoresetMode) -> int:
    return 11 if mode is AutoresetMode.SAME_STEP else 7


def _start_states(key, floats, num_envs: int, dtype):
    """Fresh start states ``[4, num_envs]``, uniform in ``[low, high)`` (the last two floats).

    Drawn with jaxcart's counter hash (:func:`jaxcart.core.tricks.hash_uniform`) in float32 (one
    hash per number; the values are then exact in float64 too); Threefry would cost more than
    the physics.
    """
    import jax.numpy as jnp

    from jaxcart.core.tricks import hash_uniform

    low, high = floats[-2:].astype(jnp.float32)
    return hash_uniform(key, (4, num_envs), jnp.float32, low, high).astype(dtype)


def _vector_reset(rows, key, floats, mask):
    """Starts new episodes where ``mask`` (bool ``[num_envs]``): fresh states, every other row
    of those envs zero."""
    import jax.numpy as jnp

    fresh = _start_states(key, floats, rows.shape[1], rows.dtype)
    fresh = jnp.concatenate([fresh, jnp.zeros((rows.shape[0] - 4, rows.shape[1]), rows.dtype)])
    return jnp.where(mask, fresh, rows)


def _vector_step(rows, inputs, floats, params: EnvParams, mode: AutoresetMode):
    """Steps every env, resetting as ``mode`` says; ``rows`` in, ``rows`` out (see above).
    ``inputs``: uint32 ``[num_envs + 2]``, the actions then this step's key (one transfer).

    NEXT_STEP: the envs whose episode ended on the previous step start a new one instead of
    stepping (reward 0, not terminated or truncated), as Gymnasium's ``CartPoleVectorEnv``.
    SAME_STEP: the envs whose episode ended on the previous step step from the start state
    drawn then (the host returned it as their observation), and every env gets a fresh start
    state in case its episode ends now; the state rows keep the stepped state, the host's
    ``final_obs``. DISABLED: no reset.

    The stepped state is used once: XLA:CPU would compute it again (its sin and cos included)
    for a second use.
    """
    import jax.numpy as jnp

    from jaxcart.core import env as cartpole

    actions, key = inputs[:-2], inputs[-2:]
    ended = rows[_ENDED] != 0  # on the previous step
    start, steps = rows[_STATE_ROWS], rows[_STEP_COUNT].astype(jnp.int32)
    if mode is AutoresetMode.SAME_STEP:
        start = jnp.where(ended, rows[_START_ROWS], start)
        steps = jnp.where(ended, 0, steps)
    state = cartpole.EnvState(start[0], start[1], start[2], start[3], step_count=steps)
    params = _with_floats(params, floats)
    _, state, reward, terminated, truncated = cartpole.step_env(state, actions, params)
    new = jnp.stack([state.x, state.x_dot, state.theta, state.theta_dot])
    steps = state.step_count
    fresh = _start_states(key, floats, rows.shape[1], rows.dtype)
    if mode is AutoresetMode.NEXT_STEP:
        new = jnp.where(ended, fresh, new)
        steps = jnp.where(ended, 0, steps)
        reward = jnp.where(ended, jnp.zeros_like(reward), reward)
        terminated, truncated = terminated & ~ended, truncated & ~ended
    code = terminated.astype(rows.dtype) + 2 * truncated.astype(rows.dtype)
    out = [new, steps[None], reward[None], code[None]]
    if mode is AutoresetMode.SAME_STEP:
        out.append(fresh)
    return jnp.concatenate([r.astype(rows.dtype) for r in out])


def _float_spec(x64: bool):
    import jax
    import jax.numpy as jnp

    return jax.ShapeDtypeStruct((len(_FLOAT_PARAMS),), jnp.float64 if x64 else jnp.float32)


@functools.cache
def _compiled_single_step(params: EnvParams, x64: bool):
    """:func:`_single_step` for ``params`` (a :func:`_compile_key`), compiled ahead of time in
    that precision (the state donated)."""
    import jax
    import jax.numpy as jnp

    with _precision(x64):
        packed = jax.ShapeDtypeStruct((5,), jnp.float64 if x64 else jnp.float32)
        action = jax.ShapeDtypeStruct((), jnp.int32)
        fn = jax.jit(functools.partial(_single_step, params=params), donate_argnums=0)
        return fn.lower(packed, action, _float_spec(x64)).compile()


def _rows_spec(num_envs: int, mode: AutoresetMode, x64: bool):
    import jax
    import jax.numpy as jnp

    dtype = jnp.float64 if x64 else jnp.float32
    return jax.ShapeDtypeStruct((_num_rows(mode), num_envs), dtype)


@functools.cache
def _compiled_vector_reset(num_envs: int, mode: AutoresetMode, x64: bool):
    """:func:`_vector_reset` compiled ahead of time (the rows donated)."""
    import jax
    import jax.numpy as jnp

    with _precision(x64):
        key = jax.ShapeDtypeStruct((2,), jnp.uint32)
        mask = jax.ShapeDtypeStruct((num_envs,), jnp.bool_)
        fn = jax.jit(_vector_reset, donate_argnums=0)
        return fn.lower(_rows_spec(num_envs, mode, x64), key, _float_spec(x64), mask).compile()


@functools.cache
def _compiled_vector_step(params: EnvParams, num_envs: int, mode: AutoresetMode, x64: bool):
    """:func:`_vector_step` for ``params`` (a :func:`_compile_key`) and ``mode``, compiled ahead
    of time (the rows donated)."""
    import jax
    import jax.numpy as jnp

    with _precision(x64):
        rows = _rows_spec(num_envs, mode, x64)
        inputs = jax.ShapeDtypeStruct((num_envs + 2,), jnp.uint32)
        fn = jax.jit(functools.partial(_vector_step, params=params, mode=mode), donate_argnums=0)
        return fn.lower(rows, inputs, _float_spec(x64)).compile()


def _reset_mask(mask: Any, num_envs: int) -> np.ndarray:
    """``options["reset_mask"]`` checked as Gymnasium's ``SyncVectorEnv`` checks it."""
    if not isinstance(mask, np.ndarray):
        raise TypeError(f"`options['reset_mask']` must be a numpy array, got {type(mask)}")
    if mask.shape != (num_envs,):
        raise ValueError(
            f"`options['reset_mask']` must have shape `({num_envs},)`, got {mask.shape}"
        )
    if mask.dtype != np.bool_:
        raise TypeError(f"`options['reset_mask']` must have `dtype=np.bool_`, got {mask.dtype}")
    if not mask.any():
        raise ValueError(
            "`options['reset_mask']` must contain a boolean array with at least one True "
            f"value, got reset_mask={mask}"
        )
    return mask


def _observations(rows: np.ndarray) -> np.ndarray:
    """float32 ``[num_envs, 4]`` from the host copy of the rows: the transposed state rows, in
    Fortran order like the ``state.T.astype(np.float32)`` of Gymnasium's ``CartPoleVectorEnv``
    (a straight cast, several times cheaper than a transposing one)."""
    return rows[_STATE_ROWS].T.astype(np.float32)


def _same_step_info(final_rows: np.ndarray, done: np.ndarray) -> dict[str, Any]:
    """``SyncVectorEnv``'s same-step info from the stepped states ``[4, num_envs]``:
    ``final_obs`` an object array ``[num_envs]`` holding the last observation of each env whose
    episode ended (``None`` elsewhere), ``final_info`` the (empty) info of those steps, each
    with its mask."""
    final_obs = final_rows.T[done].astype(np.float32)  # [ended, 4], C order
    per_env = np.full(done.shape[0], None, dtype=object)
    # One row of final_obs per ended env, without a Python loop.
    per_env[done] = np.fromiter(final_obs, dtype=object, count=len(final_obs))
    return {"final_obs": per_env, "_final_obs": done, "final_info": {}, "_final_info": done.copy()}


class _Renderer:
    """Draws cart-pole states with Gymnasium's ``CartPoleEnv`` renderer (needs pygame)."""

    def __init__(self, params: EnvParams) -> None:
        from gymnasium.envs.classic_control.cartpole import CartPoleEnv

        self._env = CartPoleEnv(render_mode="rgb_array")
        # The drawing scale and pole length come from these two constants.
        self._env.x_threshold = params.x_threshold
        self._env.length = params.length

    def frame(self, state: np.ndarray) -> np.ndarray:
        """An RGB frame ``[400, 600, 3]`` uint8 of one state ``[x, x_dot, theta, theta_dot]``."""
        self._env.state = state
        return self._env.render()

    def close(self) -> None:
        self._env.close()


def _no_render_mode_warning(env: gym.Env | VectorEnv, make: str) -> None:
    spec_id = env.spec.id if env.spec is not None else ENV_ID
    gym.logger.warn(
        "You are calling render method without specifying any render mode. "
        "You can specify the render_mode at initialization, "
        f'e.g. gym.{make}("{spec_id}", render_mode="rgb_array")'
    )


def _check_render_mode(render_mode: str | None, metadata: dict[str, Any]) -> None:
    if render_mode is not None and render_mode not in metadata["render_modes"]:
        raise ValueError(
            f"render_mode must be one of {metadata['render_modes']} or None, got {render_mode!r}"
        )


def _read_only(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array


class JaxCartPoleEnv(gym.Env[np.ndarray, int]):
    """Gymnasium's CartPole with jaxcart's compiled physics; see the module docstring.

    Args:
        render_mode: ``None`` or ``"rgb_array"``.
        sutton_barto_reward: Gymnasium's option (0 per step, -1 on failure); overrides
            ``params.sutton_barto_reward`` when given.
        params: jaxcart :class:`~jaxcart.core.env.EnvParams` (physics, thresholds, reset bounds,
            integrator); default CartPole-v1's. ``params.max_episode_steps`` is not used: as
            with Gymnasium's ``CartPoleEnv``, the episode limit is the ``TimeLimit`` wrapper's.
        float64: step the physics in float64 (JAX x64 enabled for this env's calls only), as
            Gymnasium's CartPole keeps its state in float64, so that whole episodes track
            Gymnasium's; ``False`` uses JAX's global precision (float32 by default, what
            jaxcart trains with), which drifts from Gymnasium by ~1e-5 over tens of steps.

    Attributes:
        state: the physical state ``[x, x_dot, theta, theta_dot]``, a read-only float64 NumPy
            array (``None`` before the first reset), as Gymnasium's ``CartPoleEnv.state``;
            assign a new array to inject a state (the step itself keeps its copy on the JAX
            device, so editing the array in place could not reach it).
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": 50}

    def __init__(
        self,
        render_mode: str | None = None,
        sutton_barto_reward: bool | None = None,
        params: EnvParams | None = None,
        float64: bool = True,
    ) -> None:
        import jax.numpy as jnp

        from jaxcart.core import env as cartpole

        _check_render_mode(render_mode, self.metadata)
        self.params = _make_params(params, sutton_barto_reward, None)
        self.float64 = bool(float64)
        self._x64 = _uses_x64(self.float64)
        self._step_fn = _compiled_single_step(_compile_key(self.params), self._x64)
        with _precision(self._x64):
            self._floats = jnp.asarray(_float_values(self.params, 0.0, 0.0))
        self._device_actions = (jnp.asarray(0, jnp.int32), jnp.asarray(1, jnp.int32))
        self.observation_space = cartpole.observation_space(self.params)
        self.action_space = cartpole.action_space(self.params)
        self.render_mode = render_mode
        self._state: np.ndarray | None = None
        self._device_state = None  # [*state, terminated] on the device; None: upload _state
        self._steps_beyond_terminated: int | None = None
        self._renderer: _Renderer | None = None

    @property
    def state(self) -> np.ndarray | None:
        return self._state

    @state.setter
    def state(self, value: Any) -> None:
        self._state = None if value is None else _read_only(np.array(value, dtype=np.float64))
        self._device_state = None

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Starts an episode; ``options`` may set ``{"low": ..., "high": ...}`` as in Gymnasium.

        The start state is drawn from ``self.np_random`` exactly as Gymnasium's CartPole draws
        it, so a given seed starts the same episode in both.
        """
        super().reset(seed=seed)
        low, high = _reset_bounds(options, self.params)
        self.state = self.np_random.uniform(low=low, high=high, size=(4,))
        self._steps_beyond_terminated = None
        return self._state.astype(np.float32), {}

    def _advance(self, action: Any) -> bool:
        """Steps the physics (one compiled call, one transfer back); returns ``terminated``."""
        import jax

        if self._device_state is None:
            with _precision(self._x64):
                self._device_state = jax.device_put(np.append(self._state, 0.0))
        # The two valid actions live on the device: a NumPy scalar would be a transfer per call.
        device_action = self._device_actions[int(action)]
        self._device_state = self._step_fn(self._device_state, device_action, self._floats)
        # A copy: the device buffer is donated to the next step.
        packed = np.array(self._device_state)
        self._state = _read_only(packed[:4])
        return bool(packed[4])

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """One step (no autoreset, no truncation: ``TimeLimit`` adds that, as in Gymnasium)."""
        assert self.action_space.contains(action), f"{action!r} ({type(action)}) invalid"
        assert self._state is not None, "Call reset before using step method."
        terminated = self._advance(action)

        sutton_barto = bool(self.params.sutton_barto_reward)
        # Gymnasium pays +1 (Sutton-Barto: 0) per step, the terminating one included (-1), and
        # 0 (Sutton-Barto: -1) for steps taken after termination, with a warning.
        if not terminated:
            reward = 0.0 if sutton_barto else 1.0
        elif self._steps_beyond_terminated is None:
            self._steps_beyond_terminated = 0
            reward = -1.0 if sutton_barto else 1.0
        else:
            if self._steps_beyond_terminated == 0:
                gym.logger.warn(
                    "You are calling 'step()' even though this environment has already returned "
                    "terminated = True. You should always call 'reset()' once you receive "
                    "'terminated = True' -- any further steps are undefined behavior."
                )
            self._steps_beyond_terminated += 1
            reward = -1.0 if sutton_barto else 0.0
        return self._state.astype(np.float32), reward, terminated, False, {}

    def render(self) -> np.ndarray | None:
        """An RGB frame ``[400, 600, 3]`` uint8 (``render_mode="rgb_array"``)."""
        if self.render_mode is None:
            _no_render_mode_warning(self, "make")
            return None
        if self._state is None:
            return None
        if self._renderer is None:
            self._renderer = _Renderer(self.params)
        return self._renderer.frame(self._state.copy())

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


class JaxCartPoleVectorEnv(VectorEnv[np.ndarray, np.ndarray, np.ndarray]):
    """``num_envs`` CartPoles stepped as one compiled jaxcart step.

    Autoreset (``autoreset_mode``, reported in ``metadata["autoreset_mode"]``):

    - ``NEXT_STEP`` (the default, as Gymnasium's ``CartPoleVectorEnv`` and ``SyncVectorEnv``):
      the step on which an episode ends returns its last observation with ``terminated`` or
      ``truncated``; the next step ignores that env's action and starts a new episode,
      returning its first observation with reward 0, not terminated, not truncated.
      ``info`` is always ``{}``.
    - ``SAME_STEP``: on the step an episode ends, ``terminated``/``truncated`` are reported,
      the observation is the first of the next episode, and ``info`` holds Gymnasium's
      ``SyncVectorEnv`` same-step keys: ``info["final_obs"]`` (object array ``[num_envs]``, the
      final observation where ``info["_final_obs"]`` is true, ``None`` elsewhere) and
      ``info["final_info"]`` (``{}``) with its mask ``info["_final_info"]``. Steps in which no
      episode ends return ``info == {}``.
    - ``DISABLED``: no autoreset; stepping an env whose episode has ended raises
      ``AssertionError`` until ``reset(options={"reset_mask": mask})`` restarts it.

    ``reset(options={"reset_mask": mask})`` (bool ``[num_envs]``) restarts only the masked envs
    in every mode, as with ``SyncVectorEnv``. Start states are drawn on the device with keys
    taken from ``self.np_random``, so ``reset(seed=...)`` makes the run deterministic (they
    differ from the states Gymnasium's vector CartPole draws with NumPy). Observations are
    float32 ``[num_envs, 4]`` in Fortran order, as Gymnasium's ``CartPoleVectorEnv`` returns
    them; rewards float32, flags bool.

    Args:
        num_envs: number of sub-environments.
        max_episode_steps: truncation limit (``make_vec`` passes the registered 500); overrides
            ``params.max_episode_steps`` when given.
        render_mode: ``None`` or ``"rgb_array"`` (a list of ``num_envs`` frames).
        sutton_barto_reward: as for :class:`JaxCartPoleEnv`.
        params: jaxcart :class:`~jaxcart.core.env.EnvParams`; default CartPole-v1's.
        float64: as for :class:`JaxCartPoleEnv` (the batch state stays on the JAX device in
            that precision).
        autoreset_mode: a ``gymnasium.vector.AutoresetMode`` or its value (``"NextStep"``,
            ``"SameStep"``, ``"Disabled"``).

    Attributes:
        state: the physical states, float64 ``[4, num_envs]`` (rows x, x_dot, theta,
            theta_dot), as Gymnasium's ``CartPoleVectorEnv.state``: a read-only copy of the
            device state; assign a new array to inject states (step counts are kept).
    """

    metadata: ClassVar[dict[str, Any]] = {
        "render_modes": ["rgb_array"],
        "render_fps": 50,
        "autoreset_mode": AutoresetMode.NEXT_STEP,
    }

    def __init__(
        self,
        num_envs: int = 1,
        max_episode_steps: int | None = None,
        render_mode: str | None = None,
        sutton_barto_reward: bool | None = None,
        params: EnvParams | None = None,
        float64: bool = True,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
    ) -> None:
        from jaxcart.core import env as cartpole

        if num_envs < 1:
            raise ValueError(f"num_envs must be at least 1, got {num_envs}")
        _check_render_mode(render_mode, self.metadata)
        self.autoreset_mode = _autoreset_mode(autoreset_mode)
        self.metadata = {**type(self).metadata, "autoreset_mode": self.autoreset_mode}
        self.num_envs = int(num_envs)
        self.params = _make_params(params, sutton_barto_reward, max_episode_steps)
        self.float64 = bool(float64)
        self._x64 = _uses_x64(self.float64)
        self.render_mode = render_mode
        self.single_observation_space = cartpole.observation_space(self.params)
        self.single_action_space = cartpole.action_space(self.params)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._reset_fn = _compiled_vector_reset(self.num_envs, self.autoreset_mode, self._x64)
        self._step_fn = _compiled_vector_step(
            _compile_key(self.params), self.num_envs, self.autoreset_mode, self._x64
        )
        self._rows = None  # the device state (see _vector_step); None before the first reset
        self._floats = None  # _float_values with the last reset's bounds, on the device
        self._keys = np.zeros((0, 2), dtype=np.uint32)  # step keys not yet used
        self._ended = np.zeros(self.num_envs, dtype=np.bool_)  # for DISABLED's check
        self._renderer: _Renderer | None = None

    @property
    def state(self) -> np.ndarray | None:
        if self._rows is None:
            return None
        rows = np.array(self._rows)
        if self.autoreset_mode is not AutoresetMode.SAME_STEP:
            return _read_only(rows[_STATE_ROWS])
        ended = rows[_ENDED] != 0
        return _read_only(np.where(ended, rows[_START_ROWS], rows[_STATE_ROWS]))

    @state.setter
    def state(self, value: Any) -> None:
        assert self._rows is not None, "Call reset before setting the state."
        value = np.asarray(value, dtype=np.float64)
        if value.shape != (4, self.num_envs):
            raise ValueError(f"state must have shape (4, {self.num_envs}), got {value.shape}")
        with _precision(self._x64):
            self._rows = self._rows.at[_STATE_ROWS].set(value)
            if self.autoreset_mode is AutoresetMode.SAME_STEP:  # where an episode just ended
                self._rows = self._rows.at[_START_ROWS].set(value)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Resets every sub-environment, or those of ``options["reset_mask"]``. ``options`` may
        also set ``{"low": ..., "high": ...}``, which then applies to the autoresets too, until
        the next ``reset``."""
        import jax.numpy as jnp

        super().reset(seed=seed)
        options = dict(options or {})
        mask = options.pop("reset_mask", None)
        if mask is not None:
            mask = _reset_mask(mask, self.num_envs)
        if mask is None or self._rows is None:  # the first reset starts every env
            mask = np.ones(self.num_envs, dtype=np.bool_)
        low, high = _reset_bounds(options, self.params)
        key = self.np_random.integers(2**32, size=2, dtype=np.uint32)
        self._keys = self.np_random.integers(2**32, size=(_KEY_BLOCK, 2), dtype=np.uint32)
        with _precision(self._x64):
            self._floats = jnp.asarray(_float_values(self.params, low, high))
            if self._rows is None:
                spec = _rows_spec(self.num_envs, self.autoreset_mode, self._x64)
                self._rows = jnp.zeros(spec.shape, spec.dtype)
        self._rows = self._reset_fn(self._rows, key, self._floats, mask)
        self._ended &= ~mask
        # A copy: the device buffer is donated to the next call.
        return _observations(np.array(self._rows)), {}

    def _step_key(self) -> np.ndarray:
        """The next step's key (``uint32[2]``), from a block drawn from ``np_random``."""
        if not len(self._keys):
            self._keys = self.np_random.integers(2**32, size=(_KEY_BLOCK, 2), dtype=np.uint32)
        key, self._keys = self._keys[0], self._keys[1:]
        return key

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Steps every sub-environment, with the autoreset of ``autoreset_mode``."""
        assert self.action_space.contains(actions), f"{actions!r} ({type(actions)}) invalid"
        assert self._rows is not None, "Call reset before using step method."
        if self.autoreset_mode is AutoresetMode.DISABLED and self._ended.any():
            raise AssertionError(
                f"sub-environments {np.flatnonzero(self._ended).tolist()} have ended; with "
                "autoreset disabled, reset them (reset(options={'reset_mask': mask})) first"
            )
        inputs = np.empty(self.num_envs + 2, dtype=np.uint32)
        inputs[:-2] = actions
        inputs[-2:] = self._step_key()
        self._rows = self._step_fn(self._rows, inputs, self._floats)
        # The one transfer to the host; a copy, as the device buffer is donated to the next call.
        rows = np.array(self._rows)
        obs = _observations(rows)
        reward = rows[_REWARD].astype(np.float32)
        code = rows[_ENDED].astype(np.uint8)
        terminated, truncated = (code & 1) != 0, (code & 2) != 0
        info: dict[str, Any] = {}
        if self.autoreset_mode is AutoresetMode.SAME_STEP:
            done = terminated | truncated
            if done.any():
                info = _same_step_info(rows[_STATE_ROWS], done)
                obs[done] = rows[_START_ROWS].T[done]  # the next episodes' first
        elif self.autoreset_mode is AutoresetMode.DISABLED:
            self._ended = terminated | truncated
        return obs, reward, terminated, truncated, info

    def render(self) -> list[np.ndarray] | None:
        """One RGB frame per sub-environment (``render_mode="rgb_array"``)."""
        if self.render_mode is None:
            _no_render_mode_warning(self, "make_vec")
            return None
        if self._rows is None:
            raise ValueError("Call reset before rendering.")
        if self._renderer is None:
            self._renderer = _Renderer(self.params)
        return [self._renderer.frame(s.copy()) for s in self.state.T]

    def close_extras(self, **kwargs: Any) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

"""Gymnasium front-ends for jaxcart's CartPole: a ``gymnasium.Env`` and a ``VectorEnv``.

``import jaxcart`` registers ``"jaxcart/CartPole-v1"`` with Gymnasium (``gymnasium.register``,
with this module's classes as string entry points; see ``jaxcart/__init__.py``)::

    import gymnasium as gym
    import jaxcart

    env = gym.make("jaxcart/CartPole-v1")  # TimeLimit(500), like gym.make("CartPole-v1")
    envs = gym.make_vec("jaxcart/CartPole-v1", num_envs=8)  # JaxCartPoleVectorEnv, NEXT_STEP

:class:`JaxCartPoleEnv` is a drop-in for Gymnasium's ``CartPoleEnv``: the same spaces, the same
``reset(seed=...)`` start states (drawn from ``self.np_random`` exactly as Gymnasium draws
them), the same reward, ``terminated`` and ``{}`` info, ``truncated`` always ``False`` (the
``TimeLimit`` from registration truncates at 500 steps, as for ``CartPole-v1``), the same
``AssertionError`` for an invalid action, and a ``state`` attribute to read or inject the
physical state. The physics step is jaxcart's :func:`jaxcart.core.cartpole.step_env`.

:class:`JaxCartPoleVectorEnv` is a drop-in for Gymnasium's ``CartPoleVectorEnv``, with a choice
of autoreset mode (``autoreset_mode=``: ``NEXT_STEP`` by default, as Gymnasium's; ``SAME_STEP``
with ``SyncVectorEnv``'s ``final_obs``/``final_info`` layout; ``DISABLED`` with
``reset(options={"reset_mask": mask})``).

Each ``step`` is one call of a program compiled ahead of time (:mod:`jaxcart.gym.kernels`),
whose result comes back to NumPy in one copy, from which the observations, rewards, flags and
info dict are built on the host.

Both step the physics in float64 by default (JAX's x64 mode switched on for the adapters' own
calls only), as Gymnasium's CartPole keeps its state in float64, so that whole episodes track
Gymnasium's; ``float64=False`` uses JAX's global precision (float32 unless x64 is on).

Only NumPy and Gymnasium are imported with this module; JAX loads when an env is built.
Rendering (``render_mode="rgb_array"``) draws with Gymnasium's own CartPole renderer and needs
pygame (``pip install "gymnasium[classic-control]"``); ``gym.make(..., render_mode="human")``
wraps it in Gymnasium's ``HumanRendering``.

This module is the front-ends' stable address (Gymnasium code may name
``jaxcart.gym.adapter:JaxCartPoleEnv``).

Autoreset modes (``autoreset_mode=``, reported in ``metadata["autoreset_mode"]``):

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
"""

from __future__ import annotations

import os
import time
from typing import TYPE_CHECKING, Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from jaxcart.gym import ENV_ID, kernels

if TYPE_CHECKING:
    from jaxcart.core.cartpole import EnvParams

__all__ = ["ENV_ID", "JaxCartPoleEnv", "JaxCartPoleVectorEnv"]

PARAM_ATTRIBUTES = (*kernels.FLOAT_PARAMS[:-2], "kinematics_integrator")
"""``CartPoleEnv``'s attributes that both front-ends read from ``self.params`` (read-only)."""


def _param_attribute(name: str, field: str) -> property:
    def get(env: Any) -> Any:
        return getattr(env.params, field)

    def refuse(env: Any, value: Any) -> None:
        raise AttributeError(
            f"{name} is read-only on jaxcart's env (its physics is compiled from the params): "
            f'make the env with gym.make("{ENV_ID}", params=EnvParams({field}=...)) instead'
        )

    return property(get, refuse, doc=f"``params.{field}``, as Gymnasium's CartPole ``{name}``.")


class CartPoleAttributes:
    """What both front-ends share: Gymnasium ``CartPoleEnv``'s attributes (``x_threshold``,
    ``gravity``, ``total_mass``, ... :data:`PARAM_ATTRIBUTES`) read from ``self.params``, so
    code written for ``gym.make("CartPole-v1").unwrapped`` runs on jaxcart's envs unchanged
    (read-only: setting one names the ``params=`` route), their setup and their rendering
    with Gymnasium's own CartPole renderer."""

    params: EnvParams
    render_mode: str | None
    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": 50}
    _renderer: Any = None
    screen_width = 600
    screen_height = 400

    def _setup(
        self,
        render_mode: str | None,
        params: EnvParams | None,
        sutton_barto_reward: bool | None,
        max_episode_steps: int | None,
        float64: bool,
    ) -> tuple[Any, Any]:
        """Checks ``render_mode``, sets the params, precision and render mode; returns one
        env's ``(observation_space, action_space)``."""
        import jax

        from jaxcart.core import cartpole

        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']} or None, "
                f"got {render_mode!r}"
            )
        self.params = kernels.make_params(params, sutton_barto_reward, max_episode_steps)
        self.float64 = bool(float64)
        # float64 when asked, otherwise as JAX's global setting says
        self._x64 = self.float64 or bool(jax.config.jax_enable_x64)
        self.render_mode = render_mode
        return cartpole.observation_space(self.params), cartpole.action_space(self.params)

    @property
    def total_mass(self) -> float:
        """``masspole + masscart``, derived from the params as ``step`` derives it."""
        return self.params.masspole + self.params.masscart

    @property
    def polemass_length(self) -> float:
        """``masspole * length``, derived from the params as ``step`` derives it."""
        return self.params.masspole * self.params.length

    def _reset_bounds(self, options: dict | None) -> tuple[float, float]:
        """Gymnasium's ``options={"low": ..., "high": ...}`` reset bounds, else the params'."""
        from gymnasium.envs.classic_control import utils

        return utils.maybe_parse_reset_bounds(
            options, self.params.reset_low, self.params.reset_high
        )

    def _frames(self, states: np.ndarray | None, make: str) -> list[np.ndarray] | None:
        """RGB frames ``[400, 600, 3]`` uint8 of ``states`` ``[n, 4]`` (None: no state yet),
        drawn by Gymnasium's ``CartPoleEnv`` renderer (needs pygame); None, with Gymnasium's
        warning, without a render mode (``make``: how to set one)."""
        if self.render_mode is None:
            spec_id = self.spec.id if self.spec is not None else ENV_ID
            gym.logger.warn(
                "You are calling render method without specifying any render mode. "
                "You can specify the render_mode at initialization, "
                f'e.g. gym.{make}("{spec_id}", render_mode="rgb_array")'
            )
            return None
        if states is None:
            return None
        if self._renderer is None:
            from gymnasium.envs.classic_control.cartpole import CartPoleEnv

            self._renderer = CartPoleEnv(render_mode="rgb_array")
            # The drawing scale and pole length come from these two constants.
            self._renderer.x_threshold = self.params.x_threshold
            self._renderer.length = self.params.length
        frames = []
        for state in states:
            self._renderer.state = state.copy()
            frames.append(self._renderer.render())
        return frames

    def close_extras(self, **kwargs: Any) -> None:
        """Closes the renderer (``VectorEnv.close`` calls it; it is ``JaxCartPoleEnv.close``)."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


for _name in PARAM_ATTRIBUTES:
    setattr(CartPoleAttributes, _name, _param_attribute(_name, _name))


def _read_only(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array


class JaxCartPoleEnv(CartPoleAttributes, gym.Env[np.ndarray, int]):
    """Gymnasium's CartPole with jaxcart's compiled physics; see :mod:`jaxcart.gym.adapter`.

    Args:
        render_mode: ``None`` or ``"rgb_array"``.
        sutton_barto_reward: Gymnasium's option (0 per step, -1 on failure); overrides
            ``params.sutton_barto_reward`` when given.
        params: jaxcart :class:`~jaxcart.core.cartpole.EnvParams` (physics, thresholds, reset bounds,
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
        x_threshold, theta_threshold_radians, gravity, masscart, masspole, length, force_mag,
            tau, kinematics_integrator, total_mass, polemass_length: ``CartPoleEnv``'s
            constants, read from ``params`` (read-only: set them through ``params=``).
        steps_beyond_terminated: as ``CartPoleEnv``'s (``None`` until the episode ends).
    """

    def __init__(
        self,
        render_mode: str | None = None,
        sutton_barto_reward: bool | None = None,
        params: EnvParams | None = None,
        float64: bool = True,
    ) -> None:
        import jax.numpy as jnp

        spaces = self._setup(render_mode, params, sutton_barto_reward, None, float64)
        self.observation_space, self.action_space = spaces
        self._step_fn = kernels.compiled_single_step(kernels.compile_key(self.params), self._x64)
        with kernels.precision(self._x64):
            self._floats = jnp.asarray(kernels.float_values(self.params, 0.0, 0.0))
        self._device_actions = (jnp.asarray(0, jnp.int32), jnp.asarray(1, jnp.int32))
        self._state: np.ndarray | None = None
        self._device_state = None  # [*state, terminated] on the device; None: upload _state
        self.steps_beyond_terminated: int | None = None

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
        low, high = self._reset_bounds(options)
        self.state = self.np_random.uniform(low=low, high=high, size=(4,))
        self.steps_beyond_terminated = None
        return self._state.astype(np.float32), {}

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """One step (no autoreset, no truncation: ``TimeLimit`` adds that, as in Gymnasium):
        one compiled call, one transfer back."""
        import jax

        assert self.action_space.contains(action), f"{action!r} ({type(action)}) invalid"
        assert self._state is not None, "Call reset before using step method."
        if self._device_state is None:
            with kernels.precision(self._x64):
                self._device_state = jax.device_put(np.append(self._state, 0.0))
        # The two valid actions live on the device: a NumPy scalar would be a transfer per call.
        device_action = self._device_actions[int(action)]
        self._device_state = self._step_fn(self._device_state, device_action, self._floats)
        # A copy: the device buffer is donated to the next step.
        packed = np.array(self._device_state)
        self._state, terminated = _read_only(packed[:4]), bool(packed[4])

        sutton_barto = bool(self.params.sutton_barto_reward)
        # Gymnasium pays +1 (Sutton-Barto: 0) per step, the terminating one included (-1), and
        # 0 (Sutton-Barto: -1) for steps taken after termination, with a warning.
        if not terminated:
            reward = 0.0 if sutton_barto else 1.0
        elif self.steps_beyond_terminated is None:
            self.steps_beyond_terminated = 0
            reward = -1.0 if sutton_barto else 1.0
        else:
            if self.steps_beyond_terminated == 0:
                gym.logger.warn(
                    "You are calling 'step()' even though this environment has already returned "
                    "terminated = True. You should always call 'reset()' once you receive "
                    "'terminated = True' -- any further steps are undefined behavior."
                )
            self.steps_beyond_terminated += 1
            reward = -1.0 if sutton_barto else 0.0
        return self._state.astype(np.float32), reward, terminated, False, {}

    def render(self) -> np.ndarray | None:
        """An RGB frame ``[400, 600, 3]`` uint8 (``render_mode="rgb_array"``)."""
        frames = self._frames(None if self._state is None else self._state[None], "make")
        return frames[0] if frames else None

    close = CartPoleAttributes.close_extras


_KEY_BLOCK = 1024  # step keys drawn from np_random at a time


def _autoreset_mode(mode: AutoresetMode | str) -> AutoresetMode:
    """``mode`` as an :class:`AutoresetMode`; a clear error for anything that is not one."""
    valid = ", ".join(repr(m.value) for m in AutoresetMode)
    error = ValueError if isinstance(mode, str | AutoresetMode) else TypeError
    try:
        return AutoresetMode(mode)
    except ValueError:
        raise error(
            f"autoreset_mode must be a gymnasium.vector.AutoresetMode or one of {valid}, "
            f"got {mode!r} ({type(mode).__name__})"
        ) from None


def _reset_mask(mask: Any, num_envs: int, every_env: bool) -> np.ndarray:
    """The envs to reset, bool ``[num_envs]``: ``options["reset_mask"]`` (``mask``), checked as
    Gymnasium's ``SyncVectorEnv`` checks it, or every env if ``mask`` is ``None`` or
    ``every_env``."""
    if mask is not None:
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
    return np.ones(num_envs, dtype=np.bool_) if mask is None or every_env else mask


def _valid_actions(actions: Any, space: Any) -> bool:
    """``space.contains(actions)`` (``space``: the batched ``Discrete(2)``), without its generic
    checks for the usual case of an integer array of the right shape: every action 0 or 1."""
    if type(actions) is np.ndarray and actions.dtype.kind in "iu" and actions.shape == space.shape:
        return not (actions >> 1).any()  # 0 and 1 are the only integers with no bit above the first
    return bool(space.contains(actions))


def _step_results(
    rows: np.ndarray, mode: AutoresetMode
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
    """``step``'s ``(obs [num_envs, 4] float32, reward [num_envs] float32, terminated,
    truncated, info)`` from the host copy of the rows after a step in ``mode``. In
    ``SAME_STEP``, where an episode ended, ``info`` is ``SyncVectorEnv``'s same-step info:
    ``final_obs`` an object array ``[num_envs]`` holding the last observation of each env whose
    episode ended (``None`` elsewhere), ``final_info`` the (empty) info of those steps, each
    with its mask."""
    obs = kernels.observations(rows)
    reward = rows[kernels.REWARD].astype(np.float32)
    code = rows[kernels.ENDED].astype(np.uint8)
    terminated, truncated = (code & 1) != 0, (code & 2) != 0
    info: dict[str, Any] = {}
    if mode is AutoresetMode.SAME_STEP:
        done = terminated | truncated
        if done.any():
            final_obs = rows[kernels.STATE_ROWS].T[done].astype(np.float32)  # [ended, 4], C order
            per_env = np.full(done.shape[0], None, dtype=object)
            # One row of final_obs per ended env, without a Python loop.
            per_env[done] = np.fromiter(final_obs, dtype=object, count=len(final_obs))
            info = {"final_obs": per_env, "_final_obs": done}
            info |= {"final_info": {}, "_final_info": done.copy()}
            obs[done] = rows[kernels.START_ROWS].T[done]  # the next episodes' first
    return obs, reward, terminated, truncated, info


class JaxCartPoleVectorEnv(CartPoleAttributes, VectorEnv[np.ndarray, np.ndarray, np.ndarray]):
    """``num_envs`` CartPoles stepped as one compiled jaxcart step, with the autoreset of
    ``autoreset_mode`` (``NEXT_STEP``, ``SAME_STEP`` or ``DISABLED``: see the module docstring).

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
        params: jaxcart :class:`~jaxcart.core.cartpole.EnvParams`; default CartPole-v1's.
        float64: as for :class:`JaxCartPoleEnv` (the batch state stays on the JAX device in
            that precision).
        autoreset_mode: a ``gymnasium.vector.AutoresetMode`` or its value (``"NextStep"``,
            ``"SameStep"``, ``"Disabled"``).

    Attributes:
        state: the physical states, float64 ``[4, num_envs]`` (rows x, x_dot, theta,
            theta_dot), as Gymnasium's ``CartPoleVectorEnv.state``: a read-only copy of the
            device state; assign a new array to inject states (step counts are kept).
        x_threshold, theta_threshold_radians, gravity, masscart, masspole, length, force_mag,
            tau, kinematics_integrator, total_mass, polemass_length, max_episode_steps, low,
            high: ``CartPoleVectorEnv``'s constants, read from ``params`` (read-only).
    """

    metadata: ClassVar[dict[str, Any]] = {
        **CartPoleAttributes.metadata,
        "autoreset_mode": AutoresetMode.NEXT_STEP,
    }
    # CartPoleVectorEnv's further attributes, each read from the field of params it names
    max_episode_steps = _param_attribute("max_episode_steps", "max_episode_steps")
    low = _param_attribute("low", "reset_low")
    high = _param_attribute("high", "reset_high")

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
        if num_envs < 1:
            raise ValueError(f"num_envs must be at least 1, got {num_envs}")
        spaces = self._setup(render_mode, params, sutton_barto_reward, max_episode_steps, float64)
        self.single_observation_space, self.single_action_space = spaces
        self.autoreset_mode = _autoreset_mode(autoreset_mode)
        self.metadata = {**type(self).metadata, "autoreset_mode": self.autoreset_mode}
        self.num_envs = int(num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._reset_fn = kernels.compiled_vector_reset(
            self.num_envs, self.autoreset_mode, self._x64
        )
        self._step_fn = kernels.compiled_vector_step(
            kernels.compile_key(self.params), self.num_envs, self.autoreset_mode, self._x64
        )
        self._rows = None  # the device state (see kernels.vector_step); None before the first reset
        self._spare = None  # a buffer like it, into which the next step writes its rows
        self._floats = None  # kernels.float_values with the last reset's bounds, on the device
        self._keys = np.zeros((0, 2), dtype=np.uint32)  # step keys not yet used
        self._ended = np.zeros(self.num_envs, dtype=np.bool_)  # for DISABLED's check

    @property
    def state(self) -> np.ndarray | None:
        """The physical states in a host copy of the rows: in ``SAME_STEP``, where an episode
        just ended, the next episode's start state."""
        if self._rows is None:
            return None
        rows = np.array(self._rows)
        states = rows[kernels.STATE_ROWS]
        if self.autoreset_mode is AutoresetMode.SAME_STEP:
            states = np.where(rows[kernels.ENDED] != 0, rows[kernels.START_ROWS], states)
        return _read_only(states)

    @state.setter
    def state(self, value: Any) -> None:
        assert self._rows is not None, "Call reset before setting the state."
        with kernels.precision(self._x64):
            self._rows = kernels.with_states(self._rows, value, self.autoreset_mode)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Resets every sub-environment, or those of ``options["reset_mask"]``. ``options`` may
        also set ``{"low": ..., "high": ...}``, which then applies to the autoresets too, until
        the next ``reset``."""
        import jax.numpy as jnp

        super().reset(seed=seed)
        options = dict(options or {})
        # The first reset starts every env.
        mask = _reset_mask(options.pop("reset_mask", None), self.num_envs, self._rows is None)
        low, high = self._reset_bounds(options)
        key = self.np_random.integers(2**32, size=2, dtype=np.uint32)
        self._keys = self.np_random.integers(2**32, size=(_KEY_BLOCK, 2), dtype=np.uint32)
        with kernels.precision(self._x64):
            self._floats = jnp.asarray(kernels.float_values(self.params, low, high))
            if self._rows is None:
                shape = kernels.rows_shape(self.num_envs, self.autoreset_mode)
                self._rows, self._spare = (jnp.zeros(shape, jnp.zeros(()).dtype) for _ in "ab")
        self._rows = self._reset_fn(self._rows, key, self._floats, mask)
        self._ended &= ~mask
        return kernels.observations(np.asarray(self._rows)), {}  # a new array

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Steps every sub-environment, with the autoreset of ``autoreset_mode``."""
        assert _valid_actions(actions, self.action_space), f"{actions!r} ({type(actions)}) invalid"
        assert self._rows is not None, "Call reset before using step method."
        if self.autoreset_mode is AutoresetMode.DISABLED and self._ended.any():
            raise AssertionError(
                f"sub-environments {np.flatnonzero(self._ended).tolist()} have ended; with "
                "autoreset disabled, reset them (reset(options={'reset_mask': mask})) first"
            )
        if not len(self._keys):  # the step keys come in blocks drawn from np_random
            self._keys = self.np_random.integers(2**32, size=(_KEY_BLOCK, 2), dtype=np.uint32)
        inputs = kernels.step_inputs(actions, self._keys[0])
        self._keys = self._keys[1:]
        rows = self._step_fn(self._rows, self._spare, inputs, self._floats)
        self._rows, self._spare = rows, self._rows
        _spin_until_ready(rows)
        # One read-only view of the device buffer (no copy on CPU); every output is a new array.
        results = _step_results(np.asarray(rows), self.autoreset_mode)
        if self.autoreset_mode is AutoresetMode.DISABLED:
            self._ended = results[2] | results[3]  # terminated | truncated
        return results

    def render(self) -> list[np.ndarray] | None:
        """One RGB frame per sub-environment (``render_mode="rgb_array"``)."""
        if self.render_mode is not None and self._rows is None:
            raise ValueError("Call reset before rendering.")
        return self._frames(None if self._rows is None else self.state.T, "make_vec")


SPIN_SECONDS = 300e-6
"""How long a step waits for its result by polling before it blocks (about 3 steps at N =
4,096 on this project's machine)."""


def _spin_until_ready(array) -> None:
    """Polls ``array`` for up to :data:`SPIN_SECONDS`, yielding the core between polls,
    before the caller blocks on it. With JAX's default asynchronous CPU dispatch the step runs
    on XLA's worker threads, and a caller asleep on the result pays a wake-up per step: at N =
    4,096 on a quiet 2-core machine polling took the vector env from 0.73-0.88x to 1.10-1.19x
    Gymnasium's NumPy vector env. Polling without yielding was erratic (0.69-1.17x) and,
    with both cores busy elsewhere, slower than blocking (0.38-0.41x against 0.52-0.54x);
    yielding measured 0.88-0.94x there, blocking 0.52-0.91x (``benchmarks/RESULTS.md``,
    "Gymnasium adapter")."""
    deadline = time.perf_counter() + SPIN_SECONDS
    while not array.is_ready() and time.perf_counter() < deadline:
        os.sched_yield()

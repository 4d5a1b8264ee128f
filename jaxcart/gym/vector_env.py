"""``num_envs`` jaxcart CartPoles as a Gymnasium ``VectorEnv``, a drop-in for Gymnasium's
``CartPoleVectorEnv`` with a choice of autoreset mode (see also :mod:`jaxcart.gym.adapter`).

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

import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from jaxcart.gym import host, kernels

if TYPE_CHECKING:
    from jaxcart.core.cartpole import EnvParams

_KEY_BLOCK = 1024  # step keys drawn from np_random at a time


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


def _current_states(rows: np.ndarray, mode: AutoresetMode) -> np.ndarray:
    """The physical states ``[4, num_envs]`` in the host copy of the rows: in ``SAME_STEP``,
    where an episode just ended, the next episode's start state."""
    if mode is not AutoresetMode.SAME_STEP:
        return rows[kernels.STATE_ROWS]
    ended = rows[kernels.ENDED] != 0
    return np.where(ended, rows[kernels.START_ROWS], rows[kernels.STATE_ROWS])


def _valid_actions(actions: Any, space: Any) -> bool:
    """``space.contains(actions)`` (``space``: the batched ``Discrete(2)``), without its generic
    checks for the usual case of an integer array of the right shape: every action 0 or 1."""
    if type(actions) is np.ndarray and actions.dtype.kind in "iu" and actions.shape == space.shape:
        return not (actions >> 1).any()  # 0 and 1 are the only integers with no bit above the first
    return bool(space.contains(actions))


def _check_none_ended(ended: np.ndarray) -> None:
    """With autoreset disabled, stepping an env whose episode has ended is an error."""
    if ended.any():
        raise AssertionError(
            f"sub-environments {np.flatnonzero(ended).tolist()} have ended; with "
            "autoreset disabled, reset them (reset(options={'reset_mask': mask})) first"
        )


def _step_results(
    rows: np.ndarray, mode: AutoresetMode
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
    """``step``'s ``(obs [num_envs, 4] float32, reward [num_envs] float32, terminated,
    truncated, info)`` from the host copy of the rows after a step in ``mode``."""
    obs = kernels.observations(rows)
    reward = rows[kernels.REWARD].astype(np.float32)
    code = rows[kernels.ENDED].astype(np.uint8)
    terminated, truncated = (code & 1) != 0, (code & 2) != 0
    info: dict[str, Any] = {}
    if mode is AutoresetMode.SAME_STEP:
        done = terminated | truncated
        if done.any():
            info = _same_step_info(rows[kernels.STATE_ROWS], done)
            obs[done] = rows[kernels.START_ROWS].T[done]  # the next episodes' first
    return obs, reward, terminated, truncated, info


class JaxCartPoleVectorEnv(host.CartPoleAttributes, VectorEnv[np.ndarray, np.ndarray, np.ndarray]):
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
        from jaxcart.core import cartpole

        if num_envs < 1:
            raise ValueError(f"num_envs must be at least 1, got {num_envs}")
        host.check_render_mode(render_mode, self.metadata)
        self.autoreset_mode = _autoreset_mode(autoreset_mode)
        self.metadata = {**type(self).metadata, "autoreset_mode": self.autoreset_mode}
        self.num_envs = int(num_envs)
        self.params = kernels.make_params(params, sutton_barto_reward, max_episode_steps)
        self.float64 = bool(float64)
        self._x64 = kernels.uses_x64(self.float64)
        self.render_mode = render_mode
        self.single_observation_space = cartpole.observation_space(self.params)
        self.single_action_space = cartpole.action_space(self.params)
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
    def max_episode_steps(self) -> int:
        return int(self.params.max_episode_steps)

    @property
    def low(self) -> float:
        """The default lower reset bound, as ``CartPoleVectorEnv.low``."""
        return self.params.reset_low

    @property
    def high(self) -> float:
        """The default upper reset bound, as ``CartPoleVectorEnv.high``."""
        return self.params.reset_high

    @property
    def state(self) -> np.ndarray | None:
        if self._rows is None:
            return None
        return host.read_only(_current_states(np.array(self._rows), self.autoreset_mode))

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
        low, high = host.reset_bounds(options, self.params)
        key = self.np_random.integers(2**32, size=2, dtype=np.uint32)
        self._keys = self.np_random.integers(2**32, size=(_KEY_BLOCK, 2), dtype=np.uint32)
        with kernels.precision(self._x64):
            self._floats = jnp.asarray(kernels.float_values(self.params, low, high))
            if self._rows is None:
                spec = kernels.rows_spec(self.num_envs, self.autoreset_mode, self._x64)
                self._rows, self._spare = (jnp.zeros(spec.shape, spec.dtype) for _ in "ab")
        self._rows = self._reset_fn(self._rows, key, self._floats, mask)
        self._ended &= ~mask
        return kernels.observations(np.asarray(self._rows)), {}  # a new array

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
        assert _valid_actions(actions, self.action_space), f"{actions!r} ({type(actions)}) invalid"
        assert self._rows is not None, "Call reset before using step method."
        if self.autoreset_mode is AutoresetMode.DISABLED:
            _check_none_ended(self._ended)
        inputs = kernels.step_inputs(actions, self._step_key())
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

    def close_extras(self, **kwargs: Any) -> None:
        self._close_renderer()


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

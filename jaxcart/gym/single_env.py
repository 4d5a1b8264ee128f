"""jaxcart's CartPole as a ``gymnasium.Env``, a drop-in for Gymnasium's ``CartPoleEnv``
(see :mod:`jaxcart.gym.adapter`)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

import gymnasium as gym
import numpy as np

from jaxcart.gym import host, kernels

if TYPE_CHECKING:
    from jaxcart.core.cartpole import EnvParams


class JaxCartPoleEnv(host.CartPoleAttributes, gym.Env[np.ndarray, int]):
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

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": 50}

    def __init__(
        self,
        render_mode: str | None = None,
        sutton_barto_reward: bool | None = None,
        params: EnvParams | None = None,
        float64: bool = True,
    ) -> None:
        import jax.numpy as jnp

        from jaxcart.core import cartpole

        host.check_render_mode(render_mode, self.metadata)
        self.params = kernels.make_params(params, sutton_barto_reward, None)
        self.float64 = bool(float64)
        self._x64 = kernels.uses_x64(self.float64)
        self._step_fn = kernels.compiled_single_step(kernels.compile_key(self.params), self._x64)
        with kernels.precision(self._x64):
            self._floats = jnp.asarray(kernels.float_values(self.params, 0.0, 0.0))
        self._device_actions = (jnp.asarray(0, jnp.int32), jnp.asarray(1, jnp.int32))
        self.observation_space = cartpole.observation_space(self.params)
        self.action_space = cartpole.action_space(self.params)
        self.render_mode = render_mode
        self._state: np.ndarray | None = None
        self._device_state = None  # [*state, terminated] on the device; None: upload _state
        self._steps_beyond_terminated: int | None = None

    @property
    def state(self) -> np.ndarray | None:
        return self._state

    @property
    def steps_beyond_terminated(self) -> int | None:
        return self._steps_beyond_terminated

    @state.setter
    def state(self, value: Any) -> None:
        self._state = None if value is None else host.read_only(np.array(value, dtype=np.float64))
        self._device_state = None

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Starts an episode; ``options`` may set ``{"low": ..., "high": ...}`` as in Gymnasium.

        The start state is drawn from ``self.np_random`` exactly as Gymnasium's CartPole draws
        it, so a given seed starts the same episode in both.
        """
        super().reset(seed=seed)
        low, high = host.reset_bounds(options, self.params)
        self.state = self.np_random.uniform(low=low, high=high, size=(4,))
        self._steps_beyond_terminated = None
        return self._state.astype(np.float32), {}

    def _advance(self, action: Any) -> bool:
        """Steps the physics (one compiled call, one transfer back); returns ``terminated``."""
        import jax

        if self._device_state is None:
            with kernels.precision(self._x64):
                self._device_state = jax.device_put(np.append(self._state, 0.0))
        # The two valid actions live on the device: a NumPy scalar would be a transfer per call.
        device_action = self._device_actions[int(action)]
        self._device_state = self._step_fn(self._device_state, device_action, self._floats)
        # A copy: the device buffer is donated to the next step.
        packed = np.array(self._device_state)
        self._state = host.read_only(packed[:4])
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
        frames = self._frames(None if self._state is None else self._state[None], "make")
        return frames[0] if frames else None

    def close(self) -> None:
        self._close_renderer()

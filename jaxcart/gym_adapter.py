"""Gymnasium front-ends for jaxcart's CartPole: a ``gymnasium.Env`` and a ``VectorEnv``.

Importing this module registers ``"jaxcart/CartPole-v1"`` with Gymnasium (idempotently)::

    import gymnasium as gym
    import jaxcart.gym_adapter  # or: gym.make("jaxcart.gym_adapter:jaxcart/CartPole-v1")

    env = gym.make("jaxcart/CartPole-v1")  # TimeLimit(500), like gym.make("CartPole-v1")
    envs = gym.make_vec("jaxcart/CartPole-v1", num_envs=8)  # JaxCartPoleVectorEnv

:class:`JaxCartPoleEnv` is a drop-in for Gymnasium's ``CartPoleEnv``: the same spaces, the same
``reset(seed=...)`` start states (drawn from ``self.np_random`` exactly as Gymnasium draws
them), the same reward, ``terminated`` and ``{}`` info, ``truncated`` always ``False`` (the
``TimeLimit`` from registration truncates at 500 steps, as for ``CartPole-v1``), the same
``AssertionError`` for an invalid action, and a ``state`` attribute to read or inject the
physical state. The physics step is jaxcart's compiled :func:`jaxcart.env.step_env`.

:class:`JaxCartPoleVectorEnv` runs ``num_envs`` cart-poles as one compiled, vmapped
:func:`jaxcart.env.step` with same-step autoreset (``AutoresetMode.SAME_STEP``): when an episode
ends, the returned observation starts the next one and ``info["final_obs"]`` holds the last
observation of the finished one, in Gymnasium's ``SyncVectorEnv`` layout.

Both step the physics in float64 by default (JAX's x64 mode switched on for the adapters' own
calls only), as Gymnasium's CartPole keeps its state in float64, so that whole episodes track
Gymnasium's; ``float64=False`` uses JAX's global precision (float32 unless x64 is on).

Only NumPy and Gymnasium are imported with this module; JAX loads when an env is built.
Rendering (``render_mode="rgb_array"``) draws with Gymnasium's own CartPole renderer and needs
pygame (``pip install "gymnasium[classic-control]"``); ``gym.make(..., render_mode="human")``
wraps it in Gymnasium's ``HumanRendering``.
"""

from __future__ import annotations

import contextlib
import functools
from typing import TYPE_CHECKING, Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

if TYPE_CHECKING:
    from jaxcart.env import EnvParams, EnvState

ENV_ID = "jaxcart/CartPole-v1"
MAX_EPISODE_STEPS = 500


def register_envs() -> None:
    """Registers ``jaxcart/CartPole-v1`` (single and vector entry points); idempotent."""
    if ENV_ID in gym.registry:
        return
    gym.register(
        id=ENV_ID,
        entry_point="jaxcart.gym_adapter:JaxCartPoleEnv",
        vector_entry_point="jaxcart.gym_adapter:JaxCartPoleVectorEnv",
        max_episode_steps=MAX_EPISODE_STEPS,
        reward_threshold=475.0,  # CartPole-v1's
    )


@functools.cache
def _jit(fn, static_argnames: tuple[str, ...] = ()):
    """``jax.jit(fn)``, built once per function so every env instance shares its compilations."""
    import jax

    return jax.jit(fn, static_argnames=static_argnames)


def _transition(state, action, params: EnvParams):
    """One physics step of one env, no reset: ``(next_state (4,), terminated)``."""
    from jaxcart import env as cartpole

    obs, _, _, terminated, _ = cartpole.step_env(cartpole.state_from_obs(state), action, params)
    return obs, terminated


def _vector_reset(key, params: EnvParams, num_envs: int):
    """Starts ``num_envs`` episodes: ``(key, obs [num_envs, 4], state)``."""
    import jax

    from jaxcart import env as cartpole

    key, subkey = jax.random.split(key)
    obs, state = jax.vmap(cartpole.reset, in_axes=(0, None))(
        jax.random.split(subkey, num_envs), params
    )
    return key, obs, state


def _vector_step(key, state: EnvState, actions, params: EnvParams):
    """Steps every env with same-step autoreset.

    Returns:
        ``(key, obs, state, reward, terminated, truncated, final_obs)``; obs and final_obs
        ``[num_envs, 4]``, the rest ``[num_envs]``.
    """
    import jax

    from jaxcart import env as cartpole

    key, subkey = jax.random.split(key)
    keys = jax.random.split(subkey, actions.shape[0])
    obs, state, reward, terminated, truncated, info = jax.vmap(
        cartpole.step, in_axes=(0, 0, 0, None)
    )(keys, state, actions, params)
    return key, obs, state, reward, terminated, truncated, info["final_obs"]


def _precision(float64: bool):
    """JAX's x64 mode for the adapter's own calls only (the global setting is left alone)."""
    import jax

    return jax.enable_x64(True) if float64 else contextlib.nullcontext()


def _to_device(params: EnvParams) -> EnvParams:
    """``params`` with array leaves, so a step does not convert Python floats on every call."""
    import jax
    import jax.numpy as jnp

    return jax.tree.map(jnp.asarray, params)


def _make_params(
    params: EnvParams | None, sutton_barto_reward: bool | None, max_episode_steps: int | None
) -> EnvParams:
    """``params`` (default: CartPole-v1's) with the explicitly given options applied."""
    from jaxcart import env as cartpole

    params = cartpole.EnvParams() if params is None else params
    if sutton_barto_reward is not None:
        params = params.replace(sutton_barto_reward=bool(sutton_barto_reward))
    if max_episode_steps is not None:
        params = params.replace(max_episode_steps=int(max_episode_steps))
    return params


def _reset_bounds(options: dict | None, params: EnvParams) -> tuple[float, float]:
    """Gymnasium's ``options={"low": ..., "high": ...}`` reset bounds, else the params' ones."""
    from gymnasium.envs.classic_control import utils

    return utils.maybe_parse_reset_bounds(options, params.reset_low, params.reset_high)


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


class JaxCartPoleEnv(gym.Env[np.ndarray, int]):
    """Gymnasium's CartPole with jaxcart's compiled physics; see the module docstring.

    Args:
        render_mode: ``None`` or ``"rgb_array"``.
        sutton_barto_reward: Gymnasium's option (0 per step, -1 on failure); overrides
            ``params.sutton_barto_reward`` when given.
        params: jaxcart :class:`~jaxcart.env.EnvParams` (physics, thresholds, reset bounds,
            integrator); default CartPole-v1's. ``params.max_episode_steps`` is not used: as
            with Gymnasium's ``CartPoleEnv``, the episode limit is the ``TimeLimit`` wrapper's.
        float64: step the physics in float64 (JAX x64 enabled for this env's calls only), as
            Gymnasium's CartPole keeps its state in float64, so that whole episodes track
            Gymnasium's; ``False`` uses JAX's global precision (float32 by default, what
            jaxcart trains with), which drifts from Gymnasium by ~1e-5 over tens of steps.

    Attributes:
        state: the physical state ``[x, x_dot, theta, theta_dot]``, a float64 NumPy array
            (``None`` before the first reset), as Gymnasium's ``CartPoleEnv.state``; assign to
            inject a state.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": 50}

    def __init__(
        self,
        render_mode: str | None = None,
        sutton_barto_reward: bool | None = None,
        params: EnvParams | None = None,
        float64: bool = True,
    ) -> None:
        from jaxcart import env as cartpole

        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']} or None, "
                f"got {render_mode!r}"
            )
        self.params = _make_params(params, sutton_barto_reward, None)
        self.float64 = bool(float64)
        with _precision(self.float64):
            self._device_params = _to_device(self.params)
        self.observation_space = cartpole.observation_space(self.params)
        self.action_space = cartpole.action_space(self.params)
        self.render_mode = render_mode
        self.state: np.ndarray | None = None
        self._steps_beyond_terminated: int | None = None
        self._renderer: _Renderer | None = None

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
        return np.array(self.state, dtype=np.float32), {}

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """One step (no autoreset, no truncation: ``TimeLimit`` adds that, as in Gymnasium)."""
        assert self.action_space.contains(action), f"{action!r} ({type(action)}) invalid"
        assert self.state is not None, "Call reset before using step method."
        with _precision(self.float64):
            next_state, terminated = _jit(_transition)(
                np.asarray(self.state, dtype=np.float64), np.int32(action), self._device_params
            )
            self.state = np.array(next_state, dtype=np.float64)
            terminated = bool(terminated)

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
        return np.array(self.state, dtype=np.float32), reward, terminated, False, {}

    def render(self) -> np.ndarray | None:
        """An RGB frame ``[400, 600, 3]`` uint8 (``render_mode="rgb_array"``)."""
        if self.render_mode is None:
            _no_render_mode_warning(self, "make")
            return None
        if self.state is None:
            return None
        if self._renderer is None:
            self._renderer = _Renderer(self.params)
        return self._renderer.frame(np.asarray(self.state, dtype=np.float64))

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


class JaxCartPoleVectorEnv(VectorEnv[np.ndarray, np.ndarray, np.ndarray]):
    """``num_envs`` CartPoles stepped as one vmapped, compiled jaxcart step.

    Same-step autoreset (``metadata["autoreset_mode"] == AutoresetMode.SAME_STEP``): on the step
    an episode ends, ``terminated``/``truncated`` are reported, the observation is the first of
    the next episode, and ``info`` holds Gymnasium's ``SyncVectorEnv`` same-step keys:
    ``info["final_obs"]`` (object array ``[num_envs]``, the final observation where
    ``info["_final_obs"]`` is true, ``None`` elsewhere) and ``info["final_info"]`` (``{}``) with
    its mask ``info["_final_info"]``. Steps in which no episode ends return ``info == {}``.

    Resets draw JAX keys from ``self.np_random``, so ``reset(seed=...)`` is deterministic
    (the start states differ from Gymnasium's vector CartPole, which draws them with NumPy).

    Args:
        num_envs: number of sub-environments.
        max_episode_steps: truncation limit (``make_vec`` passes the registered 500); overrides
            ``params.max_episode_steps`` when given.
        render_mode: ``None`` or ``"rgb_array"`` (a list of ``num_envs`` frames).
        sutton_barto_reward: as for :class:`JaxCartPoleEnv`.
        params: jaxcart :class:`~jaxcart.env.EnvParams`; default CartPole-v1's.
        float64: as for :class:`JaxCartPoleEnv` (the batch state stays on the JAX device in
            that precision).
    """

    metadata: ClassVar[dict[str, Any]] = {
        "render_modes": ["rgb_array"],
        "render_fps": 50,
        "autoreset_mode": AutoresetMode.SAME_STEP,
    }

    def __init__(
        self,
        num_envs: int = 1,
        max_episode_steps: int | None = None,
        render_mode: str | None = None,
        sutton_barto_reward: bool | None = None,
        params: EnvParams | None = None,
        float64: bool = True,
    ) -> None:
        from jaxcart import env as cartpole

        if num_envs < 1:
            raise ValueError(f"num_envs must be at least 1, got {num_envs}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']} or None, "
                f"got {render_mode!r}"
            )
        self.num_envs = int(num_envs)
        self.params = _make_params(params, sutton_barto_reward, max_episode_steps)
        self.float64 = bool(float64)
        self.render_mode = render_mode
        self.single_observation_space = cartpole.observation_space(self.params)
        self.single_action_space = cartpole.action_space(self.params)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._device_params = self.params  # with the last reset's bounds, as arrays
        self._key = None
        self._state: EnvState | None = None
        self._renderer: _Renderer | None = None

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Resets every sub-environment; ``options`` may set ``{"low": ..., "high": ...}``,
        which also applies to the autoresets until the next ``reset``."""
        import jax

        super().reset(seed=seed)
        low, high = _reset_bounds(options, self.params)
        episode_params = self.params.replace(reset_low=low, reset_high=high)
        seed_bits = int(self.np_random.integers(2**31))
        with _precision(self.float64):
            self._device_params = _to_device(episode_params)
            self._key, obs, self._state = _jit(_vector_reset, ("num_envs",))(
                jax.random.PRNGKey(seed_bits), self._device_params, num_envs=self.num_envs
            )
            obs = np.array(obs, dtype=np.float32)
        return obs, {}

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Steps every sub-environment, resetting those whose episode ends on this step."""
        assert self.action_space.contains(actions), f"{actions!r} ({type(actions)}) invalid"
        assert self._state is not None, "Call reset before using step method."
        with _precision(self.float64):
            self._key, obs, self._state, reward, terminated, truncated, final_obs = _jit(
                _vector_step
            )(self._key, self._state, np.asarray(actions, dtype=np.int32), self._device_params)
            obs, reward, final_obs, terminated, truncated = (
                np.array(obs, dtype=np.float32),
                np.array(reward, dtype=np.float32),
                np.array(final_obs, dtype=np.float32),
                np.array(terminated, dtype=np.bool_),
                np.array(truncated, dtype=np.bool_),
            )
        done = terminated | truncated
        info: dict[str, Any] = {}
        if done.any():
            final_obs_per_env = np.full(self.num_envs, None, dtype=object)
            for i in np.flatnonzero(done):
                final_obs_per_env[i] = final_obs[i].copy()
            info = {
                "final_obs": final_obs_per_env,
                "_final_obs": done.copy(),
                "final_info": {},
                "_final_info": done.copy(),
            }
        return obs, reward, terminated, truncated, info

    def render(self) -> list[np.ndarray] | None:
        """One RGB frame per sub-environment (``render_mode="rgb_array"``)."""
        if self.render_mode is None:
            _no_render_mode_warning(self, "make_vec")
            return None
        if self._state is None:
            raise ValueError("Call reset before rendering.")
        from jaxcart import env as cartpole

        if self._renderer is None:
            self._renderer = _Renderer(self.params)
        with _precision(self.float64):
            states = np.array(cartpole.get_obs(self._state), dtype=np.float64)
        return [self._renderer.frame(s) for s in states]

    def close_extras(self, **kwargs: Any) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


register_envs()

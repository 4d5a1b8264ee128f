"""The host side that both Gymnasium front-ends share: reset bounds, rendering with Gymnasium's
own CartPole renderer, render-mode checks and read-only state arrays."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import VectorEnv

from jaxcart.gym import ENV_ID

if TYPE_CHECKING:
    from jaxcart.core.cartpole import EnvParams


def reset_bounds(options: dict | None, params: EnvParams) -> tuple[float, float]:
    """Gymnasium's ``options={"low": ..., "high": ...}`` reset bounds, else the params' ones."""
    from gymnasium.envs.classic_control import utils

    return utils.maybe_parse_reset_bounds(options, params.reset_low, params.reset_high)


class Renderer:
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


def no_render_mode_warning(env: gym.Env | VectorEnv, make: str) -> None:
    spec_id = env.spec.id if env.spec is not None else ENV_ID
    gym.logger.warn(
        "You are calling render method without specifying any render mode. "
        "You can specify the render_mode at initialization, "
        f'e.g. gym.{make}("{spec_id}", render_mode="rgb_array")'
    )


def check_render_mode(render_mode: str | None, metadata: dict[str, Any]) -> None:
    if render_mode is not None and render_mode not in metadata["render_modes"]:
        raise ValueError(
            f"render_mode must be one of {metadata['render_modes']} or None, got {render_mode!r}"
        )


def read_only(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array

"""The host side that both Gymnasium front-ends share: ``CartPoleEnv``'s attributes, reset
bounds, rendering with Gymnasium's own CartPole renderer, render-mode checks and read-only state
arrays."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np

from jaxcart.gym import ENV_ID

if TYPE_CHECKING:
    from jaxcart.core.cartpole import EnvParams


def _param_attribute(name: str) -> property:
    def get(env: Any) -> Any:
        return getattr(env.params, name)

    def refuse(env: Any, value: Any) -> None:
        raise AttributeError(
            f"{name} is read-only on jaxcart's env (its physics is compiled from the params): "
            f'make the env with gym.make("{ENV_ID}", params=EnvParams({name}=...)) instead'
        )

    return property(get, refuse, doc=f"``params.{name}``, as ``CartPoleEnv.{name}``.")


class CartPoleAttributes:
    """Gymnasium ``CartPoleEnv``'s attributes (``x_threshold``, ``gravity``, ``total_mass``, ...)
    read from ``self.params``, so code written for ``gym.make("CartPole-v1").unwrapped`` runs
    on jaxcart's envs unchanged (read-only: setting one names the ``params=`` route), and the
    rendering both front-ends share."""

    params: EnvParams
    render_mode: str | None
    _renderer: Renderer | None = None

    gravity = _param_attribute("gravity")
    masscart = _param_attribute("masscart")
    masspole = _param_attribute("masspole")
    length = _param_attribute("length")
    force_mag = _param_attribute("force_mag")
    tau = _param_attribute("tau")
    kinematics_integrator = _param_attribute("kinematics_integrator")
    theta_threshold_radians = _param_attribute("theta_threshold_radians")
    x_threshold = _param_attribute("x_threshold")

    @property
    def total_mass(self) -> float:
        """``masspole + masscart``, derived from the params as ``step`` derives it."""
        return self.params.masspole + self.params.masscart

    @property
    def polemass_length(self) -> float:
        """``masspole * length``, derived from the params as ``step`` derives it."""
        return self.params.masspole * self.params.length

    @property
    def screen_width(self) -> int:
        return 600

    @property
    def screen_height(self) -> int:
        return 400

    def _frames(self, states: np.ndarray | None, make: str) -> list[np.ndarray] | None:
        """RGB frames ``[400, 600, 3]`` uint8 of ``states`` ``[n, 4]`` (None: no state yet);
        None, with Gymnasium's warning, without a render mode (``make``: how to set one)."""
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
            self._renderer = Renderer(self.params)
        return [self._renderer.frame(state.copy()) for state in states]

    def _close_renderer(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


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


def check_render_mode(render_mode: str | None, metadata: dict[str, Any]) -> None:
    if render_mode is not None and render_mode not in metadata["render_modes"]:
        raise ValueError(
            f"render_mode must be one of {metadata['render_modes']} or None, got {render_mode!r}"
        )


def read_only(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array

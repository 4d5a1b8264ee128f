"""Gymnasium's own ``CartPole-v1`` (its ``CartPoleEnv`` class, not jaxcart's adapter) with the
physics of a jaxcart :class:`~jaxcart.core.cartpole.EnvParams`: the reference every trained
policy is evaluated in.

Gymnasium's ``CartPoleEnv`` computes ``total_mass`` and ``polemass_length`` once, in its
constructor; setting ``masspole`` or ``length`` on an instance afterwards leaves them stale.
:func:`make_cartpole` sets the physics and then recomputes both, as the constructor would.
Gymnasium's ``length`` is half the pole's length, as jaxcart's is.
"""

from __future__ import annotations

from typing import Any

from jaxcart.core.cartpole import EnvParams, observation_space
from jaxcart.core.physics import CONTINUOUS

PHYSICS = (*CONTINUOUS, "kinematics_integrator")
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


__all__ = ["PHYSICS", "make_cartpole", "reset_options"]

"""Gymnasium's own ``CartPole-v1`` (its ``CartPoleEnv`` class, not jaxcart's adapter) with the
physics of a jaxcart :class:`~jaxcart.core.cartpole.EnvParams`: the reference every trained
policy is evaluated in.

Gymnasium's ``CartPoleEnv`` computes ``total_mass`` and ``polemass_length`` once, in its
constructor; setting ``masspole`` or ``length`` on an instance afterwards leaves them stale.
:func:`make_cartpole` sets the physics and then recomputes both, as the constructor would.
Gymnasium's ``length`` is half the pole's length, as jaxcart's is.
"""

from __future__ import annotations

from jaxcart.core.cartpole import PHYSICS, make_cartpole, reset_options

__all__ = ["PHYSICS", "make_cartpole", "reset_options"]

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
``jaxcart.gym.adapter:JaxCartPoleEnv``); the classes live in :mod:`jaxcart.gym.single_env` and
:mod:`jaxcart.gym.vector_env`.
"""

from jaxcart.gym import ENV_ID
from jaxcart.gym.single_env import JaxCartPoleEnv
from jaxcart.gym.vector_env import JaxCartPoleVectorEnv

__all__ = ["ENV_ID", "JaxCartPoleEnv", "JaxCartPoleVectorEnv"]

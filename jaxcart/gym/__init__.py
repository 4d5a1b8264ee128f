"""jaxcart's Gymnasium front-ends (:mod:`jaxcart.gym.adapter`, over the compiled programs of
:mod:`jaxcart.gym.kernels`) and Gymnasium's own CartPole with a run's physics
(:mod:`jaxcart.gym.stock`).

This ``__init__`` holds :func:`register`, which ``import jaxcart`` calls: Gymnasium's own
``gymnasium.register`` with string entry points, so it imports neither JAX nor the front-ends.
"""

from __future__ import annotations

ENV_ID = "jaxcart/CartPole-v1"


def register() -> None:
    """Registers ``jaxcart/CartPole-v1`` with Gymnasium (single and vector entry points, the
    ``TimeLimit`` and reward threshold of ``CartPole-v1``); idempotent, so a second call (a
    reloaded package) does not make Gymnasium warn about overriding it."""
    import gymnasium

    if ENV_ID in gymnasium.registry:
        return
    gymnasium.register(
        id=ENV_ID,
        entry_point="jaxcart.gym.adapter:JaxCartPoleEnv",
        vector_entry_point="jaxcart.gym.adapter:JaxCartPoleVectorEnv",
        max_episode_steps=500,
        reward_threshold=475.0,
    )

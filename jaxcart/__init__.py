"""jaxcart: CartPole-v1 and PPO in pure JAX.

Importing ``jaxcart`` is cheap: the JAX-backed names below load on first use.

Env API (pure functions over pytrees)::

    from jaxcart import EnvParams, reset, step
    obs, state = reset(key, EnvParams())
    obs, state, reward, terminated, truncated, info = step(key, state, action, params)

Training: ``python -m jaxcart.train``, or from Python :func:`run_new` / :func:`resume_run`
(:mod:`jaxcart.lifecycle`: a run directory like the command line's) and
:func:`jaxcart.trainer.train` (arrays only, no files); a trained policy: :func:`load_policy`.

Comparing runs over seeds: :func:`compare_runs` (``python -m jaxcart.compare``), with the
statistics in :mod:`jaxcart.stats` (:func:`iqm`, :func:`bootstrap_ci`,
:func:`probability_of_improvement`).
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

_LAZY = {
    "EnvParams": "jaxcart.env",
    "EnvState": "jaxcart.env",
    "reset": "jaxcart.env",
    "step": "jaxcart.env",
    "step_env": "jaxcart.env",
    "observation_space": "jaxcart.env",
    "action_space": "jaxcart.env",
    "describe": "jaxcart.env",
    "PPOConfig": "jaxcart.config",
    "ConfigError": "jaxcart.config",
    "preset": "jaxcart.config",
    "PRESETS": "jaxcart.config",
    "train": "jaxcart.trainer",
    "load_policy": "jaxcart.policy",
    "RunSpec": "jaxcart.lifecycle",
    "RunOptions": "jaxcart.lifecycle",
    "run_new": "jaxcart.lifecycle",
    "resume_run": "jaxcart.lifecycle",
    "JaxCartPoleEnv": "jaxcart.gym_adapter",
    "JaxCartPoleVectorEnv": "jaxcart.gym_adapter",
    "plot_runs": "jaxcart.plot",
    "compare_runs": "jaxcart.compare",
    "iqm": "jaxcart.stats",
    "bootstrap_ci": "jaxcart.stats",
    "probability_of_improvement": "jaxcart.stats",
    "render_gif": "jaxcart.render",
}

__all__ = sorted(_LAZY)


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'jaxcart' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))

"""jaxcart: CartPole-v1 and PPO in pure JAX.

Importing ``jaxcart`` is cheap: the JAX-backed names below load on first use.

Env API (pure functions over pytrees)::

    from jaxcart import EnvParams, reset, step
    obs, state = reset(key, EnvParams())
    obs, state, reward, terminated, truncated, info = step(key, state, action, params)

Gymnasium: ``import jaxcart`` registers ``"jaxcart/CartPole-v1"`` (:mod:`jaxcart.gym_adapter`),
so ``gymnasium.make("jaxcart/CartPole-v1")`` and ``gymnasium.make_vec(...)`` work.

Training: ``python -m jaxcart.train`` (``python -m jaxcart`` lists the commands), or from
Python :func:`run_new` / :func:`resume_run` (:mod:`jaxcart.lifecycle`: a run directory like
the command line's) and :func:`train_runs` (:func:`jaxcart.trainer.train`: arrays only, no
files); a trained policy: :func:`load_policy`. Call :func:`use_all_host_cores` first, before
any JAX work, to train on one CPU device per core as the command line does.

``jaxcart.train`` is the command-line module, never the training function, so that
``import jaxcart.train`` cannot change what ``jaxcart.train_runs`` is.

Comparing runs over seeds: :func:`compare_runs` (``python -m jaxcart.compare``), with the
statistics in :mod:`jaxcart.stats` (:func:`iqm`, :func:`bootstrap_ci`,
:func:`probability_of_improvement`).
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
import warnings

__version__ = "0.1.0"

_LAZY: dict[str, str | tuple[str, str]] = {
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
    "train_runs": ("jaxcart.trainer", "train"),
    "use_all_host_cores": "jaxcart.devices",
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
        module, attr = _LAZY[name] if isinstance(_LAZY[name], tuple) else (_LAZY[name], name)
        value = getattr(importlib.import_module(module), attr)
        globals()[name] = value
        return value
    if name == "train":  # the submodule, once imported, is an attribute and never gets here
        raise AttributeError(
            "jaxcart.train is the command-line module (import jaxcart.train); the training "
            "function is jaxcart.train_runs (jaxcart.trainer.train) or jaxcart.run_new"
        )
    raise AttributeError(f"module 'jaxcart' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


# Gymnasium registration. Importing Gymnasium costs about 0.2 s (NumPy included), a hundred
# times the rest of ``import jaxcart``, so jaxcart registers its env when Gymnasium is imported:
# at once if it already is, otherwise just after its import. Registering with string entry
# points loads nothing else.

_GYMNASIUM_ENV_ID = "jaxcart/CartPole-v1"


def _register_gymnasium_envs() -> None:
    """Registers ``jaxcart/CartPole-v1`` with Gymnasium (single and vector entry points, the
    ``TimeLimit`` and reward threshold of ``CartPole-v1``); idempotent."""
    import gymnasium

    if _GYMNASIUM_ENV_ID in gymnasium.registry:
        return
    gymnasium.register(
        id=_GYMNASIUM_ENV_ID,
        entry_point="jaxcart.gym_adapter:JaxCartPoleEnv",
        vector_entry_point="jaxcart.gym_adapter:JaxCartPoleVectorEnv",
        max_episode_steps=500,
        reward_threshold=475.0,
    )


class _RegisteringLoader:
    """Gymnasium's own loader, which then registers jaxcart's env."""

    def __init__(self, loader) -> None:
        self.loader = loader

    def create_module(self, spec):
        return self.loader.create_module(spec)

    def exec_module(self, module) -> None:
        # The module keeps Gymnasium's loader, as if this one had never been there.
        module.__loader__ = module.__spec__.loader = self.loader
        self.loader.exec_module(module)
        try:
            _register_gymnasium_envs()
        except Exception as error:  # a failed registration must not fail Gymnasium's import
            warnings.warn(
                f"jaxcart could not register {_GYMNASIUM_ENV_ID}: {error!r}", stacklevel=2
            )


class _GymnasiumImportHook:
    """A ``sys.meta_path`` finder that finds nothing itself: it hands ``gymnasium``'s spec,
    found by the other finders, a :class:`_RegisteringLoader`, then removes itself."""

    def find_spec(self, fullname, path=None, target=None):
        if fullname != "gymnasium":
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(fullname)
        if spec is not None and spec.loader is not None:
            spec.loader = _RegisteringLoader(spec.loader)
        return spec


if "gymnasium" in sys.modules:
    _register_gymnasium_envs()
elif not any(isinstance(f, _GymnasiumImportHook) for f in sys.meta_path):
    sys.meta_path.insert(0, _GymnasiumImportHook())

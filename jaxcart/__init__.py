"""jaxcart: CartPole-v1 and PPO in pure JAX.

Importing ``jaxcart`` loads no JAX: the JAX-backed names below load on first use.

Env API (pure functions over pytrees)::

    from jaxcart import EnvParams, reset, step
    obs, state = reset(key, EnvParams())
    obs, state, reward, terminated, truncated, info = step(key, state, action, params)

Gymnasium: ``import jaxcart`` registers ``"jaxcart/CartPole-v1"`` through Gymnasium's own
``gymnasium.register``, with string entry points into :mod:`jaxcart.gym.adapter`, so
``gymnasium.make("jaxcart/CartPole-v1")``, ``gymnasium.make("jaxcart:jaxcart/CartPole-v1")`` and
``gymnasium.make_vec(...)`` work. Importing Gymnasium for that (about 0.1 s) is all the import
does besides defining names: it installs no signal handler and no import hook. The commands
handle Ctrl-C in their ``main`` (:func:`jaxcart.cli.command_main`).

Training: ``python -m jaxcart.train`` (``python -m jaxcart`` lists the commands), or from
Python :func:`run_new` / :func:`resume_run` (:mod:`jaxcart.run.lifecycle`: a run directory like
the command line's) and :func:`train_runs` (:func:`jaxcart.engine.loop.train`: arrays only, no
files); a trained policy: :func:`load_policy`. Call :func:`use_all_host_cores` first, before
any JAX work, to train on one CPU device per core as the command line does.

``jaxcart.train`` is the command-line module, never the training function, so that
``import jaxcart.train`` cannot change what ``jaxcart.train_runs`` is.

Comparing runs over seeds: :func:`compare_runs` (``python -m jaxcart.compare``), with the
statistics in :mod:`jaxcart.analysis.stats` (:func:`iqm`, :func:`bootstrap_ci`,
:func:`probability_of_improvement`).
"""

import importlib

from jaxcart.gym import register as _register_gymnasium_env

__version__ = "0.1.0"

_LAZY: dict[str, str | tuple[str, str]] = {
    "EnvParams": "jaxcart.core.cartpole",
    "EnvState": "jaxcart.core.cartpole",
    "reset": "jaxcart.core.cartpole",
    "step": "jaxcart.core.cartpole",
    "step_env": "jaxcart.core.cartpole",
    "observation_space": "jaxcart.core.cartpole",
    "action_space": "jaxcart.core.cartpole",
    "describe": "jaxcart.env",
    "Env": "jaxcart.core.envs",
    "env_from_step": ("jaxcart.core.envs", "from_step"),
    "register_env": ("jaxcart.core.envs", "register"),
    "PPOConfig": "jaxcart.core.config",
    "ConfigError": "jaxcart.core.config",
    "preset": "jaxcart.core.config",
    "PRESETS": "jaxcart.core.config",
    "train_runs": ("jaxcart.engine.loop", "train"),
    "use_all_host_cores": "jaxcart.engine.devices",
    "load_policy": "jaxcart.rundir.policy",
    "RunSpec": "jaxcart.run.spec",
    "RunOptions": "jaxcart.run.spec",
    "run_new": "jaxcart.run.lifecycle",
    "resume_run": "jaxcart.run.lifecycle",
    "JaxCartPoleEnv": "jaxcart.gym.adapter",
    "JaxCartPoleVectorEnv": "jaxcart.gym.adapter",
    "plot_runs": "jaxcart.plot",
    "compare_runs": "jaxcart.compare",
    "iqm": "jaxcart.analysis.stats",
    "bootstrap_ci": "jaxcart.analysis.stats",
    "probability_of_improvement": "jaxcart.analysis.stats",
    "render_gif": "jaxcart.results.gif",
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
            "function is jaxcart.train_runs (jaxcart.engine.loop.train) or jaxcart.run_new"
        )
    raise AttributeError(f"module 'jaxcart' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


# Gymnasium's documented route: a package that provides an env registers it when imported, so
# that ``import jaxcart`` then ``gymnasium.make("jaxcart/CartPole-v1")`` works, and so does
# ``gymnasium.make("jaxcart:jaxcart/CartPole-v1")`` (Gymnasium imports the module before the
# colon). The entry points are strings: neither JAX nor the front-ends load until an env is made.
_register_gymnasium_env()

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

_LAZY_FROM = {
    "jaxcart.core.cartpole": (
        "EnvParams",
        "EnvState",
        "reset",
        "step",
        "step_env",
        "observation_space",
        "action_space",
    ),
    "jaxcart.env": ("describe",),
    "jaxcart.core.envs": ("Env", "env_from_step", "register_env"),
    "jaxcart.core.config": ("PPOConfig", "ConfigError", "preset", "PRESETS"),
    "jaxcart.engine.loop": ("train_runs",),
    "jaxcart.engine.devices": ("use_all_host_cores",),
    "jaxcart.rundir.policy": ("load_policy",),
    "jaxcart.run.spec": ("RunSpec", "RunOptions"),
    "jaxcart.run.lifecycle": ("run_new", "resume_run"),
    "jaxcart.gym.adapter": ("JaxCartPoleEnv", "JaxCartPoleVectorEnv"),
    "jaxcart.plot": ("plot_runs",),
    "jaxcart.compare": ("compare_runs",),
    "jaxcart.analysis.stats": ("iqm", "bootstrap_ci", "probability_of_improvement"),
    "jaxcart.results.gif": ("render_gif",),
}
"""Each module and the names it gives the package, loaded on first use."""
_RENAMED = {"env_from_step": "from_step", "register_env": "register", "train_runs": "train"}
"""Names the package gives under another name than their module's."""
_LAZY = {name: module for module, names in _LAZY_FROM.items() for name in names}

__all__ = sorted(_LAZY)


def __getattr__(name: str):
    if name in _LAZY:
        module = importlib.import_module(_LAZY[name])
        value = getattr(module, _RENAMED.get(name, name))
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

"""jaxcart: CartPole-v1 and PPO in pure JAX.

Importing ``jaxcart`` is cheap: the JAX-backed names below load on first use.

Env API (pure functions over pytrees)::

    from jaxcart import EnvParams, reset, step
    obs, state = reset(key, EnvParams())
    obs, state, reward, terminated, truncated, info = step(key, state, action, params)

Gymnasium: ``import jaxcart`` registers ``"jaxcart/CartPole-v1"`` (:mod:`jaxcart.gym.adapter`),
so ``gymnasium.make("jaxcart/CartPole-v1")`` and ``gymnasium.make_vec(...)`` work.

Training: ``python -m jaxcart.train`` (``python -m jaxcart`` lists the commands), or from
Python :func:`run_new` / :func:`resume_run` (:mod:`jaxcart.run.lifecycle`: a run directory like
the command line's) and :func:`train_runs` (:func:`jaxcart.engine.trainer.train`: arrays only, no
files); a trained policy: :func:`load_policy`. Call :func:`use_all_host_cores` first, before
any JAX work, to train on one CPU device per core as the command line does.

``jaxcart.train`` is the command-line module, never the training function, so that
``import jaxcart.train`` cannot change what ``jaxcart.train_runs`` is.

Comparing runs over seeds: :func:`compare_runs` (``python -m jaxcart.compare``), with the
statistics in :mod:`jaxcart.analysis.stats` (:func:`iqm`, :func:`bootstrap_ci`,
:func:`probability_of_improvement`).
"""

# The first call of the package installs its start-up signal handler. A signal is handled at
# the first check CPython makes after it arrives, and every call is such a check: whatever
# runs before this install could meet a Ctrl-C with a traceback. The imports below are of
# modules CPython has already loaded (``_signal`` is the C half of ``signal``, whose own import
# takes milliseconds), so they run no Python code and make no such check. No
# ``from __future__ import annotations`` here for the same reason: it is an import.
import _signal
import os
import sys

_SIGNAL_NAMES = {_signal.SIGINT: "SIGINT", _signal.SIGTERM: "SIGTERM"}


def _started_as_a_command() -> bool:
    """Whether this process is ``python -m jaxcart[.COMMAND]`` or a ``jaxcart`` script."""
    argv = getattr(sys, "orig_argv", [])
    if "-m" in argv[:-1]:
        return argv[argv.index("-m") + 1].split(".")[0] == "jaxcart"
    return os.path.basename(sys.argv[0] if sys.argv else "") in ("jaxcart", "jaxcart-train")


def _exit_while_starting(signum: int, frame: object) -> None:
    """A command ends with one line, never a traceback from inside an import. Imported by
    other code, the package behaves as if it had installed nothing: the handler it replaced
    runs (Python's own raises ``KeyboardInterrupt`` for SIGINT), or the signal's default
    action is taken."""
    if not _started_as_a_command():
        previous = globals().get("_PREVIOUS", {}).get(signum)
        if callable(previous):
            previous(signum, frame)
        elif signum == _signal.SIGINT and previous is None:
            raise KeyboardInterrupt
        elif previous != _signal.SIG_IGN:
            _signal.signal(signum, _signal.SIG_DFL)
            os.kill(os.getpid(), signum)
        return
    name = _SIGNAL_NAMES.get(signum, str(signum))
    os.write(2, f"\ninterrupted ({name}) while starting; nothing was written\n".encode())
    os._exit(128 + signum)


try:
    _PREVIOUS = {
        _signal.SIGINT: _signal.signal(_signal.SIGINT, _exit_while_starting),
        _signal.SIGTERM: _signal.signal(_signal.SIGTERM, _exit_while_starting),
    }
except ValueError:  # imported in another thread: only the main thread may set handlers
    _PREVIOUS = {}
if _PREVIOUS and not _started_as_a_command():
    # Imported by other code: leave its signal handling as it was (a handler set outside
    # Python reads back as None and cannot be put back; the one above then stays, and it does
    # what Python's defaults do). A command keeps the handler through its imports (most of a
    # second) and then installs its own handling.
    for _sig, _previous in _PREVIOUS.items():
        if _previous is not None:
            _signal.signal(_sig, _previous)

import importlib  # noqa: E402

__version__ = "0.1.0"

_LAZY: dict[str, str | tuple[str, str]] = {
    "EnvParams": "jaxcart.core.env",
    "EnvState": "jaxcart.core.env",
    "reset": "jaxcart.core.env",
    "step": "jaxcart.core.env",
    "step_env": "jaxcart.core.env",
    "observation_space": "jaxcart.core.env",
    "action_space": "jaxcart.core.env",
    "describe": "jaxcart.env",
    "PPOConfig": "jaxcart.core.config",
    "ConfigError": "jaxcart.core.config",
    "preset": "jaxcart.core.config",
    "PRESETS": "jaxcart.core.config",
    "train_runs": ("jaxcart.engine.trainer", "train"),
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
    "render_gif": "jaxcart.gym.render",
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
            "function is jaxcart.train_runs (jaxcart.engine.trainer.train) or jaxcart.run_new"
        )
    raise AttributeError(f"module 'jaxcart' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


# Gymnasium registration. Importing Gymnasium costs about 0.2 s (NumPy included), a hundred
# times the rest of ``import jaxcart``, so jaxcart registers its env when Gymnasium is imported:
# at once if it already is, otherwise just after its import. Registering with string entry
# points loads nothing else.

from jaxcart.gym import register_when_gymnasium_loads  # noqa: E402

register_when_gymnasium_loads()

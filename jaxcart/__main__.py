"""``python -m jaxcart`` (``jaxcart``): the commands in a few lines; ``python -m jaxcart
COMMAND [ARGS]`` runs one (the same as ``python -m jaxcart.COMMAND [ARGS]``)."""

from __future__ import annotations

import difflib
import importlib
import sys
from typing import NoReturn

from jaxcart import cli
from jaxcart.cli import EXIT_USAGE, VERSION_TEXT
from jaxcart.engine import devices

COMMANDS = {
    "train": "train PPO, evaluate every seed in Gymnasium, save a run directory",
    "evaluate": "greedy Gymnasium evaluation of a run's seeds; --gif renders one to a GIF",
    "plot": "learning curves of runs and sweeps as an image",
    "compare": "IQM and probability of improvement across runs, with intervals",
    "tune": "hyperparameter search on Optuna, trials x seeds in one program",
    "export": "one seed's policy as a Stable-Baselines3 zip or an ONNX model",
    "sb3": "Stable-Baselines3's own PPO (PyTorch) trained into a run directory",
    "env": "CartPole's spaces, bounds and limits",
}


def overview() -> str:
    """What ``python -m jaxcart`` prints: each command and what it does."""
    width = max(map(len, COMMANDS))
    lines = [
        f"{VERSION_TEXT}: CartPole-v1 and PPO in pure JAX.",
        "",
        "commands (python -m jaxcart.COMMAND --help for each one's options):",
        *(f"  python -m jaxcart.{name:<{width}}  {text}" for name, text in COMMANDS.items()),
        "",
        "python -m jaxcart COMMAND [ARGS] (or the installed jaxcart COMMAND [ARGS]) is the",
        "same as python -m jaxcart.COMMAND [ARGS]; jaxcart-train is python -m jaxcart.train.",
        "e.g. python -m jaxcart.train --preset fast --num-seeds 8 --out runs/fast8",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Prints the overview (no arguments, ``--help``), the version, or runs a command."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(overview())
        return 0
    if argv[0] == "--version":
        print(VERSION_TEXT)
        return 0
    command, rest = argv[0], argv[1:]
    if command not in COMMANDS:
        close = difflib.get_close_matches(command, list(COMMANDS), n=1)
        hint = f"did you mean {close[0]}? " if close else ""
        print(
            f"error: unknown command {command!r}; {hint}choose one of {', '.join(COMMANDS)} "
            "(see python -m jaxcart --help)",
            file=sys.stderr,
        )
        return EXIT_USAGE
    module = importlib.import_module(f"jaxcart.{command}")
    if command in ("train", "tune"):  # one CPU device per core, as python -m jaxcart.COMMAND
        devices.use_all_host_cores()
    return module.main(rest)


def cli_main(argv: list[str] | None = None) -> NoReturn:
    """The process entry (the ``jaxcart`` script, ``python -m jaxcart``): :func:`main`
    through :func:`jaxcart.cli.command_main`; exits."""
    cli.command_main(main, argv)


if __name__ == "__main__":
    cli_main()

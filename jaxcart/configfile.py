"""``python -m jaxcart.train --config FILE``: options from a file, read as command-line tokens.

Three kinds of file, told apart by their contents:

- **jaxcart's own** (TOML, YAML or JSON): a mapping whose keys are the command's options, spelled
  either way (``learning_rate`` or ``learning-rate``, ``num_seeds``, ``preset``, ``sweep``, ...).
  A key that is no option is an error, one line each (with a "did you mean").
- **rl-zoo3's** ``hyperparams/ppo.yml``: a mapping of env ids to hyperparameters. The entry
  of the env the command line trains (``--env``, else its ``--preset``'s: CartPole-v1 by
  default) is read through Stable-Baselines3's names (:data:`jaxcart.cli.ALIASES`:
  ``n_envs``, ``n_steps``, ``batch_size``, ``n_epochs``, ``n_timesteps``, ``clip_range``, ...),
  a ``lin_X`` learning rate or clip range as ``X`` annealed linearly to 0 (``--anneal-lr``,
  ``--anneal-clip``) on SB3's progress (``--anneal-progress sb3``: rl-zoo3's
  ``linear_schedule(X)`` is ``progress_remaining * X``, and SB3 updates its progress after
  each rollout, before the update); each key jaxcart has no equivalent for gets one line and
  is ignored.
- **a run's** ``config.json`` (or the run directory): its preset, seeds, sweep, wave width,
  evaluation episodes and every config field, so the run trains again as it did (a new
  ``--out``).

The file becomes tokens placed before the command line's, so an option typed on the command
line overrides the file's.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import stat
import sys
import tomllib
from pathlib import Path

from jaxcart import cli

ZOO_ENV_ID = re.compile(r"[\w/.:-]+-v\d+")
"""An rl-zoo3 file's top-level keys are env ids (``CartPole-v1``, ``ALE/Pong-v5``)."""
NOT_FROM_FILE = ("config", "help", "version")
MAX_FILE_BYTES = 1 << 20


def read_config_file(
    path: Path, parser: argparse.ArgumentParser, env_id: str
) -> tuple[list[str], list[str]]:
    """``path`` (TOML, YAML, JSON, or a run directory) as tokens for ``parser``, and its notes
    (one line per ignored key); ``env_id``: the env whose entry an rl-zoo3 file gives.

    Raises:
        cli.UsageError: unreadable, not a mapping, no ``env_id`` entry in an rl-zoo3 file,
            or keys that are no option (one line each).
    """
    data = _load(path)
    if not isinstance(data, dict):
        raise cli.UsageError(f"--config {path}: expected a mapping of options at the top level")
    notes: list[str] = []
    zoo = any(isinstance(v, dict) and ZOO_ENV_ID.fullmatch(str(k)) for k, v in data.items())
    if "format_version" in data and isinstance(data.get("config"), dict):  # a run's config.json
        data, zoo = _run_values(data, path, notes), False
    elif zoo:
        if not isinstance(data.get(env_id), dict):
            envs = ", ".join(k for k in data if ZOO_ENV_ID.fullmatch(str(k)))
            raise cli.UsageError(f"--config {path}: no {env_id} entry (it has {envs})")
        data = _zoo_values(data[env_id], path, notes)
    return _tokens_of(data, path, parser, notes, zoo), notes


def _run_values(data: dict, path: Path, notes: list[str]) -> dict:
    """A run's ``config.json`` as the options that train it again: read as ``--resume``
    reads it (:meth:`~jaxcart.run.spec.RunSpec.from_record`), then spelled as options
    (:meth:`~jaxcart.run.spec.RunSpec.options`), with its wave width and evaluation episodes."""
    from jaxcart.core.config import ConfigError, PPOConfig
    from jaxcart.run.spec import RunSpec

    try:
        spec = RunSpec.from_record({**data, "config": PPOConfig.from_dict(data["config"])})
        values = spec.options()
    except (ConfigError, TypeError, ValueError) as exc:
        raise cli.UsageError(f"--config {path}: {exc}") from None
    values.update({k: data[k] for k in ("wave_size", "eval_episodes") if data.get(k) is not None})
    if data.get("lr_schedule"):
        notes.append(
            f"note: --config {path}: its lr_schedule (from a --resume that extended it) is "
            "not reproduced; the learning rate anneals over the whole run"
        )
    return values


def _load(path: Path) -> object:
    """The file's data, by its suffix (a directory: its ``config.json``, read as every file of
    a run directory is: no link followed, a regular file only)."""
    raw = _run_config_bytes(path) if path.is_dir() else None
    if raw is not None:
        path = path / "config.json"
    suffix = path.suffix.lower()
    if suffix not in (".toml", ".yml", ".yaml", ".json"):
        raise cli.UsageError(f"--config {path}: expected a .toml, .yml, .yaml or .json file")
    if raw is None:
        try:  # O_NONBLOCK: a FIFO is refused below instead of blocking the open
            fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
        except OSError as exc:
            raise cli.UsageError(f"--config {path}: {exc.strerror or exc}") from None
        with os.fdopen(fd, "rb") as f:
            if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):
                raise cli.UsageError(f"--config {path}: not a regular file")
            raw = f.read(MAX_FILE_BYTES + 1)
    if len(raw) > MAX_FILE_BYTES:
        raise cli.UsageError(f"--config {path}: larger than {MAX_FILE_BYTES:,} bytes")
    if suffix in (".yml", ".yaml"):
        try:
            import yaml
        except ImportError:
            raise cli.UsageError(
                f"--config {path}: reading YAML needs PyYAML (pip install pyyaml)"
            ) from None
    try:
        if suffix == ".toml":
            return tomllib.loads(raw.decode())
        return json.loads(raw) if suffix == ".json" else yaml.safe_load(raw)
    except Exception as exc:  # each parser has its own error class: all mean "not readable"
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise cli.UsageError(f"--config {path}: not valid {suffix[1:].upper()}: {first}") from None


def _run_config_bytes(run_dir: Path) -> bytes:
    """A run directory's ``config.json`` through the run directory's own reader."""
    from jaxcart.rundir import files, layout

    try:
        with files.opened(run_dir) as directory:
            return files.read_bytes(directory / layout.CONFIG_FILE, MAX_FILE_BYTES)
    except files.RunDirError as exc:
        raise cli.UsageError(f"--config {run_dir}: {exc}") from None


def _zoo_values(entry: dict, path: Path, notes: list[str]) -> dict:
    """An rl-zoo3 entry's values, with its schedules and policy read as jaxcart's."""
    values = {}
    for key, value in entry.items():
        if key == "policy":
            if value != "MlpPolicy":
                notes.append(
                    f"note: --config {path}: policy {value!r} ignored; jaxcart trains an MLP"
                )
        elif key in ("learning_rate", "clip_range") and isinstance(value, str):
            match = re.fullmatch(r"lin_(.+)", value.strip())
            values[key] = match[1] if match else value
            if match:
                values["anneal_lr" if key == "learning_rate" else "anneal_clip"] = True
                values["anneal_progress"] = "sb3"
        else:
            values[key] = value
    return values


def action_of(key: str, parser: argparse.ArgumentParser, zoo: bool) -> argparse.Action | None:
    """The parser's action for a file's key: its own option, or (rl-zoo3) an SB3 alias."""
    actions = parser._option_string_actions  # argparse has no public map of its options
    name = key.replace("_", "-").lower()
    name = {"env-params": "env-param"}.get(name, name)  # config.json's name for the option
    if name in NOT_FROM_FILE:
        return None
    flag = f"--{name}"
    if flag not in actions and zoo:
        flag = next((f for f in cli.ALIASES.get(name, ()) if f in actions), flag)
    return actions.get(flag)


def _tokens_of(
    values: dict, path: Path, parser: argparse.ArgumentParser, notes: list[str], zoo: bool
) -> list[str]:
    """Each key's tokens; unknown keys are notes (rl-zoo3) or errors."""
    tokens, unknown = [], []
    for key, value in values.items():
        action = action_of(str(key), parser, zoo)
        if action is None and zoo:
            notes.append(f"note: --config {path}: {key} is not supported by jaxcart; ignored")
        elif action is None:
            hint = cli.suggestion(f"--{key}", list(parser._option_string_actions))
            unknown.append(
                f"{key!r} is no option of this command"
                + (f" (did you mean {hint}?)" if hint else "")
            )
        else:
            try:
                tokens += option_tokens(action, value)
            except (ValueError, cli.UsageError) as exc:
                raise cli.UsageError(f"--config {path}: {exc}") from None
    if unknown:
        raise cli.UsageError("\nerror: ".join(f"--config {path}: {u}" for u in unknown))
    return tokens


def option_tokens(action: argparse.Action, value: object) -> list[str]:
    """The command-line tokens that give ``action`` the file's ``value``."""
    flag = action.option_strings[0]
    if action.nargs == 0:  # a switch: --name/--no-name, or store_true
        if not isinstance(value, bool):
            raise ValueError(f"{flag} in a config file takes true or false, got {value!r}")
        if isinstance(action, argparse.BooleanOptionalAction):
            return [flag if value else "--no-" + flag[2:]]
        return [flag] if value else []
    if isinstance(action, argparse._AppendAction):
        if isinstance(value, dict):  # sweep = {learning_rate = [1e-3, 5e-3]}
            value = [f"{k}={cli.spelled(v)}" for k, v in value.items()]
        return [t for v in (value if isinstance(value, list) else [value]) for t in (flag, str(v))]
    return [f"{flag}={cli.spelled(value)}"]


def parse_with_config(parser: argparse.ArgumentParser, argv: list[str]) -> argparse.Namespace:
    """``argv`` parsed after the ``--config`` file's options when it names one, so that the
    command line's override the file's; the file's ignored keys are printed, a line each, and
    a bad value in the file is named as coming from it."""
    tokens = cli.join_negative_values(argv)
    args = parser.parse_args(tokens)
    if args.config is None:
        return args
    from jaxcart.core.config import PRESETS, PPOConfig

    chosen = PRESETS.get(getattr(args, "preset", None) or "sb3", {}).get("env", PPOConfig.env)
    from_file, notes = read_config_file(args.config, parser, vars(args).get("env", chosen))
    for note in notes:
        print(note, file=sys.stderr)
    try:
        parser.parse_args(from_file)  # a bad value names the file it came from
    except cli.UsageError as exc:
        raise cli.UsageError(f"--config {args.config}: {exc}") from None
    return parser.parse_args(from_file + tokens)

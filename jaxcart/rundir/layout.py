"""Every name jaxcart gives to what it writes: a run directory's files and subdirectories, the
entries inside its tree files, and the default places of plots and comparisons.

Layout of ``RUN_DIR``:

- ``config.json``: the PPO config, preset, seeds, device count and package versions;
- ``metrics.csv``: one row per seed and iteration, SB3 metric names as columns;
- ``params.npz``: every seed's network parameters, a tree file (:mod:`jaxcart.rundir.files`) with
  arrays ``[num_seeds, ...]`` keyed by path (``params/actor/hidden_0/kernel``, ...);
- ``evaluation.json``: per-seed greedy evaluation in Gymnasium's CartPole-v1 (and in jaxcart);
- ``checkpoint.npz``: the full training state while a run is unfinished
  (:mod:`jaxcart.rundir.directory`);
- ``metrics.stream``: the metrics so far of the wave being trained, appended chunk by chunk
  beside the checkpoint (:class:`jaxcart.rundir.files.MetricsStream`);
- ``waves/wave-00003.npz``: one block of results per finished wave of a run trained in waves
  (:class:`jaxcart.rundir.directory.Block`);
- ``manifest.json``: the digest of every finished file, checked by every reader
  (:class:`jaxcart.rundir.files.Manifest`);
- ``.lock``: held by the process that trains it (:class:`jaxcart.rundir.files.RunLock`);
- ``policy-seed0.zip`` / ``.onnx``: one seed's policy, where ``python -m jaxcart.export``
  puts it without ``--out`` (:func:`export_file`); no reader looks at it;
- ``sb3-plan.json`` and ``sb3-seeds/seed-314159.npz``: while ``python -m jaxcart.sb3`` trains,
  what it was asked for and each seed it has finished (removed once the run is written);
- a sweep's directory holds ``config.json``, ``sweep.json`` and one run directory per
  combination, ``combo-000``, ``combo-001``, ...

An evaluation (``python -m jaxcart.evaluate RUN --out DIR``) is a run directory without
training: ``config.json`` (the run's config, the physics it was evaluated on as
``env_params``, the run itself under ``evaluation_of``), ``evaluation.json`` and
``manifest.json``. With ``--sweep env.NAME=...`` it is a sweep of them (``sweep.json``,
``combo-000/``, ...) and ``robustness.png``.

Nothing here reads or writes a file's contents; :mod:`jaxcart.rundir.files` writes,
:mod:`jaxcart.rundir.reader` reads.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

FORMAT_VERSION = 1
"""Of ``config.json``."""
CHECKPOINT_FORMAT = 3
"""Of ``checkpoint.npz``: a checkpoint of another format is refused, never guessed at (3: the
metrics so far moved out of it, into ``metrics.stream``)."""
CONFIG_FILE = "config.json"
METRICS_FILE = "metrics.csv"
PARAMS_FILE = "params.npz"
PARAMS_BEST_FILE = "params_best.npz"
"""Every seed's best policy by the periodic evaluation (``PPOConfig.keep_best``)."""
POLICY_FILES = {"final": PARAMS_FILE, "best": PARAMS_BEST_FILE}
"""Which parameters a reader takes (``--policy final|best``)."""
EVALUATION_FILE = "evaluation.json"
EVALUATION_OF_KEY = "evaluation_of"
"""Of an evaluation's ``config.json``: the run evaluated (``run``, ``combination``,
``policy``, ``trained_physics``); its presence says the directory holds no training."""
SWEEP_FILE = "sweep.json"
CHECKPOINT_FILE = "checkpoint.npz"
METRICS_STREAM_FILE = "metrics.stream"
LOCK_FILE = ".lock"
MANIFEST_FILE = "manifest.json"
"""Every finished file's digest (:class:`jaxcart.rundir.files.Manifest`), rewritten after each."""
WAVES_DIR = "waves"
SB3_PLAN_FILE = "sb3-plan.json"
SB3_SEEDS_DIR = "sb3-seeds"
GROUPS_FILE = "groups.json"
"""A structural sweep's shape groups (each a run directory ``group-000/``, ...) and their
combinations ranked together."""
GROUP_GLOB = "group-[0-9][0-9][0-9]*"
COMBO_GLOB = "combo-[0-9][0-9][0-9]*"
"""Matches the combination directories of a sweep (``combo-000``, ..., ``combo-1000``)."""
DIGEST_KEY = "digest"
"""Of ``config.json`` and wave files: ``sha256:<hex>`` of their contents, checked on resume."""
WRITE_PROBE = ".write-test"
"""Written and removed at once to check that a new run directory is writable."""
TEMPORARY_SUFFIX = ".tmp"
"""A file being written is ``.<name>.<random>.tmp`` beside its target until renamed."""

METRICS_INDEX_COLUMNS = ("seed_index", "iteration", "env_steps")
"""The first columns of ``metrics.csv``; the metrics follow under their own names."""

# Entries of the tree files (names of arrays inside the .npz, before ``/<tree path>``).
CHECKPOINT_STATE = "state/"
CHECKPOINT_PARAMS = "state/runners/params/"
"""Where a checkpoint keeps the parameters, leaves ``[R, ...]``."""
CHECKPOINT_BEST_PARAMS = "state/runners/best/params/"
"""Where a checkpoint keeps the best policies so far (``PPOConfig.keep_best``)."""
BLOCK_PARAMS = "params/"
BLOCK_BEST_PARAMS = "params_best/"
BLOCK_METRICS = "metrics/"

CURVES_FILE = "curves.png"
"""``python -m jaxcart.plot RUN_DIR`` draws one run into ``RUN_DIR/curves.png``..."""
PLOT_COMPARISON_FILE = "comparison.png"
"""...and several into ``comparison.png`` in the current directory."""
ROBUSTNESS_FIGURE_FILE = "robustness.png"
"""``python -m jaxcart.evaluate --sweep ... --out DIR``: the return against the swept value."""
COMPARE_FILE = "compare.json"
COMPARE_FIGURE_FILE = "compare.png"
COMPARE_CURVES_FILE = "curves.csv"
"""``python -m jaxcart.compare`` writes all three into its ``--out`` directory (the CSV: every
compared seed's learning curve, ``run,seed,env_steps,ep_rew_mean``)."""


def export_file(
    run_dir: str | os.PathLike,
    suffix: str,
    seed_index: int,
    combination: int | None = None,
    policy: str = "final",
) -> Path:
    """Where ``python -m jaxcart.export`` writes without ``--out``: into the run directory,
    one file per seed, combination and policy, so that no export replaces another's:
    ``RUN_DIR/policy-seed0.zip``, ``policy-best-combo003-seed1.onnx``."""
    best = "-best" if policy == "best" else ""
    combo = "" if combination is None else f"-combo{combination:03d}"
    return Path(run_dir) / f"policy{best}{combo}-seed{seed_index}{suffix}"


def combo_dir(sweep_dir: str | os.PathLike, combo: int) -> Path:
    """The run directory of one combination of a sweep."""
    return Path(sweep_dir) / f"combo-{combo:03d}"


def group_dir(sweep_dir: str | os.PathLike, group: int) -> Path:
    """The run directory of one shape group of a structural sweep."""
    return Path(sweep_dir) / f"group-{group:03d}"


def wave_file(run_dir: str | os.PathLike, wave: int) -> Path:
    """The block file of one finished wave: ``RUN_DIR/waves/wave-00003.npz``."""
    return Path(run_dir) / WAVES_DIR / f"wave-{wave:05d}.npz"


def sb3_seed_file(run_dir: str | os.PathLike, seed: int) -> Path:
    """Where ``python -m jaxcart.sb3`` keeps one finished seed until the run is written."""
    return Path(run_dir) / SB3_SEEDS_DIR / f"seed-{seed}.npz"


def temporary_prefix(path: str | os.PathLike) -> str:
    """The start of the name of a temporary file written beside ``path``: ``.<name>.``."""
    return f".{Path(path).name}."


def is_temporary(path: str | os.PathLike) -> bool:
    """A leftover of a write that never finished (see :data:`TEMPORARY_SUFFIX`)."""
    name = Path(path).name
    return name.startswith(".") and name.endswith(TEMPORARY_SUFFIX)


def fresh_dir(base: str | os.PathLike) -> Path:
    """``base``, or ``base-2``, ``base-3``, ... : the first that does not exist yet."""
    base = Path(base)
    out, n = base, 1
    while out.exists():
        n += 1
        out = base.with_name(f"{base.name}-{n}")
    return out


def default_run_dir(preset_name: str) -> Path:
    """``runs/<preset>-<YYYYmmdd-HHMMSS>``, suffixed when that exists already."""
    return fresh_dir(Path("runs") / f"{preset_name}-{time.strftime('%Y%m%d-%H%M%S')}")


def default_compare_dir(beside: Path) -> Path:
    """``compare-<YYYYmmdd-HHMMSS>`` in ``beside`` (the folder holding the compared runs, such
    as ``runs/``, so that nothing lands in the current directory), suffixed when it exists."""
    return fresh_dir(Path(beside) / f"compare-{time.strftime('%Y%m%d-%H%M%S')}")

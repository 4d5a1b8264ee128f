"""A run directory's outputs, written from blocks of consecutive runs.

A :class:`Block` holds what training and evaluation produced for runs ``[start, stop)``:
parameters, metrics, divergences and evaluation returns. A run trained in one go is one
block in memory; a run trained in waves keeps one block file per finished wave
(``waves/wave-00003.npz``) and the outputs are streamed from them, so that no step holds
more than one wave in memory: ``metrics.csv``, ``params.npz`` and ``evaluation.json``, for
the whole run or for one combination of a sweep.
"""

from __future__ import annotations

import csv
import json
import zipfile
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass

import numpy as np

from jaxcart.core.envs import DEFAULT_ENV
from jaxcart.core.solved import is_solved, solved_definition
from jaxcart.rundir import files, layout
from jaxcart.rundir.layout import BLOCK_BEST_PARAMS, BLOCK_METRICS, BLOCK_PARAMS

Digest = Callable[[str], None] | None
"""Called with a finished file's digest before it is renamed into place (its manifest)."""


BEST_ARRAYS = ("best_gym_returns", "best_iteration", "best_score")
"""What a block of a run that keeps its best policies holds of them: their Gymnasium returns
``[n, episodes]``, the (1-based) iteration each was evaluated at and its eval/mean_return
``[n]``."""


@dataclass
class Block:
    """Results of runs ``[start, stop)``: arrays with a leading (or, for metrics, second)
    axis of ``stop - start`` runs."""

    start: int
    stop: int
    params: dict[str, np.ndarray]  # flattened names -> [n, ...]
    metrics: dict[str, np.ndarray]  # name -> [iterations, n]
    diverged_at: np.ndarray  # [n]
    gym_returns: np.ndarray  # [n, episodes]
    jax_returns: np.ndarray  # [n, episodes]
    timing: dict[str, float]
    best_params: dict[str, np.ndarray] | None = None  # keep_best's, flattened -> [n, ...]
    best: dict[str, np.ndarray] | None = None  # keep_best's BEST_ARRAYS

    def save(self, path: files.Target) -> None:
        arrays = {BLOCK_PARAMS + k: v for k, v in self.params.items()}
        arrays |= {BLOCK_BEST_PARAMS + k: v for k, v in (self.best_params or {}).items()}
        arrays |= self.best or {}
        arrays |= {BLOCK_METRICS + k: np.asarray(v) for k, v in self.metrics.items()}
        arrays |= {
            "diverged_at": self.diverged_at,
            "gym_returns": self.gym_returns,
            "jax_returns": self.jax_returns,
        }
        meta = {"start": self.start, "stop": self.stop, **self.timing}
        files.save_tree(path, arrays, {**meta, layout.DIGEST_KEY: files.arrays_digest(arrays)})

    @classmethod
    def load(cls, path: files.Target) -> Block:
        arrays, meta = files.load_tree(path)
        take = lambda prefix: {
            k[len(prefix) :]: v for k, v in arrays.items() if k.startswith(prefix)
        }
        timing = {k: v for k, v in meta.items() if k not in ("start", "stop", layout.DIGEST_KEY)}
        return cls(
            int(meta["start"]),
            int(meta["stop"]),
            take(BLOCK_PARAMS),
            take(BLOCK_METRICS),
            arrays["diverged_at"],
            arrays["gym_returns"],
            arrays["jax_returns"],
            timing,
            take(BLOCK_BEST_PARAMS) or None,
            {k: arrays[k] for k in BEST_ARRAYS if k in arrays} or None,
        )


def _overlap(start: int, stop: int, runs: range) -> slice | None:
    """The slice of a block of runs ``[start, stop)`` that holds some of ``runs``."""
    lo, hi = max(start, runs.start), min(stop, runs.stop)
    return slice(lo - start, hi - start) if lo < hi else None


def overlapping(blocks: list, runs: range) -> Iterator[tuple[Block, slice]]:
    """Each block that holds some of ``runs`` (loaded when it is a path), with the slice of
    its axis that does."""
    for item in blocks:
        block = item if isinstance(item, Block) else Block.load(item)
        take = _overlap(block.start, block.stop, runs)
        if take is not None:
            yield block, take


def _param_slices(blocks: list, runs: range, name: str, best: bool = False) -> Iterator[np.ndarray]:
    """One parameter array of each block that holds some of ``runs``, sliced to them (the
    best policies' with ``best``); a block file is read for that array alone."""
    for item in blocks:
        if isinstance(item, Block):
            take = _overlap(item.start, item.stop, runs)
            if take is not None:
                yield (item.best_params if best else item.params)[name][take]
            continue
        meta = files.read_meta(item)
        take = _overlap(int(meta["start"]), int(meta["stop"]), runs)
        if take is not None:
            with files.open_tree(item) as raw, np.load(raw, allow_pickle=False) as data:
                yield data[(BLOCK_BEST_PARAMS if best else BLOCK_PARAMS) + name][take]


def metrics_csv_rows(
    metrics: dict[str, np.ndarray], batch_size: int, first_seed: int = 0, runs: slice = slice(None)
) -> Iterator[list]:
    """The rows of ``metrics.csv`` for the runs ``runs`` of metrics ``[iterations, R]``,
    numbered from ``first_seed``: seed by seed, iteration by iteration."""
    names = list(metrics)
    columns = [np.asarray(metrics[n])[:, runs] for n in names]
    iterations, num_seeds = columns[0].shape
    for s in range(num_seeds):
        for i in range(iterations):
            row = [float(c[i, s]) for c in columns]
            yield [first_seed + s, i + 1, (i + 1) * batch_size, *row]


def _write_csv(path: files.Target, parts: Iterable, batch_size: int, on_digest: Digest) -> None:
    """``metrics.csv`` from ``(metrics [iterations, R], first seed index, runs)`` parts."""
    with files.atomic_file(path, "w", on_digest) as f:
        writer, header = csv.writer(f, lineterminator="\n"), None
        for metrics, first, take in parts:
            if header is None:
                header = [*layout.METRICS_INDEX_COLUMNS, *metrics]
                writer.writerow(header)
            writer.writerows(metrics_csv_rows(metrics, batch_size, first, take))


def write_metrics_csv(
    path: files.Target, metrics: dict[str, np.ndarray], batch_size: int, on_digest: Digest = None
) -> None:
    """Rows ``seed_index, iteration, env_steps, <metrics...>`` from leaves ``[iterations, S]``
    (a run's metrics in memory: a stopped run's so far, or another library's log)."""
    _write_csv(path, [(metrics, 0, slice(None))], batch_size, on_digest)


def write_blocks_metrics_csv(
    path: files.Target, blocks: list, runs: range, batch_size: int, on_digest: Digest = None
) -> None:
    """Rows ``seed_index, iteration, env_steps, <metrics...>`` for ``runs`` (seed index
    counted from ``runs.start``), streamed block by block and renamed into place."""
    parts = ((b.metrics, b.start + t.start - runs.start, t) for b, t in overlapping(blocks, runs))
    _write_csv(path, parts, batch_size, on_digest)


def write_params(
    path: files.Target, blocks: list, runs: range, on_digest: Digest = None, best: bool = False
) -> None:
    """``params.npz`` for ``runs`` (``params_best.npz`` of the best policies with ``best``):
    each array's header for the whole run, then its blocks' bytes in order (a leading-axis
    concatenation), streamed into place."""
    first, _ = next(overlapping(blocks, runs))
    with (
        files.atomic_file(path, "wb", on_digest) as out,
        zipfile.ZipFile(out, "w", allowZip64=True) as zf,
    ):
        for name, a in first.params.items():
            shape = (len(runs), *a.shape[1:])
            with zf.open(name + ".npy", "w", force_zip64=True) as f:
                header = {
                    "descr": np.lib.format.dtype_to_descr(a.dtype),
                    "fortran_order": False,
                    "shape": shape,
                }
                np.lib.format.write_array_header_1_0(f, header)
                for part in _param_slices(blocks, runs, name, best):
                    f.write(np.ascontiguousarray(part).tobytes())


def write_evaluation(
    path: files.Target,
    blocks: list,
    runs: range,
    episodes: int,
    extra: dict,
    on_digest: Digest = None,
    env_id: str = DEFAULT_ENV,
) -> None:
    """``evaluation.json`` for ``runs``: per-seed returns and solved flags (solved as
    ``env_id`` defines it), streamed."""
    solved_total = best_solved = 0
    with files.atomic_file(path, "w", on_digest) as f:
        definition = json.dumps(solved_definition(env_id).format(episodes=episodes))
        head = f'{{\n  "episodes": {episodes},\n  "solved_definition": {definition},\n'
        f.write(head + '  "seeds": [')
        sep = "\n"
        for block, take in overlapping(blocks, runs):
            final = block.metrics["rollout/ep_rew_mean"][-1, take]
            g, j, d = block.gym_returns[take], block.jax_returns[take], block.diverged_at[take]
            first = block.start + take.start - runs.start
            for s in range(len(g)):
                seed = {
                    "seed_index": first + s,
                    **gymnasium_entry(g[s], env_id),
                    "jaxcart_returns": j[s].tolist(),
                    "jaxcart_mean": float(j[s].mean()),
                    "final_ep_rew_mean": float(final[s]),
                    "diverged_at_iteration": int(d[s]) if d[s] >= 0 else None,
                }
                solved_total += int(seed["solved"])
                if block.best is not None:
                    seed |= _best_entry(block.best, take, s, env_id)
                    best_solved += int(seed["best"]["solved"])
                f.write(sep + "    " + json.dumps(seed))
                sep = ",\n"
        tail = {"solved_seeds": solved_total, **extra}
        if any(block.best is not None for block, _ in overlapping(blocks, runs)):
            tail = {"solved_seeds": solved_total, "best_solved_seeds": best_solved, **extra}
        f.write("\n  ],\n" + json.dumps(tail, indent=2)[2:] + "\n")


def _best_entry(best: dict[str, np.ndarray], take: slice, s: int, env_id: str) -> dict:
    """A seed's best policy in ``evaluation.json``: its Gymnasium verdict and where it was."""
    g = best["best_gym_returns"][take][s]
    iteration = int(best["best_iteration"][take][s])
    return {
        "best": {
            "iteration": iteration if iteration > 0 else None,
            "eval_mean_return": float(best["best_score"][take][s]) if iteration > 0 else None,
            **gymnasium_entry(g, env_id),
        }
    }


def gymnasium_entry(returns: np.ndarray, env_id: str = DEFAULT_ENV) -> dict:
    """One seed's greedy Gymnasium episodes as ``evaluation.json`` records them: the returns
    ``[episodes]``, their mean and least, and whether they solve ``env_id``."""
    return {
        "gymnasium_returns": returns.tolist(),
        "gymnasium_mean": float(returns.mean()),
        "gymnasium_min": float(returns.min()),
        "solved": bool(is_solved(returns, env_id)),
    }


def evaluation_record(returns: np.ndarray, env_id: str = DEFAULT_ENV) -> dict:
    """``evaluation.json`` of greedy Gymnasium returns ``[num_seeds, episodes]``: per seed
    its returns, their mean and least, and whether they solve ``env_id``."""
    returns = np.asarray(returns)
    seeds = [{"seed_index": s, **gymnasium_entry(g, env_id)} for s, g in enumerate(returns)]
    return {
        "episodes": returns.shape[1],
        "solved_definition": solved_definition(env_id).format(episodes=returns.shape[1]),
        "seeds": seeds,
        "solved_seeds": sum(seed["solved"] for seed in seeds),
    }


def write_evaluation_dir(
    directory: files.Dir,
    info: dict,
    returns: np.ndarray | None = None,
    others: dict[str, dict] | None = None,
) -> None:
    """An evaluation written in one go (``python -m jaxcart.evaluate --out``, laid out as
    :mod:`jaxcart.rundir.layout` says): ``config.json`` (``info``), ``evaluation.json`` of
    ``returns`` ``[num_seeds, episodes]`` (a sweep's own directory has none: its
    ``combo-NNN/`` do) and ``others`` (name -> JSON object: a sweep's ``sweep.json``), each
    recorded in the directory's manifest as a run's files are, so that the readers check it
    as they check a run."""
    named = {layout.CONFIG_FILE: {**info, files.MANIFEST_FLAG: True}}
    if returns is not None:
        named[layout.EVALUATION_FILE] = evaluation_record(
            returns, info["config"].get("env", DEFAULT_ENV)
        )
    files.record_json(directory, {**named, **(others or {})})

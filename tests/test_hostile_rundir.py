"""A run directory as a trust boundary: crafted, linked, edited and half-deleted run
directories are refused in one line (a :class:`RunDirError`, exit 2 from the command line),
nothing outside the directory is read or written through a link, and no size or index in a
file drives an allocation.

The cases are generated: a session fixture trains a few tiny runs once (finished,
interrupted, a sweep, a run in waves), each case copies one and breaks it in one way, then
tries the readers (resume, load_policy, plot, compare's evaluation, evaluate's parameters).
The counts go to the "fault injection" summary at the end of the session.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import os
import shutil
import subprocess
import sys
import warnings
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from conftest import FAULT_FIGURES
from helpers import TINY, TRAIN_ENV, stopped_run

from jaxcart import train
from jaxcart.core.config import ConfigError
from jaxcart.results import scores as comparison
from jaxcart.run import lifecycle, loggers, waves
from jaxcart.run.greedy import CrossCheck
from jaxcart.run.spec import RunOptions, RunSpec
from jaxcart.rundir import files, layout, policy, reader
from jaxcart.rundir.directory import RunDir
from jaxcart.rundir.files import RunDirError, RunLock

SMALL = dataclasses.replace(TINY, total_timesteps=256, anneal_lr=False)  # 2 iterations
OPTIONS = RunOptions(eval_episodes=2, compile_cache=False, chunk_size=1)
PRECIOUS = b"a file outside the run directory\n"


@pytest.fixture(scope="session")
def bases(tmp_path_factory) -> dict[str, Path]:
    """Tiny runs, trained once: ``finished``, ``interrupted`` (1 of 4 iterations), a finished
    ``sweep`` of two combinations, and ``waved``, 4 seeds trained in waves of 2."""
    root = tmp_path_factory.mktemp("hostile-bases")
    lifecycle.run_new(RunSpec(SMALL, num_seeds=2), root / "finished", OPTIONS)
    longer = RunSpec(dataclasses.replace(SMALL, total_timesteps=512), num_seeds=2)
    stopped_run(longer, root / "interrupted", OPTIONS, chunks=1)[0].close()
    sweep = RunSpec(SMALL, num_seeds=1, sweep={"learning_rate": [1e-3, 2e-3]})
    lifecycle.run_new(sweep, root / "sweep", OPTIONS)
    two = waves.PROCESS_RESERVE_BYTES + 2 * waves.bytes_per_run(SMALL, 2) / waves.USABLE_FRACTION
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(waves.MEMORY_ENV, str(int(two) + 10))
        lifecycle.run_new(RunSpec(SMALL, num_seeds=4), root / "waved", OPTIONS)
    assert (root / "waved" / layout.WAVES_DIR / "wave-00001.npz").is_file()
    return {p.name: p for p in root.iterdir()}


# ---- mutations --------------------------------------------------------------------------


def edit_json(path: Path, change: Callable[[dict], object], redigest: bool = True) -> None:
    """Changes a JSON file; ``redigest`` recomputes config.json's digest (a run made so)."""
    data = json.loads(path.read_text())
    change(data)
    if redigest and layout.DIGEST_KEY in data:
        data.pop(layout.DIGEST_KEY)
        data[layout.DIGEST_KEY] = files.json_digest(data)
    path.write_text(json.dumps(data))


def raw_meta(path: Path, meta: bytes) -> None:
    """Replaces a tree file's ``__meta__`` entry with ``meta`` (any bytes)."""
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    arrays[files.META_KEY] = np.frombuffer(meta, np.uint8)
    np.savez(path, **arrays)


def edit_meta(**changes: object) -> Callable[[Path, Path], None]:
    def mutate(run: Path, outside: Path) -> None:
        path = run / layout.CHECKPOINT_FILE
        meta = json.loads(bytes(np.load(path)[files.META_KEY]).decode())
        raw_meta(path, json.dumps({**meta, **changes}).encode())

    return mutate


def edit_wave(change: Callable[[dict, dict], None], redigest: bool) -> Callable[[Path, Path], None]:
    """Rewrites wave 0 of a run in waves after ``change(arrays, meta)``."""

    def mutate(run: Path, outside: Path) -> None:
        path = run / layout.WAVES_DIR / "wave-00000.npz"
        arrays, meta = files.load_tree(path)
        change(arrays, meta)
        if redigest:
            meta[layout.DIGEST_KEY] = files.arrays_digest(arrays)
        files.save_tree(path, arrays, meta)

    return mutate


def link(name: str, to: str = "outside") -> Callable[[Path, Path], None]:
    """Replaces ``name`` in the run directory with a link to ``outside``'s file or directory
    of that name (``to="dangling"``: to a path that does not exist)."""

    def mutate(run: Path, outside: Path) -> None:
        target = run / name
        if target.is_dir() and not target.is_symlink():
            shutil.rmtree(target)
        else:
            target.unlink(missing_ok=True)
        dest = {"outside": outside / name, "dangling": outside / "missing", "zero": "/dev/zero"}
        os.symlink(dest[to], target)

    return mutate


def metrics_csv(text: str) -> Callable[[Path, Path], None]:
    return lambda run, outside: (run / layout.METRICS_FILE).write_text(text)


def config_field(redigest: bool = True, **fields: object) -> Callable[[Path, Path], None]:
    return lambda run, outside: edit_json(
        run / layout.CONFIG_FILE, lambda d: d.update(fields), redigest
    )


def config_text(text: str) -> Callable[[Path, Path], None]:
    """config.json with one field's value replaced by raw JSON text."""

    def mutate(run: Path, outside: Path) -> None:
        data = json.loads((run / layout.CONFIG_FILE).read_text())
        data.pop(layout.DIGEST_KEY)
        body = json.dumps(data)
        (run / layout.CONFIG_FILE).write_text(body[:-1] + ", " + text + "}")

    return mutate


def hidden(text: str) -> Callable[[Path, Path], None]:
    """config.json with ``text`` as its first hidden size, digest recomputed over the value
    it parses to (a crafted file, not a hand edit)."""

    def mutate(run: Path, outside: Path) -> None:
        data = json.loads((run / layout.CONFIG_FILE).read_text())
        data.pop(layout.DIGEST_KEY)
        data["config"]["hidden_sizes"] = [json.loads(text)]
        body = json.dumps({**data, layout.DIGEST_KEY: files.json_digest(data)})
        (run / layout.CONFIG_FILE).write_text(body.replace("Infinity", text))

    return mutate


def evaluation(change: Callable[[dict], object]) -> Callable[[Path, Path], None]:
    return lambda run, outside: edit_json(run / layout.EVALUATION_FILE, change)


def fifo(name: str) -> Callable[[Path, Path], None]:
    def mutate(run: Path, outside: Path) -> None:
        (run / name).unlink()
        os.mkfifo(run / name)

    return mutate


def zip_bomb(run: Path, outside: Path) -> None:
    """wave 0 as a deflated entry of 64 MB of zeros (64 KB on disk)."""
    path = run / layout.WAVES_DIR / "wave-00000.npz"
    buf = io.BytesIO()
    with (
        zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf,
        zf.open("gym_returns.npy", "w") as f,
    ):
        np.lib.format.write_array_header_1_0(
            f, {"descr": "<f8", "fortran_order": False, "shape": (8 << 20,)}
        )
        for _ in range(64):
            f.write(bytes(1 << 20))
    path.write_bytes(buf.getvalue())


def unfinish(run: Path, outside: Path) -> None:
    """A run in waves stopped after its waves, before its outputs: resume only builds them."""
    for name in (layout.EVALUATION_FILE, layout.PARAMS_FILE, layout.METRICS_FILE):
        (run / name).unlink()


def both(*mutations: Callable[[Path, Path], None]) -> Callable[[Path, Path], None]:
    def mutate(run: Path, outside: Path) -> None:
        for m in mutations:
            m(run, outside)

    return mutate


# ---- what is tried on a broken directory ------------------------------------------------


def resume(run: Path) -> None:
    lifecycle.resume_run(run, OPTIONS)


def load_policy(run: Path) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # an unfinished run's note
        policy.load_policy(run, "all")


def plot(run: Path) -> None:
    reader.load_runs([run])


def compare_scores(run: Path) -> None:
    for loaded in reader.load_runs([run]):
        comparison.read_evaluation(loaded, required=True)


def evaluate_params(run: Path) -> None:
    policy.run_params(run)


def sweep_policy(run: Path) -> None:
    policy.run_params(run, combination=0)


READERS = (load_policy, plot, compare_scores, evaluate_params)


def logger_opens(backend: type) -> Callable[[Path], None]:
    """Opens one logger backend on the run directory (as training would), then closes it."""

    def open_backend(run: Path) -> None:
        opened = backend(run, ["0"], {})
        opened.open()
        opened.close()

    open_backend.__name__ = f"open_{backend.name}"
    return open_backend


@dataclasses.dataclass(frozen=True)
class Case:
    """One way to break a run directory. ``sealed``: its manifest is then rewritten to match
    (a directory crafted by someone who recomputes the digests), so what is tested is the
    check behind the manifest; unsealed cases are edited bytes the manifest must catch."""

    name: str
    base: str
    mutate: Callable[[Path, Path], None]
    actions: tuple[Callable[[Path], None], ...]
    match: str
    sealed: bool = True
    group: str = "crafted files"


def reseal(run: Path) -> None:
    """Rewrites every manifest under ``run`` to list its files' current digests."""
    for listing in [run / layout.MANIFEST_FILE, *run.glob(f"*/{layout.MANIFEST_FILE}")]:
        if listing.is_symlink() or not listing.is_file():
            continue
        data = json.loads(listing.read_text())
        for name in data["files"]:
            path = listing.parent / name
            if path.is_file() and not path.is_symlink():
                digest = "sha256:" + hashlib.sha256(path.read_bytes()).hexdigest()
                data["files"][name] = [digest]
        listing.write_text(json.dumps(data))


S_LINK = "symbolic link"
CORRUPT = "corrupted|out of range|incompatible|has format"
CASES = [
    # writes outside through links
    Case("lock-link", "interrupted", link(layout.LOCK_FILE), (resume,), S_LINK),
    Case("lock-dangling", "interrupted", link(layout.LOCK_FILE, "dangling"), (resume,), S_LINK),
    Case("lock-link-finished", "finished", link(layout.LOCK_FILE), (resume,), S_LINK),
    Case("combo-link-finished-sweep", "sweep", link("combo-000"), (resume,), "already finished"),
    Case(
        "combo-link-unfinished-sweep",
        "sweep",
        both(link("combo-000"), lambda r, o: (r / layout.SWEEP_FILE).unlink()),
        (resume,),
        S_LINK,
    ),
    Case("waves-link", "waved", both(unfinish, link(layout.WAVES_DIR)), (resume,), S_LINK),
    # reads outside through links, FIFOs and devices
    Case("config.json-link", "finished", link(layout.CONFIG_FILE), READERS, S_LINK),
    Case(
        "params-link", "finished", link(layout.PARAMS_FILE), (load_policy, evaluate_params), S_LINK
    ),
    Case("metrics-link", "finished", link(layout.METRICS_FILE), (plot, compare_scores), S_LINK),
    Case(
        "evaluation-link", "finished", link(layout.EVALUATION_FILE), (plot, compare_scores), S_LINK
    ),
    Case(
        "checkpoint-link", "interrupted", link(layout.CHECKPOINT_FILE), (resume, *READERS), S_LINK
    ),
    Case(
        "checkpoint-dev-zero",
        "interrupted",
        link(layout.CHECKPOINT_FILE, "zero"),
        (resume, *READERS),
        S_LINK,
    ),
    Case(
        "checkpoint-fifo",
        "interrupted",
        fifo(layout.CHECKPOINT_FILE),
        (resume, *READERS),
        "not a regular file",
    ),
    Case("config-fifo", "finished", fifo(layout.CONFIG_FILE), READERS, "not a regular file"),
    Case("params-fifo", "finished", fifo(layout.PARAMS_FILE), (load_policy,), "not a regular file"),
    Case("combo-link-read", "sweep", link("combo-000"), (sweep_policy, plot), S_LINK),
    # links that would change what a directory is (a sweep, a finished or unfinished run)
    Case("sweep-json-link", "finished", link(layout.SWEEP_FILE), (resume, *READERS), S_LINK),
    Case(
        "sweep-json-link-sweep",
        "sweep",
        link(layout.SWEEP_FILE),
        (resume, sweep_policy, plot, compare_scores),
        S_LINK,
    ),
    Case("params-link-unfinished", "interrupted", link(layout.PARAMS_FILE), READERS, S_LINK),
    # logger directories in the run directory: nothing is logged through a link (SwanLab's
    # folder is the user's ./swanlog or --logger-dir, outside the run directory)
    *(
        Case(
            f"{name}-dir-link",
            "finished",
            link(name, "dangling"),
            (logger_opens(loggers.BACKENDS[backend]),),
            S_LINK,
        )
        for name, backend in (
            ("tensorboard", "tensorboard"),
            ("wandb", "wandb"),
        )
    ),
    Case(
        "wave-file-link", "waved", both(unfinish, link("waves/wave-00000.npz")), (resume,), S_LINK
    ),
    # sizes and indices from the files
    Case(
        "metrics-seed-index",
        "finished",
        metrics_csv("seed_index,iteration,env_steps,x\n200000,1,128,0\n"),
        (plot,),
        "out of range",
    ),
    Case(
        "metrics-iteration",
        "finished",
        metrics_csv("seed_index,iteration,env_steps,x\n0,90000000,128,0\n"),
        (plot,),
        "out of range",
    ),
    Case(
        "total-timesteps-1e18",
        "interrupted",
        lambda r, o: edit_json(
            r / layout.CONFIG_FILE, lambda d: d["config"].update(total_timesteps=10**18)
        ),
        (resume, *READERS),
        CORRUPT + "|iterations",
    ),
    Case(
        "eval-episodes-huge",
        "interrupted",
        config_field(eval_episodes=10_000_000),
        (resume,),
        "eval_episodes",
    ),
    Case("wave-zip-bomb", "waved", both(unfinish, zip_bomb), (resume,), "compressed|declares"),
    *(
        Case(
            f"meta-{name}", "interrupted", edit_meta(**{field: value}), (resume, *READERS), CORRUPT
        )
        for name, field, value in (
            ("chunk-negative", "chunk_size", -7),
            ("chunk-zero", "chunk_size", 0),
            ("chunk-string", "chunk_size", "7"),
            ("iteration-string", "iteration", "1"),
            ("iteration-null", "iteration", None),
            ("iteration-list", "iteration", [1]),
            ("elapsed-string", "elapsed", "fast"),
            ("versions-list", "versions", ["jax"]),
            ("versions-string", "versions", "0.4"),
            ("format-list", "checkpoint_format", [2]),
            ("wave-negative", "wave", -1),
        )
    ),
    Case(
        "meta-deep-nesting",
        "interrupted",
        lambda r, o: raw_meta(r / layout.CHECKPOINT_FILE, b"[" * 200_000),
        (resume, *READERS),
        CORRUPT,
    ),
    Case(
        "meta-not-json",
        "interrupted",
        lambda r, o: raw_meta(r / layout.CHECKPOINT_FILE, b"\xff{"),
        (resume, *READERS),
        CORRUPT,
    ),
    # crafted config.json
    Case("config-hidden-1e400", "interrupted", hidden("1e400"), (resume, *READERS), CORRUPT),
    Case("config-hidden-fraction", "interrupted", hidden("64.5"), (resume, *READERS), CORRUPT),
    Case("config-hidden-bool", "finished", hidden("true"), READERS, CORRUPT),
    Case("config-num-seeds-1e30", "finished", config_text('"num_seeds": 1e30'), READERS, CORRUPT),
    Case("config-preset-list", "finished", config_field(preset=["sb3"]), READERS, CORRUPT),
    Case("config-preset-dict", "finished", config_field(preset={"a": 1}), READERS, CORRUPT),
    Case("config-combination-list", "finished", config_field(combination=[1, 2]), READERS, CORRUPT),
    Case(
        "config-combinations-dict",
        "finished",
        config_field(combinations={"a": 1}),
        READERS,
        CORRUPT,
    ),
    Case(
        "config-seed-5000-digits",
        "finished",
        config_text('"seed": ' + "9" * 5000),
        READERS,
        CORRUPT,
    ),
    Case(
        "config-infinity-float",
        "finished",
        config_text(
            '"config": '
            + json.dumps({**SMALL.to_dict(), "hidden_sizes": [64]}).replace(
                '"learning_rate": 0.001', '"learning_rate": Infinity'
            )
        ),
        READERS,
        CORRUPT,
    ),
    Case(
        "config-not-object",
        "finished",
        lambda r, o: (r / layout.CONFIG_FILE).write_text("[1]"),
        READERS,
        "not a JSON object",
    ),
    # silently wrong before
    Case(
        "config-hand-edited",
        "interrupted",
        config_field(redigest=False, seed=3),
        (resume,),
        "digest",
    ),
    Case(
        "device-change",
        "interrupted",
        config_field(device_count=1),
        (resume,),
        "xla_force_host_platform_device_count=1",
    ),
    Case(
        "wave-shape",
        "waved",
        both(unfinish, edit_wave(lambda a, m: a.update({"gym_returns": np.zeros((2, 3))}), True)),
        (resume,),
        "another shape",
    ),
    Case(
        "wave-nan",
        "waved",
        both(
            unfinish,
            edit_wave(
                lambda a, m: next(v for k, v in a.items() if k.startswith("params/")).fill(np.nan),
                True,
            ),
        ),
        (resume,),
        "NaN",
    ),
    Case(
        "wave-edited",
        "waved",
        both(unfinish, edit_wave(lambda a, m: a["gym_returns"].fill(500.0), False)),
        (resume,),
        "digest",
    ),
    Case(
        "wave-other-runs",
        "waved",
        both(unfinish, edit_wave(lambda a, m: m.update(start=2, stop=4), True)),
        (resume,),
        "not the file of runs",
    ),
    Case(
        "evaluation-seed-count",
        "finished",
        evaluation(lambda d: d["seeds"].pop()),
        (plot, compare_scores),
        "holds 1 seeds",
    ),
    Case(
        "evaluation-seeds-string",
        "finished",
        evaluation(lambda d: d.update(seeds="abc")),
        (plot, compare_scores),
        CORRUPT,
    ),
    Case(
        "evaluation-seeds-numbers",
        "finished",
        evaluation(lambda d: d.update(seeds=[1, 2])),
        (plot, compare_scores),
        CORRUPT,
    ),
    Case(
        "evaluation-mean-string",
        "finished",
        evaluation(lambda d: d["seeds"][0].update(gymnasium_mean="x")),
        (plot, compare_scores),
        CORRUPT,
    ),
    Case(
        "evaluation-solved-string",
        "finished",
        evaluation(lambda d: d["seeds"][0].update(solved="yes")),
        (plot, compare_scores),
        CORRUPT,
    ),
    Case(
        "evaluation-episodes-huge",
        "finished",
        evaluation(lambda d: d.update(episodes=10**9)),
        (plot, compare_scores),
        CORRUPT,
    ),
    Case("finished-sweep-resume", "sweep", lambda r, o: None, (resume,), "already finished"),
]


# ---- generated classes: hard links, edited bytes, duplicate entries, values out of range ----


def hardlink(name: str) -> Callable[[Path, Path], None]:
    """``name`` (a file jaxcart changes in place) as a hard link to a file outside."""

    def mutate(run: Path, outside: Path) -> None:
        (outside / "precious").write_bytes(PRECIOUS * 64)
        (run / name).unlink(missing_ok=True)
        os.link(outside / "precious", run / name)

    return mutate


def append_byte(name: str) -> Callable[[Path, Path], None]:
    """One byte more at the end of ``name``: still a valid JSON, CSV or zip, other bytes."""
    return lambda run, outside: (run / name).write_bytes((run / name).read_bytes() + b" ")


def duplicate_entry(name: str) -> Callable[[Path, Path], None]:
    """``name`` (an archive) with its first array written twice, the second copy zeros: what
    ``np.load`` would read is not what a header check saw."""

    def mutate(run: Path, outside: Path) -> None:
        path = run / name
        with zipfile.ZipFile(path) as zf:
            first = zf.infolist()[0].filename
            header = zf.read(first)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # zipfile warns about the duplicate name
            with zipfile.ZipFile(path, "a") as zf:
                zf.writestr(first, header[:128] + bytes(len(header) - 128))

    return mutate


def metrics_value(column: str, value: str) -> Callable[[Path, Path], None]:
    def mutate(run: Path, outside: Path) -> None:
        lines = (run / layout.METRICS_FILE).read_text().splitlines()
        header = lines[0].split(",")
        row = lines[1].split(",")
        row[header.index(column)] = value
        lines[1] = ",".join(row)
        (run / layout.METRICS_FILE).write_text("\n".join(lines) + "\n")

    return mutate


def seed_entry(**fields: object) -> Callable[[Path, Path], None]:
    return evaluation(lambda d: d["seeds"][0].update(fields))


def stream_nans(run: Path, outside: Path) -> None:
    path = run / layout.METRICS_STREAM_FILE
    path.write_bytes(np.full(path.stat().st_size // 4, np.nan, "<f4").tobytes())


READS = {  # who reads each file a run keeps in its manifest
    layout.CONFIG_FILE: READERS,
    layout.METRICS_FILE: (plot,),
    layout.EVALUATION_FILE: (compare_scores,),
    layout.PARAMS_FILE: (load_policy, evaluate_params),
    layout.CHECKPOINT_FILE: (resume, load_policy),
}
EDITED = "not the file the run wrote"
RANGE = "outside|refusing|does not count|says solved|not the mean|not a list"
GENERATED = [
    # files changed in place, as hard links to a file elsewhere
    *(
        Case(f"hardlink-{name}-{base}", base, hardlink(name), (resume,), "hard links", group=g)
        for name, base in (
            (layout.LOCK_FILE, "interrupted"),
            (layout.LOCK_FILE, "finished"),
            (layout.LOCK_FILE, "waved"),
            (layout.METRICS_STREAM_FILE, "interrupted"),
        )
        for g in ("hard links",)
    ),
    # edited bytes in every file a manifest lists (nothing recomputed)
    *(
        Case(
            f"edited-{name}-{base}",
            base,
            append_byte(name),
            READS[name],
            EDITED,
            False,
            "edited bytes",
        )
        for base, names in (
            (
                "finished",
                (
                    layout.CONFIG_FILE,
                    layout.METRICS_FILE,
                    layout.EVALUATION_FILE,
                    layout.PARAMS_FILE,
                ),
            ),
            ("interrupted", (layout.CONFIG_FILE, layout.CHECKPOINT_FILE)),
        )
        for name in names
    ),
    Case(
        "edited-activation",
        "finished",
        config_field(config={**SMALL.to_dict(), "activation": "relu"}),
        READERS,
        EDITED,
        False,
        "edited bytes",
    ),
    Case(
        "edited-meta-iteration",
        "interrupted",
        edit_meta(iteration=0),
        (resume, load_policy),
        EDITED,
        False,
        "edited bytes",
    ),
    Case(
        "edited-stream-nan",
        "interrupted",
        stream_nans,
        (resume, load_policy),
        "rows differ",
        False,
        "edited bytes",
    ),
    Case(
        "edited-combo-evaluation",
        "sweep",
        append_byte(f"combo-000/{layout.EVALUATION_FILE}"),
        (plot, compare_scores),
        EDITED,
        False,
        "edited bytes",
    ),
    # a duplicate entry in every archive
    *(
        Case(
            f"duplicate-{name.replace('/', '-')}",
            base,
            mutate,
            actions,
            "twice",
            group="duplicate zip entries",
        )
        for name, base, mutate, actions in (
            (
                layout.PARAMS_FILE,
                "finished",
                duplicate_entry(layout.PARAMS_FILE),
                (load_policy, evaluate_params),
            ),
            (
                layout.CHECKPOINT_FILE,
                "interrupted",
                duplicate_entry(layout.CHECKPOINT_FILE),
                (resume, load_policy),
            ),
            (
                "waves/wave-00000.npz",
                "waved",
                both(unfinish, duplicate_entry("waves/wave-00000.npz")),
                (resume,),
            ),
        )
    ),
    # out-of-range values in every numeric field (the manifest recomputed: crafted files)
    *(
        Case(
            f"range-metrics-{column}-{value}",
            "finished",
            metrics_value(column, value),
            (plot,),
            RANGE,
            group="values out of range",
        )
        for column in (
            "rollout/ep_rew_mean",
            "rollout/ep_len_mean",
            "rollout/ep_rew_max",
            "train/approx_kl",
            "train/clip_fraction",
            "train/entropy_loss",
            "train/policy_gradient_loss",
            "train/value_loss",
            "train/loss",
            "train/explained_variance",
            "train/learning_rate",
            "time/fps",
            "time/elapsed",
        )
        for value in ("1e308", "inf", "-1e300")
    ),
    Case(
        "range-clip-fraction-7",
        "finished",
        metrics_value("train/clip_fraction", "7"),
        (plot,),
        RANGE,
        group="values out of range",
    ),
    *(
        Case(
            f"range-evaluation-{name}",
            "finished",
            mutate,
            (plot, compare_scores),
            RANGE,
            group="values out of range",
        )
        for name, mutate in (
            ("mean-1e300", seed_entry(gymnasium_mean=1e300)),
            ("mean-minus-7", seed_entry(gymnasium_mean=-7.0)),
            ("returns-1e300", seed_entry(gymnasium_returns=[1e300, 1e300], gymnasium_mean=1e300)),
            ("returns-minus-7", seed_entry(gymnasium_returns=[-7.0, -7.0], gymnasium_mean=-7.0)),
            ("returns-count", seed_entry(gymnasium_returns=[500.0])),
            (
                "solved-377",
                seed_entry(
                    gymnasium_returns=[377.0, 377.0],
                    gymnasium_mean=377.0,
                    gymnasium_min=377.0,
                    solved=True,
                ),
            ),
            ("min-not-least", seed_entry(gymnasium_min=-1.0)),
            (
                "mean-not-mean",
                seed_entry(
                    gymnasium_returns=[10.0, 20.0],
                    gymnasium_min=10.0,
                    gymnasium_mean=11.0,
                    solved=False,
                ),
            ),
            ("jaxcart-returns-9999", seed_entry(jaxcart_returns=[9999.0, 1.0])),
            ("final-ep-rew-1e300", seed_entry(final_ep_rew_mean=1e300)),
            ("solved-seeds", evaluation(lambda d: d.update(solved_seeds=99))),
        )
    ),
    Case(
        "range-meta-chunk-huge",
        "interrupted",
        edit_meta(chunk_size=1 << 30),
        (resume, load_policy),
        CORRUPT,
        group="values out of range",
    ),
    Case(
        "range-meta-elapsed-1e308",
        "interrupted",
        edit_meta(elapsed=1e308),
        (resume, load_policy),
        CORRUPT,
        group="values out of range",
    ),
]
CASES += GENERATED


def snapshot(root: Path) -> dict[str, tuple[bytes, int]]:
    """Every file under ``root``: its bytes and mtime."""
    return {
        str(p.relative_to(root)): (p.read_bytes(), p.stat().st_mtime_ns)
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def prepare(bases: dict[str, Path], base: str, tmp_path: Path) -> tuple[Path, Path]:
    """A copy of ``base`` to break, and ``outside``: files a link may point to (a copy of
    another finished run, plus a plain file under each run file's name)."""
    run, outside = tmp_path / "run", tmp_path / "outside"
    shutil.copytree(bases[base], run, symlinks=True)
    shutil.copytree(bases["finished"] if base != "waved" else bases["waved"], outside)
    (outside / layout.LOCK_FILE).write_bytes(PRECIOUS)
    (outside / "combo-000").mkdir(exist_ok=True)
    (outside / "combo-000" / "keep.txt").write_bytes(PRECIOUS)
    return run, outside


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_a_crafted_run_directory_is_refused_in_one_line(case, bases, tmp_path):
    run, outside = prepare(bases, case.base, tmp_path)
    case.mutate(run, outside)
    if case.sealed:
        reseal(run)
    before = snapshot(outside)
    for action in case.actions:
        with pytest.raises((RunDirError, ConfigError), match=case.match) as info:
            action(run)
        assert "\n" not in str(info.value), f"{action.__name__}: {info.value}"
        FAULT_FIGURES["hostile run directories: crafted cases x readers, refused"] += 1
    assert snapshot(outside) == before  # nothing outside was written through a link
    assert not (outside / "missing").exists()  # a dangling link created nothing
    FAULT_FIGURES["hostile run directories: crafted cases"] += 1
    FAULT_FIGURES[f"hostile run directories: {case.group}, cases refused"] += 1


CLI_CASES = [c for c in CASES if resume in c.actions and c.base != "waved"][:12]


@pytest.mark.parametrize("case", CLI_CASES, ids=[c.name for c in CLI_CASES])
def test_the_command_line_says_one_line_and_exits_2(case, bases, tmp_path, capsys):
    run, outside = prepare(bases, case.base, tmp_path)
    case.mutate(run, outside)
    if case.sealed:
        reseal(run)
    assert train.main(["--resume", str(run), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: cannot resume:") and "\n" not in err and "Traceback" not in err
    FAULT_FIGURES["hostile run directories: command lines, one line + exit 2"] += 1


def test_a_device_change_is_allowed_when_asked_and_recorded(bases, tmp_path):
    run, outside = prepare(bases, "interrupted", tmp_path)
    config_field(device_count=1)(run, outside)
    reseal(run)
    outcome = lifecycle.resume_run(run, OPTIONS, allow_device_change=True)
    assert not outcome.stopped
    info = json.loads((run / layout.CONFIG_FILE).read_text())
    assert info["device_changes"] == [{"from": 1, "to": 2}] and info["device_count"] == 2
    assert reader.read_run_config(run, verify=True)["device_count"] == 2  # digest rewritten


def test_an_interrupted_extension_reads_as_unfinished(bases, tmp_path):
    run, _ = prepare(bases, "finished", tmp_path)
    # the extension is opened (config.json rewritten) and then the process stops
    lifecycle.open_run(run, extend_to=512).close()
    assert not (run / layout.EVALUATION_FILE).exists() and not (run / layout.PARAMS_FILE).exists()
    with pytest.warns(UserWarning, match="did not finish"):
        policy.load_policy(run)
    (curves,) = reader.load_runs([run])
    assert "did not finish" in curves.note
    with pytest.raises(RunDirError, match=r"no evaluation\.json"):
        comparison.read_evaluation(curves, required=True)
    outcome = lifecycle.resume_run(run, OPTIONS)  # and the extension completes
    assert not outcome.stopped and outcome.run.config.num_iterations == 4
    assert (run / layout.EVALUATION_FILE).is_file()


def test_a_run_directory_deleted_during_evaluation_is_not_recreated(bases, tmp_path, monkeypatch):
    run, _ = prepare(bases, "interrupted", tmp_path)
    evaluate = CrossCheck.evaluate

    def delete_then_evaluate(check, *args, **kwargs):
        shutil.rmtree(run)
        return evaluate(check, *args, **kwargs)

    monkeypatch.setattr(CrossCheck, "evaluate", delete_then_evaluate)
    with pytest.raises(OSError):
        lifecycle.resume_run(run, OPTIONS)
    assert not run.exists()


def test_a_failed_start_leaves_nothing_and_a_lock_only_directory_is_taken_over(
    tmp_path, monkeypatch
):
    def fail(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(RunDir, "write_config", fail)
    with pytest.raises(OSError):
        lifecycle.create_run(RunSpec(SMALL), tmp_path / "new")
    assert not (tmp_path / "new").exists()
    monkeypatch.undo()
    (tmp_path / "stuck").mkdir()
    (tmp_path / "stuck" / layout.LOCK_FILE).write_text("12345\n")  # a start killed early
    with pytest.raises(RunDirError, match="takes it over"):
        lifecycle.resume_run(tmp_path / "stuck", OPTIONS)
    run = lifecycle.create_run(RunSpec(SMALL), tmp_path / "stuck")
    assert (tmp_path / "stuck" / layout.CONFIG_FILE).is_file()
    run.close()
    FAULT_FIGURES["hostile run directories: concurrency cases"] += 1


def test_a_lock_only_directory_held_by_a_live_start_is_not_taken_over(tmp_path):
    (tmp_path / "live").mkdir()
    with RunLock(tmp_path / "live"):  # another start, before its config.json
        with pytest.raises(RunDirError, match="in use by another jaxcart process"):
            lifecycle.create_run(RunSpec(SMALL), tmp_path / "live")
        assert (tmp_path / "live" / layout.LOCK_FILE).exists()  # its lock stays
    FAULT_FIGURES["hostile run directories: concurrency cases"] += 1


def test_two_resumes_of_one_run_one_is_refused(bases, tmp_path):
    run, _ = prepare(bases, "interrupted", tmp_path)
    opened = lifecycle.open_run(run)
    try:
        with pytest.raises(RunDirError, match="in use"):
            lifecycle.open_run(run)
    finally:
        opened.close()
    FAULT_FIGURES["hostile run directories: concurrency cases"] += 1


@pytest.mark.parametrize(
    ("env", "argv", "match"),
    [
        ({"JAXCART_MEMORY_BYTES": "abc"}, [], "JAXCART_MEMORY_BYTES"),
        ({"JAXCART_MEMORY_BYTES": "inf"}, [], "JAXCART_MEMORY_BYTES"),
        ({"JAXCART_MEMORY_BYTES": "nan"}, [], "JAXCART_MEMORY_BYTES"),
        ({}, ["--eval-episodes", "1e8"], "at most"),
        ({}, ["--checkpoint-every", "inf"], "--checkpoint-every"),
        ({}, ["--checkpoint-every", "nan"], "--checkpoint-every"),
    ],
)
def test_options_and_environment_variables_are_bounded(
    env, argv, match, tmp_path, capsys, monkeypatch
):
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    args = ["--num-envs", "4", "--num-steps", "32", "--total-timesteps", "256", "--quiet"]
    assert train.main([*args, *argv, "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip()
    assert match in err and "\n" not in err
    FAULT_FIGURES["hostile run directories: bad options and variables"] += 1


@pytest.mark.parametrize(
    ("module", "argv", "match"),
    [
        ("compare", ["--reps", "1000000000"], "--reps"),
        ("compare", ["--dpi", "100000"], "--dpi"),
        ("plot", ["--dpi", "100000"], "--dpi"),
        ("evaluate", ["--episodes", "1e8"], "at most"),
    ],
)
def test_analysis_options_are_bounded(module, argv, match, bases, capsys):
    main = __import__(f"jaxcart.{module}", fromlist=["main"]).main
    assert main([str(bases["finished"]), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert match in err and "\n" not in err
    FAULT_FIGURES["hostile run directories: bad options and variables"] += 1


def test_an_xla_device_count_of_zero_is_one_line(tmp_path):
    env = {**TRAIN_ENV, "XLA_FLAGS": "--xla_force_host_platform_device_count=0"}
    for module in ("train", "plot"):
        proc = subprocess.run(
            [sys.executable, "-m", f"jaxcart.{module}", str(tmp_path)],
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
        assert "device count in [1," in proc.stderr
    FAULT_FIGURES["hostile run directories: bad options and variables"] += 2


def test_a_run_directory_renamed_or_swapped_for_a_link_while_it_trains_keeps_every_write(
    tmp_path,
):
    """The path of a training run is renamed and a link to another directory put in its
    place: what the run writes next lands in the run's own directory (opened once), never in
    the link's target."""
    run = lifecycle.create_run(RunSpec(SMALL, num_seeds=1), tmp_path / "run")
    try:
        (tmp_path / "run").rename(tmp_path / "moved")
        (tmp_path / "elsewhere").mkdir()
        os.symlink(tmp_path / "elsewhere", tmp_path / "run")
        state = lifecycle.wave_start_state(run, range(0, 1), 0, 1)
        lifecycle.save_state(run, state)
        run.directory.write_ranking({"x": 1})
    finally:
        run.close()
    assert list((tmp_path / "elsewhere").iterdir()) == []
    written = {p.name for p in (tmp_path / "moved").iterdir()}
    assert {layout.CHECKPOINT_FILE, layout.SWEEP_FILE, layout.MANIFEST_FILE} <= written
    FAULT_FIGURES["hostile run directories: directory renames during writes"] += 1


@pytest.mark.parametrize("reading", ["curves", "params", "unfinished"])
def test_a_run_directory_swapped_while_it_is_read_is_read_from_the_one_opened(
    bases, tmp_path, monkeypatch, reading
):
    """A reader opens the run directory once: renaming it after its config.json was read, and
    putting a link to another run (trained with a different activation) in its place, does
    not mix the two runs' files: the reader still reads the first run's."""
    name = "interrupted" if reading == "unfinished" else "finished"
    run, _ = prepare(bases, name, tmp_path)
    other = tmp_path / "other"
    shutil.copytree(bases["sweep"] / "combo-001", other)  # another run, same shapes
    real, swaps = reader.read_run_config, []

    def read_then_swap(run_dir, verify=False):
        info = real(run_dir, verify)
        if not swaps:
            swaps.append(run)
            run.rename(tmp_path / "moved")
            os.symlink(other, run)
        return info

    monkeypatch.setattr(reader, "read_run_config", read_then_swap)
    if reading == "params":
        got = policy.run_params(run).params
        want = reader.load_params(tmp_path / "moved")
        assert all(np.array_equal(a, b) for a, b in zip(jax_leaves(got), jax_leaves(want)))
    else:
        curves = reader.load_run(run)
        monkeypatch.setattr(reader, "read_run_config", real)
        want = reader.load_run(tmp_path / "moved")
        assert curves.note == want.note
        assert all(
            np.array_equal(curves.metrics[k], v, equal_nan=True) for k, v in want.metrics.items()
        )
    assert swaps, "the swap happened while reading"
    FAULT_FIGURES["hostile run directories: directory renames during reads"] += 1


def jax_leaves(tree: dict) -> list[np.ndarray]:
    return [np.asarray(x) for x in files.flatten(tree).values()]


def test_a_run_from_before_manifests_is_read_with_a_note_and_a_missing_one_is_refused(
    bases, tmp_path, capsys
):
    run, _ = prepare(bases, "finished", tmp_path)
    (run / layout.MANIFEST_FILE).unlink()
    with pytest.raises(RunDirError, match=r"manifest\.json is missing"):
        reader.load_runs([run])
    edit_json(run / layout.CONFIG_FILE, lambda d: d.pop("manifest"))  # an older run
    with pytest.warns(UserWarning, match="cannot be verified"):
        (curves,) = reader.load_runs([run])
    assert curves.metrics
    from jaxcart import plot as plot_command

    assert plot_command.main([str(run), "--dpi", "20"]) == 0
    notes = [line for line in capsys.readouterr().err.splitlines() if "cannot be verified" in line]
    assert notes and all(line.startswith("note: ") for line in notes)


@pytest.mark.slow
def test_x64_training_is_float64_end_to_end_and_resumes_only_in_x64(tmp_path):
    args = [*"--num-envs 4 --num-steps 32 --total-timesteps 512 --eval-episodes 2".split()]
    env = {**TRAIN_ENV, "JAX_ENABLE_X64": "1"}
    out = tmp_path / "x64"
    command = [sys.executable, "-m", "jaxcart.train", *args, "--quiet", "--out", str(out)]
    proc = subprocess.run(command, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert json.loads((out / layout.CONFIG_FILE).read_text())["x64"] is True
    with np.load(out / layout.PARAMS_FILE) as params:
        assert {params[k].dtype for k in params.files} == {np.dtype(np.float64)}
    with np.load(out / layout.CHECKPOINT_FILE) as state:
        floats = {state[k].dtype for k in state.files if k.startswith("state/runners/params/")}
        assert floats == {np.dtype(np.float64)}
    assert policy.load_policy(out)(np.zeros(4, np.float32)) in (0, 1)
    with pytest.raises(RunDirError, match="trained in float64"):
        lifecycle.resume_run(out, OPTIONS, total_timesteps=1024)


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("JAX_PLATFORMS", "junk"),
        ("JAX_PLATFORMS", "tpu"),
        ("JAX_DEFAULT_MATMUL_PRECISION", "junk"),
        ("JAX_ENABLE_X64", "junk"),
        ("XLA_FLAGS", "junk"),
        ("XLA_FLAGS", "--xla_force_host_platform_device_count=2 --xla_no_such_flag=1"),
    ],
)
def test_an_environment_variable_jax_cannot_use_is_one_line_and_leaves_no_run(
    name, value, tmp_path
):
    out = tmp_path / "r"
    proc = subprocess.run(
        [sys.executable, "-m", "jaxcart.train", "--num-envs", "4", "--out", str(out)],
        env={**TRAIN_ENV, name: value},
        capture_output=True,
        text=True,
        timeout=300,
    )
    err = proc.stderr.strip()
    assert proc.returncode == 2 and "\n" not in err and "Traceback" not in err, err
    assert err.startswith("error:") and (name in err or name.lower() in err)
    assert not out.exists()
    FAULT_FIGURES["hostile run directories: bad options and variables"] += 1


@pytest.mark.parametrize(
    ("module", "argv", "match"),
    [
        ("train", ["--hidden-sizes", "64,,64", "--dry-run"], "empty element"),
        ("train", ["--out", "", "--dry-run"], "--out: is empty"),
        ("train", ["--out", "/proc/x", "--dry-run"], "kernel"),
        ("compare", ["--out", "/proc/x"], "kernel"),
        ("evaluate", ["--gif-seed", "-1"], "--gif-seed"),
    ],
)
def test_option_values_outside_sense_are_one_line(module, argv, match, bases, capsys):
    main = __import__(f"jaxcart.{module}", fromlist=["main"]).main
    run = [] if module == "train" else [str(bases["finished"])]
    assert main([*run, *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert match in err and "\n" not in err
    FAULT_FIGURES["hostile run directories: bad options and variables"] += 1

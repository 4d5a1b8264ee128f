"""Shared pieces of the tests: a tiny training command and run comparisons."""

from __future__ import annotations

import os
import struct
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np

from jaxcart.core.config import PPOConfig
from jaxcart.core.metrics import METRIC_NAMES
from jaxcart.rundir import layout, reader

TINY = PPOConfig(  # 32 iterations of 128 transitions: a training test in seconds
    num_envs=4,
    num_steps=32,
    total_timesteps=4096,
    minibatch_size=64,
    update_epochs=2,
    learning_rate=1e-3,
    anneal_lr=True,
)


def tiny_args(
    total_timesteps: int, num_seeds: int = 1, eval_episodes: int = 2, epochs: int = 2
) -> list[str]:
    """CLI options for a run small enough for a test: 4 envs x 32 steps, minibatches of 64."""
    return [
        "--num-envs",
        "4",
        "--num-steps",
        "32",
        "--total-timesteps",
        str(total_timesteps),
        "--minibatch-size",
        "64",
        "--update-epochs",
        str(epochs),
        "--eval-episodes",
        str(eval_episodes),
        "--num-seeds",
        str(num_seeds),
        "--quiet",
    ]


def assert_same_results(a_metrics: dict, b_metrics: dict, a_params, b_params) -> None:
    """Every learning metric and parameter bit-identical (time/* are wall-clock and may differ)."""
    for name in METRIC_NAMES:
        np.testing.assert_array_equal(a_metrics[name], b_metrics[name], err_msg=name)
    for x, y in zip(jax.tree.leaves(a_params), jax.tree.leaves(b_params), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def assert_same_run_dirs(a: Path, b: Path) -> None:
    """Two run directories hold bit-identical metrics and parameters."""
    assert_same_results(
        reader.read_metrics_csv(a / layout.METRICS_FILE),
        reader.read_metrics_csv(b / layout.METRICS_FILE),
        dict(np.load(a / layout.PARAMS_FILE)),  # the arrays, whatever network they are of
        dict(np.load(b / layout.PARAMS_FILE)),
    )


def stopped_run(spec, out: Path, options, chunks: int = 2):
    """A run created in ``out`` and stopped after ``chunks`` chunks (as Ctrl-C in a notebook
    would), its state checkpointed: ``(run, result)``, the run still open (locked)."""
    from jaxcart.run import lifecycle
    from jaxcart.run.spec import Hooks

    run = lifecycle.create_run(spec, out)
    done: list[int] = []
    hooks = Hooks(on_chunk=lambda p: done.append(p.iteration))
    result = lifecycle.train_wave(run, options, hooks, should_stop=lambda: len(done) == chunks)
    lifecycle.save_state(run, result.state)
    return run, result


WAIT_S = 600.0
"""How long a test waits for a training subprocess to reach a point (a checkpoint written,
say) before it fails: generous, since a load of 10 on two cores stretches seconds to minutes."""


TRAIN_ENV = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2"}
"""Environment of a training subprocess: two CPU devices, as in-process tests have."""


def fresh_python(code: str, env: dict[str, str], timeout: float = 120) -> str:
    """Runs ``code`` in a fresh interpreter with ``env``; asserts it exits 0 (its stderr
    otherwise) and returns its stdout, stripped."""
    done = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=timeout
    )
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


def start_train(*args: str) -> subprocess.Popen:
    """``python -m jaxcart.train ARGS`` in a subprocess, stdout and stderr merged as text."""
    return subprocess.Popen(
        [sys.executable, "-m", "jaxcart.train", *args],
        env=TRAIN_ENV,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


def read_swanlog(folder: Path) -> dict[str, dict[str, list[tuple[int, float]]]]:
    """A SwanLab log folder read back with the record reader `swanlab sync` uses: experiment name ->
    scalar key -> ``[(step, value)]``, of every finished experiment in ``folder``."""
    from swanlab.proto.swanlab.record.v1.record_pb2 import Record
    from swanlab.sdk.internal.core_python.store import DataStoreReader

    experiments = {}
    for records_file in sorted(Path(folder).glob("run-*/*.swanlab")):
        reader = DataStoreReader()
        reader.open(records_file)
        name, finished, scalars = None, False, {}
        for payload in reader:
            record = Record.FromString(payload)
            if record.HasField("start"):
                name = record.start.name
            finished |= record.HasField("finish")
            if record.HasField("scalar"):
                point = (record.scalar.step, record.scalar.value.number)
                scalars.setdefault(record.scalar.key, []).append(point)
        reader.close()
        assert finished and name is not None, records_file
        experiments[name] = scalars
    return experiments


def read_tfrecords(path: Path) -> list[bytes]:
    """Payloads of a TFRecord file (length u64, masked crc u32, payload, masked crc u32)."""
    data, records, pos = path.read_bytes(), [], 0
    while pos < len(data):
        (length,) = struct.unpack("<Q", data[pos : pos + 8])
        records.append(data[pos + 12 : pos + 12 + length])
        pos += 12 + length + 4
    return records


def read_tensorboard(folder: Path) -> dict[str, list[tuple[int, float]]]:
    """The scalars of a TensorBoard run folder's event files: tag -> ``[(step, value)]``."""
    from tensorboardX.proto.event_pb2 import Event

    scalars: dict[str, list[tuple[int, float]]] = {}
    for path in sorted(Path(folder).glob("events.out.tfevents.*")):
        for record in read_tfrecords(path):
            event = Event.FromString(record)
            for value in event.summary.value:
                if value.HasField("simple_value"):
                    scalars.setdefault(value.tag, []).append((event.step, value.simple_value))
    return scalars


def distinct_colours(rgb) -> int:
    """How many colours an RGB image (an ``(H, W, 3)`` array of 0-255 values) holds: each
    pixel read as one 24-bit integer and counted (a fraction of a second where ``np.unique``
    over rows took seconds)."""
    c = np.asarray(rgb).astype(np.uint32)
    packed = (c[..., 0] << 16) | (c[..., 1] << 8) | c[..., 2]
    return int(np.count_nonzero(np.bincount(packed.ravel(), minlength=1 << 24)))


def seal(run_dir: Path) -> None:
    """Rewrites ``run_dir``'s manifest to list every file it holds as it is now: a run
    directory crafted by someone who recomputes the digests (:class:`jaxcart.rundir.files.Manifest`)."""
    import hashlib
    import json

    from jaxcart.rundir import layout

    skip = {layout.MANIFEST_FILE, layout.LOCK_FILE, layout.METRICS_STREAM_FILE}
    listed = {
        p.name: ["sha256:" + hashlib.sha256(p.read_bytes()).hexdigest()]
        for p in sorted(Path(run_dir).iterdir())
        if p.is_file() and not p.is_symlink() and p.name not in skip
    }
    manifest = {"format": 1, "files": listed}
    (Path(run_dir) / layout.MANIFEST_FILE).write_text(json.dumps(manifest))

"""Metric loggers: what TensorBoard, SwanLab and W&B files hold after a run, and the queue around
them (log() never waits for a writer; writer errors are reported, not raised into training)."""

import dataclasses
import socket
import struct
import sys
import threading
import time
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest
from helpers import TINY, read_swanlog, read_tfrecords

from jaxcart.run import loggers
from jaxcart.run.lifecycle import run_new
from jaxcart.run.loggers import LoggerError, LoggerUnavailable, MetricBatch, make_logger
from jaxcart.run.spec import Hooks, RunOptions, RunSpec
from jaxcart.rundir import layout

RUNS = ["seed0", "seed1"]
BATCH = 128  # env steps per iteration


def synthetic_chunks(num_chunks: int = 3, size: int = 2):
    """``(first_iteration, env_steps [n], metrics [n, 2])`` per chunk; run 0 has no finished
    episode (NaN ep_rew_mean) during the first chunk, run 1 has one from the start."""
    chunks = []
    for c in range(num_chunks):
        first = c * size
        iterations = first + 1 + np.arange(size)
        reward = np.stack([10.0 * iterations, 20.0 * iterations + 1], axis=1)
        if c == 0:
            reward[:, 0] = np.nan
        metrics = {
            "rollout/ep_rew_mean": reward.astype(np.float32),
            "train/approx_kl": np.stack([0.01 * iterations, 0.02 * iterations], 1).astype(
                np.float32
            ),
            "time/fps": np.repeat((100.0 * iterations)[:, None], 2, 1).astype(np.float32),
        }
        chunks.append((first, iterations * BATCH, metrics))
    return chunks


def expected_points(chunks, run: int) -> dict[str, list[tuple[int, float]]]:
    """tag -> [(step, value)] that a per-run writer should hold, NaNs left out."""
    points: dict[str, list[tuple[int, float]]] = {}
    for first, steps, metrics in chunks:
        for i, step in enumerate(steps):
            points.setdefault("time/iterations", []).append((int(step), first + i + 1))
            for name, values in metrics.items():
                if not np.isnan(values[i, run]):
                    points.setdefault(name, []).append((int(step), float(values[i, run])))
    return points


def test_tensorboard_one_run_per_seed_with_env_step_axis(tmp_path):
    pytest.importorskip("tensorboardX")
    from tensorboardX.proto.event_pb2 import Event

    chunks = synthetic_chunks()
    with make_logger(["tensorboard"], tmp_path, RUNS, {"learning_rate": 2.5e-4}) as logger:
        for chunk in chunks:
            logger.log(*chunk)

    for r, run in enumerate(RUNS):
        files = list((tmp_path / "tensorboard" / run).glob("events.out.tfevents.*"))
        assert len(files) == 1
        scalars: dict[str, list[tuple[int, float]]] = {}
        texts = []
        for record in read_tfrecords(files[0]):
            event = Event.FromString(record)
            for value in event.summary.value:
                if value.HasField("simple_value"):
                    scalars.setdefault(value.tag, []).append((event.step, value.simple_value))
                else:
                    texts.append(value.tensor.string_val[0].decode())
        expected = expected_points(chunks, r)
        assert sorted(scalars) == sorted(expected)
        for tag, points in expected.items():
            got = scalars[tag]
            assert [s for s, _ in got] == [s for s, _ in points], tag
            np.testing.assert_allclose([v for _, v in got], [v for _, v in points], rtol=1e-6)
        # NaNs skipped: run 0 has no ep_rew_mean in the first chunk (steps 128 and 256).
        first_step = scalars["rollout/ep_rew_mean"][0][0]
        assert first_step == (3 * BATCH if r == 0 else BATCH)
        assert any("learning_rate" in t for t in texts)


def test_swanlab_offline_one_experiment_with_per_run_and_mean(tmp_path, monkeypatch, capsys):
    pytest.importorskip("swanlab")
    monkeypatch.setenv("CI", "true")
    monkeypatch.setenv("SWANLAB_WEBHOOK", "http://127.0.0.1:9/hook")  # must not be called
    monkeypatch.delenv("SWANLAB_LOG_DIR", raising=False)  # SwanLab's local mode sets it
    monkeypatch.chdir(tmp_path)  # SwanLab reads ./.env and ./swanlab.yaml; keep it clean
    network = []
    monkeypatch.setattr(socket, "getaddrinfo", lambda *a, **k: network.append(a) or [])
    monkeypatch.setattr(socket.socket, "connect", lambda self, addr: network.append(addr))
    chunks = synthetic_chunks()
    (tmp_path / "out").mkdir()  # the run directory exists before its loggers open
    with make_logger(["swanlab"], tmp_path / "out", RUNS, {"learning_rate": 2.5e-4}) as logger:
        for chunk in chunks:
            logger.log(*chunk)

    assert network == []
    assert capsys.readouterr().out.count("`swanlab ") == 1  # its sync/watch hint, once
    run_dirs = list((tmp_path / "swanlog").glob("run-*"))  # ./swanlog, SwanLab's default
    assert len(run_dirs) == 1
    records_file = next(run_dirs[0].glob("*.swanlab"))
    assert records_file.stat().st_size > 0
    assert "learning_rate" in (run_dirs[0] / "files" / "config.yaml").read_text()

    try:  # SwanLab's own record reader (internal API): check the values when it is there
        from swanlab.proto.swanlab.record.v1.record_pb2 import Record
        from swanlab.sdk.internal.core_python.store import DataStoreReader
    except ImportError:
        pytest.skip("this SwanLab version has no record reader to check values with")
    reader = DataStoreReader()
    reader.open(records_file)
    logged: dict[str, list[tuple[int, float]]] = {}
    finished = False
    for payload in reader:
        record = Record.FromString(payload)
        finished |= record.HasField("finish")
        if record.HasField("scalar"):
            scalar = record.scalar
            logged.setdefault(scalar.key, []).append((scalar.step, scalar.value.number))
    reader.close()
    assert finished

    def check(key, points):
        assert [s for s, _ in logged.get(key, [])] == [s for s, _ in points], key
        np.testing.assert_allclose([v for _, v in logged[key]], [v for _, v in points], rtol=1e-6)

    per_run = [expected_points(chunks, r) for r in range(2)]
    for r, run in enumerate(RUNS):
        for name in ("rollout/ep_rew_mean", "train/approx_kl"):
            check(f"{run}/{name}", per_run[r][name])
    assert not any(key.startswith("seed0/time/") for key in logged)
    check("time/fps", per_run[0]["time/fps"])
    check("time/iterations", per_run[0]["time/iterations"])
    # The mean over runs that have a value: run 1 alone while run 0's is NaN.
    mean = []
    for first, steps, metrics in chunks:
        for i, step in enumerate(steps):
            row = metrics["rollout/ep_rew_mean"][i]
            mean.append((int(step), float(np.nanmean(row))))
    check("rollout/ep_rew_mean", mean)


def test_swanlab_runs_logged_apart_get_their_mean_once_every_run_has_the_step(
    tmp_path, monkeypatch
):
    """SB3's seeds train apart and are logged one run at a time: each run's names at once, the
    mean under the plain name once every run has logged that step (SwanLab keeps the first)."""
    pytest.importorskip("swanlab")
    monkeypatch.setenv("CI", "true")
    monkeypatch.delenv("SWANLAB_LOG_DIR", raising=False)  # SwanLab's local mode sets it
    monkeypatch.chdir(tmp_path)
    (tmp_path / "out").mkdir()
    steps = np.array([BATCH, 2 * BATCH])
    with make_logger(["swanlab"], tmp_path / "out", RUNS) as logger:
        logger.log(0, steps, {"rollout/ep_rew_mean": [10.0, 20.0]}, run=0)
        logger.log(0, steps[:1], {"rollout/ep_rew_mean": [[30.0]]}, run=1)
    logged = read_swanlog(tmp_path / "swanlog")["out"]
    assert logged["seed0/rollout/ep_rew_mean"] == [(BATCH, 10.0), (2 * BATCH, 20.0)]
    assert logged["seed1/rollout/ep_rew_mean"] == [(BATCH, 30.0)]
    assert logged["rollout/ep_rew_mean"] == [(BATCH, 20.0)]  # run 1 never logged step 256


def read_live_swanlog(folder: Path) -> dict[str, list[tuple[int, float]]]:
    """Scalar key -> ``[(step, value)]`` of the SwanLab experiments in ``folder`` as their records
    files hold them now, finished or not (a file still empty, or a record still being written at
    its end, reads as what comes before it)."""
    from swanlab.proto.swanlab.record.v1.record_pb2 import Record
    from swanlab.sdk.internal.core_python.store import DataStoreReader

    scalars: dict[str, list[tuple[int, float]]] = {}
    for path in sorted(Path(folder).glob("run-*/*.swanlab")):
        if path.stat().st_size < 7:  # not even SwanLab's file header yet
            continue
        reader = DataStoreReader()
        reader.open(path)
        for payload in reader:  # stops at the first incomplete record
            record = Record.FromString(payload)
            if record.HasField("scalar"):
                point = (record.scalar.step, record.scalar.value.number)
                scalars.setdefault(record.scalar.key, []).append(point)
        reader.close()
    return scalars


def wait_for_steps(read, key: str, wanted: list[int], seconds: float = 60.0) -> dict:
    """Polls ``read()`` (a logger's folder read back) until ``key``'s steps are ``wanted`` or
    ``seconds`` pass; returns what it read last."""
    deadline, scalars = time.monotonic() + seconds, {}
    while time.monotonic() < deadline:
        scalars = read()
        if [step for step, _ in scalars.get(key, [])] == wanted:
            break
        time.sleep(0.05)
    return scalars


@pytest.mark.slow
def test_swanlab_holds_the_curve_on_disk_while_jaxcart_trains(tmp_path, monkeypatch):
    """Issue 40: SwanLab's records reach the disk as the run trains, not when SwanLab finishes.
    Blocked in its fifth chunk's hook, a run's ./swanlog records file already holds the five
    iterations logged so far; the finished file holds all eight, the same values first."""
    pytest.importorskip("swanlab")
    pytest.importorskip("swanlab.sdk.internal.core_python.store")  # imported before training
    monkeypatch.setenv("CI", "true")
    monkeypatch.delenv("SWANLAB_LOG_DIR", raising=False)
    monkeypatch.chdir(tmp_path)
    out, seen = tmp_path / "out", []
    steps = [TINY.batch_size * i for i in range(1, 9)]

    def on_chunk(progress) -> None:
        if progress.iteration == 5:
            read = lambda: read_live_swanlog(tmp_path / "swanlog")
            scalars = wait_for_steps(read, "train/approx_kl", steps[:5])
            seen.append((scalars, (out / layout.EVALUATION_FILE).exists()))

    spec = RunSpec(config=dataclasses.replace(TINY, total_timesteps=1024), num_seeds=1)
    options = RunOptions(eval_episodes=2, compile_cache=False, chunk_size=1, loggers=("swanlab",))
    run_new(spec, out=out, options=options, hooks=Hooks(on_chunk=on_chunk))

    ((during, finished_then),) = seen
    assert not finished_then
    for key in ("train/approx_kl", "time/iterations", "train/n_updates"):
        assert [step for step, _ in during[key]] == steps[:5], key
    assert [value for _, value in during["time/iterations"]] == [1, 2, 3, 4, 5]
    after = read_swanlog(tmp_path / "swanlog")["out"]
    assert [step for step, _ in after["train/approx_kl"]] == steps
    assert after["train/approx_kl"][:5] == during["train/approx_kl"]


class RecordingBackend:
    """Stands in for a real backend; while ``gate`` is set and closed, every write waits for
    it to open (a writer as slow as the test wants, without a race against the clock)."""

    name = "recording"
    module = None
    extra = None
    gate: threading.Event | None = None
    fail_in: str | None = None
    instances: ClassVar[list["RecordingBackend"]] = []

    def __init__(self, out_dir, run_names, config, log_dir=None):
        self.batches: list[MetricBatch] = []
        self.calls: list[str] = []
        self.thread_names: set[str] = set()
        RecordingBackend.instances.append(self)

    def _call(self, what):
        self.calls.append(what)
        self.thread_names.add(threading.current_thread().name)
        if self.fail_in == what:
            raise OSError(f"disk full during {what}")

    def open(self):
        self._call("open")

    def write(self, batch):
        if self.gate is not None:
            assert self.gate.wait(timeout=120), "the test never opened the gate"
        self._call("write")
        self.batches.append(batch)

    def close(self):
        self._call("close")


def read_wandb_records(path: Path) -> list[bytes]:
    """Payloads of a W&B ``.wandb`` file: a 7-byte header, then LevelDB-log records (crc u32,
    length u16, type u8: 1 full, 2 first, 3 middle, 4 last) in 32 KiB blocks, whose last < 7
    bytes are padding."""
    data, block, pos = path.read_bytes(), 32768, 7
    assert data[:4] == b":W&B"
    payloads, pending = [], b""
    while pos + 7 <= len(data):
        left = block - pos % block
        if left < 7:
            pos += left
            continue
        _, length, kind = struct.unpack("<IHB", data[pos : pos + 7])
        chunk, pos = data[pos + 7 : pos + 7 + length], pos + 7 + length
        if kind == 1:
            payloads.append(chunk)
        elif kind in (2, 3):
            pending += chunk
        elif kind == 4:
            payloads.append(pending + chunk)
            pending = b""
    return payloads


def test_wandb_offline_one_run_per_seed_grouped_by_run_dir(tmp_path, monkeypatch):
    pytest.importorskip("wandb")
    from wandb.proto import wandb_internal_pb2

    monkeypatch.delenv("WANDB_MODE", raising=False)  # offline is jaxcart's default
    monkeypatch.chdir(tmp_path)
    chunks = synthetic_chunks()
    with make_logger(["wandb"], tmp_path / "out", RUNS, {"learning_rate": 2.5e-4}) as logger:
        for chunk in chunks:
            logger.log(*chunk)

    files = sorted((tmp_path / "out" / "wandb").glob("offline-run-*/run-*.wandb"))
    assert len(files) == 2  # one offline run per seed
    seen = set()
    for path in files:
        logged: dict[str, list[tuple[int, float]]] = {}
        run = None
        for payload in read_wandb_records(path):
            record = wandb_internal_pb2.Record.FromString(payload)
            if record.HasField("run"):
                run = record.run
            if record.HasField("history"):
                for item in record.history.item:
                    key = item.key or "/".join(item.nested_key)
                    if not key.startswith("_"):
                        value = float(item.value_json)
                        logged.setdefault(key, []).append((record.history.step.num, value))
        assert run is not None and run.project == "jaxcart" and run.run_group == "out"
        config = {item.key: item.value_json for item in run.config.update}
        name = config["run_name"].strip('"')
        assert run.display_name == f"out-{name}" and config["learning_rate"] == "0.00025"
        seen.add(name)
        expected = expected_points(chunks, RUNS.index(name))
        assert set(logged) == set(expected)
        for key, points in expected.items():
            assert [step for step, _ in logged[key]] == [step for step, _ in points], key
            np.testing.assert_allclose(
                [v for _, v in logged[key]], [v for _, v in points], rtol=1e-6
            )
    assert seen == set(RUNS)


def test_wandb_project_entity_and_dir_from_the_environment(tmp_path, monkeypatch):
    pytest.importorskip("wandb")
    from wandb.proto import wandb_internal_pb2

    monkeypatch.delenv("WANDB_MODE", raising=False)
    monkeypatch.setenv("WANDB_PROJECT", "course")
    monkeypatch.setenv("WANDB_ENTITY", "student")
    monkeypatch.setenv("WANDB_DIR", str(tmp_path / "wandb-home"))
    monkeypatch.chdir(tmp_path)
    with make_logger(["wandb"], tmp_path / "out", RUNS) as logger:
        logger.log(*synthetic_chunks(1)[0])
    assert not (tmp_path / "out" / "wandb").exists()
    path = next((tmp_path / "wandb-home" / "wandb").glob("offline-run-*/run-*.wandb"))
    runs = [wandb_internal_pb2.Record.FromString(p) for p in read_wandb_records(path)]
    (run,) = [r.run for r in runs if r.HasField("run")]
    assert (run.project, run.entity) == ("course", "student")


def test_one_logger_dir_holds_tensorboard_runs_of_several_run_directories(tmp_path):
    pytest.importorskip("tensorboardX")
    for out in ("a", "b"):
        with make_logger(["tensorboard"], tmp_path / out, RUNS, log_dir=tmp_path / "tb") as log:
            log.log(*synthetic_chunks(1)[0])
    found = sorted(p.parent.relative_to(tmp_path) for p in tmp_path.glob("tb/*/*/events.*"))
    assert [str(p) for p in found] == ["tb/a/seed0", "tb/a/seed1", "tb/b/seed0", "tb/b/seed1"]
    assert not (tmp_path / "a" / "tensorboard").exists()


def test_elapsed_time_is_logged_under_sb3s_name(tmp_path, recording):
    first, steps, metrics = synthetic_chunks(1)[0]
    with make_logger(["recording"], tmp_path, RUNS) as logger:
        logger.log(first, steps, {**metrics, "time/elapsed": np.array([1.0, 2.0])})
    (batch,) = recording.instances[0].batches
    assert "time/time_elapsed" in batch.metrics and "time/elapsed" not in batch.metrics


def test_wandb_mode_from_the_environment_is_respected(tmp_path, monkeypatch):
    pytest.importorskip("wandb")
    monkeypatch.setenv("WANDB_MODE", "disabled")
    monkeypatch.chdir(tmp_path)
    with make_logger(["wandb"], tmp_path / "out", RUNS) as logger:
        logger.log(*synthetic_chunks(1)[0])
    assert not list((tmp_path / "out").glob("wandb/offline-run-*"))


@pytest.fixture
def recording(monkeypatch):
    monkeypatch.setitem(loggers.BACKENDS, "recording", RecordingBackend)
    monkeypatch.setattr(RecordingBackend, "instances", [])
    return RecordingBackend


def test_log_returns_at_once_while_a_slow_writer_catches_up(tmp_path, recording, monkeypatch):
    gate = threading.Event()
    monkeypatch.setattr(recording, "gate", gate)
    logger = make_logger(["recording"], tmp_path, RUNS)
    chunks = synthetic_chunks(num_chunks=5)
    for chunk in chunks:
        logger.log(*chunk)
    # log() handed the chunks over without waiting for the writer, which is held at the gate
    assert recording.instances[0].calls.count("write") == 0
    chunks[0][2]["train/approx_kl"][:] = -1.0  # the logger kept its own copy
    gate.set()
    logger.close()

    backend = recording.instances[0]
    assert backend.calls == ["open"] + ["write"] * 5 + ["close"]
    assert backend.thread_names == {"jaxcart-logger-recording"}
    assert [b.first_iteration for b in backend.batches] == [0, 2, 4, 6, 8]
    assert backend.batches[0].metrics["train/approx_kl"][0, 1] == pytest.approx(0.02)
    np.testing.assert_array_equal(backend.batches[1].env_steps, [3 * BATCH, 4 * BATCH])
    np.testing.assert_array_equal(backend.batches[1].iterations, [3, 4])
    logger.close()  # idempotent


@pytest.mark.parametrize("stage", ["open", "write"])
def test_writer_error_is_reported_once_and_raised_on_close(
    tmp_path, recording, monkeypatch, capsys, stage
):
    monkeypatch.setattr(recording, "fail_in", stage)
    logger = make_logger(["recording"], tmp_path, RUNS)
    for chunk in synthetic_chunks():
        logger.log(*chunk)  # training goes on
    with pytest.raises(LoggerError, match=r"recording logging failed.*disk full") as info:
        logger.close()
    assert isinstance(info.value.__cause__, OSError)
    assert "disk full" in str(logger.errors["recording"])
    err = capsys.readouterr().err
    assert err.count("warning: recording logging failed") == 1
    backend = recording.instances[0]
    assert backend.calls.count("write") == (1 if stage == "write" else 0)
    assert backend.calls[-1] == "close"  # still closed, to flush what was written
    logger.close()  # idempotent: raised once


def test_context_manager_lets_the_training_error_through(tmp_path, recording, monkeypatch):
    monkeypatch.setattr(recording, "fail_in", "write")
    with pytest.raises(KeyError, match="training"):
        with make_logger(["recording"], tmp_path, RUNS) as logger:
            logger.log(*synthetic_chunks()[0])
            raise KeyError("training")
    assert "recording" in logger.errors


def test_shapes_are_checked_when_logging(tmp_path, recording):
    logger = make_logger(["recording"], tmp_path, RUNS)
    steps = np.array([128, 256])
    with pytest.raises(ValueError, match="'train/loss' has shape \\(2, 3\\)"):
        logger.log(0, steps, {"train/loss": np.zeros((2, 3))})
    with pytest.raises(ValueError, match="run 2 is not one of the 2 runs"):
        logger.log(0, steps, {}, run=2)
    with pytest.raises(ValueError, match="expected \\(2, 1\\)"):
        logger.log(0, steps, {"train/loss": np.zeros((2, 2))}, run=1)
    logger.log(0, steps, {"time/fps": np.array([1.0, 2.0])})  # [n]: the same for every run
    logger.log(0, steps, {"time/fps": np.array([3.0, 4.0])}, run=1)  # run 1's alone
    logger.close()
    first, second = recording.instances[0].batches
    np.testing.assert_array_equal(first.metrics["time/fps"], [[1, 1], [2, 2]])
    assert first.runs == (0, 1) and second.runs == (1,)
    np.testing.assert_array_equal(second.metrics["time/fps"], [[3], [4]])
    with pytest.raises(RuntimeError, match="after close"):
        logger.log(0, steps, {})


def test_no_loggers_is_a_no_op(tmp_path):
    with make_logger([], tmp_path / "out", RUNS, {}) as logger:
        for chunk in synthetic_chunks():
            logger.log(*chunk)
    assert logger.names == []
    assert not (tmp_path / "out").exists()
    assert not [t for t in threading.enumerate() if t.name.startswith("jaxcart-logger")]


@pytest.mark.parametrize(
    ("name", "module"),
    [("tensorboard", "tensorboardX"), ("swanlab", "swanlab"), ("wandb", "wandb")],
)
def test_missing_package_names_the_extra(tmp_path, monkeypatch, name, module):
    monkeypatch.setitem(sys.modules, module, None)  # makes the import fail
    with pytest.raises(LoggerUnavailable, match=rf"pip install 'jaxcart\[{name}\]'") as info:
        make_logger([name], tmp_path, RUNS)
    assert isinstance(info.value, ValueError)
    assert "\n" not in str(info.value)


def test_bad_names_are_rejected(tmp_path):
    with pytest.raises(ValueError, match="unknown logger") as info:
        make_logger(["neptune"], tmp_path, RUNS)
    assert not isinstance(info.value, LoggerUnavailable)
    with pytest.raises(ValueError, match="unique"):
        make_logger([], tmp_path, ["seed0", "seed0"])
    with pytest.raises(ValueError, match="directory names"):
        make_logger([], tmp_path, ["../escape"])
    assert tuple(loggers.BACKENDS) == ("tensorboard", "swanlab", "wandb")


@pytest.mark.parametrize(
    ("installed", "mode"), [(None, "offline"), ("0.1.10b2", "local"), ("0.1.6", "offline")]
)
def test_swanlab_mode_is_local_only_with_the_dashboard_swanlab_pins(monkeypatch, installed, mode):
    from importlib import metadata

    def version(name):
        if name != "swanboard" or installed is None:
            raise metadata.PackageNotFoundError(name)
        return installed

    monkeypatch.setattr(metadata, "version", version)
    monkeypatch.setattr(
        metadata, "requires", lambda name: ["swanboard==0.1.10b2; extra == 'dashboard'"]
    )
    monkeypatch.delenv("SWANLAB_SKIP_SWANBOARD_VERSION_CHECK", raising=False)
    assert loggers.swanlab_mode() == mode

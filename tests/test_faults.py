"""Fault injection: real training runs killed at random moments and resumed, and every bad
input a user can give, each rejected with one line, exit code 2 and no traceback.

The figures (runs killed, resumes verified identical, bad inputs tried/rejected) are printed
in pytest's terminal summary.
"""

from __future__ import annotations

import errno
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import FAULT_FIGURES
from helpers import TRAIN_ENV, WAIT_S, assert_same_run_dirs, seal, start_train, tiny_args

from jaxcart.rundir import layout
from jaxcart.rundir.files import RunDirError
from jaxcart.rundir.reader import read_checkpoint_meta

RUN = [*tiny_args(25600, num_seeds=2), "--seed", "11", "--checkpoint-every", "0.2"]


def _run(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "jaxcart.train", *args],
        env=TRAIN_ENV,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


@pytest.mark.slow
def test_sigkill_at_random_moments_loses_nothing(tmp_path):
    """SIGKILL (no chance to clean up) at random moments, then --resume, repeatedly: every
    interrupted run ends bit-identical to the uninterrupted one and no checkpoint is ever
    unreadable."""
    reference = tmp_path / "reference"
    done = _run(*RUN, "--out", str(reference))
    assert done.returncode == 0, done.stdout + done.stderr

    rng = random.Random(2026)
    for trial in range(3):
        out = tmp_path / f"killed-{trial}"
        proc = start_train(*RUN, "--out", str(out))
        kills = 0
        while True:
            try:
                proc.wait(timeout=rng.uniform(0.5, 3.0) if kills == 0 else rng.uniform(1.0, 5.0))
                break  # finished before the kill
            except subprocess.TimeoutExpired:
                proc.kill()  # SIGKILL
                proc.wait()
                kills += 1
                FAULT_FIGURES["runs killed (SIGKILL)"] += 1
                if not (out / "config.json").exists():  # killed before it wrote anything
                    proc = start_train(*RUN, "--out", str(out))
                    continue
                # whatever moment it died, a checkpoint on disk is complete and readable
                if (out / layout.CHECKPOINT_FILE).exists():
                    meta = read_checkpoint_meta(out / layout.CHECKPOINT_FILE)
                    assert 0 <= meta["iteration"] <= 200
                if (out / "evaluation.json").exists():
                    break  # killed after its last write: the run is complete
                proc = start_train("--resume", str(out), "--quiet")
                if kills >= 4:
                    proc.wait(timeout=300)
                    break
        assert proc.returncode in (0, -signal.SIGKILL), proc.stdout.read()
        assert_same_run_dirs(reference, out)
        FAULT_FIGURES["interrupted runs verified bit-identical"] += 1
    assert FAULT_FIGURES["runs killed (SIGKILL)"] >= 3


@pytest.mark.slow
def test_sigint_checkpoints_and_prints_resume_command(tmp_path):
    out = tmp_path / "ctrl-c"
    proc = start_train(*RUN, "--out", str(out))
    deadline = time.monotonic() + WAIT_S
    while proc.poll() is None:
        if (out / layout.CHECKPOINT_FILE).exists() and read_checkpoint_meta(
            out / layout.CHECKPOINT_FILE
        )["iteration"] > 0:
            break
        assert time.monotonic() < deadline, f"no checkpoint past iteration 0 in {WAIT_S:.0f} s"
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    text, _ = proc.communicate(timeout=120)
    if proc.returncode == 0:
        pytest.skip("finished before Ctrl-C")
    assert proc.returncode == 128 + signal.SIGINT, text
    assert "SIGINT received" in text and f"--resume {out}" in text and "Traceback" not in text
    FAULT_FIGURES["runs killed (SIGINT)"] += 1


def _corrupt_checkpoint(run: Path) -> None:
    path = run / layout.CHECKPOINT_FILE
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def _old_version_checkpoint(run: Path) -> None:
    path = run / layout.CHECKPOINT_FILE
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(bytes(arrays["__meta__"]).decode())
    meta["versions"]["jax"] = "0.0.1"
    arrays["__meta__"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    np.savez(path, **arrays)


def _garbled_config(run: Path) -> None:
    (run / "config.json").write_text("{not json")


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory):
    """A finished tiny run, trained in this process (two CPU devices, as a subprocess with
    TRAIN_ENV has): the directory the bad-input cases copy and damage."""
    from jaxcart.train import main

    out = tmp_path_factory.mktemp("bad") / "run"
    argv = [
        *("--num-envs", "4", "--num-steps", "32", "--total-timesteps", "256"),
        *("--minibatch-size", "64", "--update-epochs", "1", "--eval-episodes", "1"),
    ]
    assert main([*argv, "--quiet", "--no-compile-cache", "--out", str(out)]) == 0
    return out


BAD_OPTIONS = [
    (["--minibatch-size", "100"], "does not divide"),
    (["--learning-rate", "0"], "learning_rate must be > 0"),
    (["--learning-rate", "-3e-4"], "learning_rate must be > 0"),
    (["--total-timesteps", "0"], "--total-timesteps must be a positive integer"),
    (["--total-timesteps", "1.5e0"], "--total-timesteps: expected a whole number"),
    (["--num-steps", "-5"], "--num-steps must be a positive integer"),
    (["--gamma", "0"], "gamma must be in (0, 1]"),
    (["--gamma", "1.01"], "gamma must be in (0, 1]"),
    (["--gae-lambda", "2"], "gae_lambda must be in (0, 1]"),
    (["--ent-coef", "-0.1"], "ent_coef must be >= 0"),
    (["--vf-coef", "-1"], "vf_coef must be >= 0"),
    (["--clip-coef", "-0.2"], "clip_coef must be > 0"),
    (["--max-grad-norm", "0"], "max_grad_norm must be > 0"),
    (["--learning-rate", "nan"], "learning_rate must be a finite number"),
    (["--num-seeds", "0"], "--num-seeds must be a positive integer"),
    (["--num-seeds", "-4"], "--num-seeds must be a positive integer"),
    (["--preset", "ppo2"], "unknown preset"),
    (["--not-an-option"], "unrecognized arguments"),
    (["--num-envs", "four"], "--num-envs: expected a whole number"),
    (["--activation", "gelu"], "activation must be 'tanh' or 'relu'"),
    (["--hidden-sizes", "64,,x"], "comma-separated integers"),
    (["--sweep", "learning_rate"], "malformed --sweep"),
    (["--sweep", "learning_rate=fast"], "values must be numbers"),
    (["--sweep", "activation=tanh,relu"], "cannot sweep 'activation'"),
    (["--sweep", "gamma=0.9,2"], "out of range"),
    (["--eval-episodes", "0"], "--eval-episodes must be a positive integer"),
    (["--checkpoint-every", "0"], "--checkpoint-every must be in (0, 31536000] seconds"),
]


@pytest.mark.parametrize("argv, message", BAD_OPTIONS, ids=[" ".join(a) for a, _ in BAD_OPTIONS])
def test_bad_option_rejected_before_compiling(argv, message, tmp_path):
    from jaxcart.train import main

    out = tmp_path / "never"
    FAULT_FIGURES["bad inputs tried"] += 1
    proc_err = _capture(lambda: main([*argv, "--out", str(out)]))
    code, err = proc_err
    assert code == 2, err
    assert message in err, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not out.exists() or not any(out.iterdir())
    FAULT_FIGURES["bad inputs rejected cleanly"] += 1


def _capture(fn):
    import contextlib
    import io

    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        code = fn()
    return code, err.getvalue()


@pytest.mark.parametrize(
    "damage, message",
    [
        (_corrupt_checkpoint, "corrupted"),
        (_old_version_checkpoint, "trained with jax 0.0.1"),
        (_garbled_config, "corrupted or from an incompatible version"),
    ],
    ids=["truncated-checkpoint", "other-jax-version", "garbled-config"],
)
def test_bad_resume_directories_rejected(damage, message, finished_run, tmp_path):
    import shutil

    run = tmp_path / "copy"
    shutil.copytree(finished_run, run)
    (run / "evaluation.json").unlink()  # pretend it was interrupted
    damage(run)
    seal(run)  # crafted, digests and all: the checks behind the manifest refuse it
    FAULT_FIGURES["bad inputs tried"] += 1
    from jaxcart.train import main

    code, err = _capture(lambda: main(["--resume", str(run)]))  # the command, in this process
    assert code == 2, err
    assert message in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    FAULT_FIGURES["bad inputs rejected cleanly"] += 1


def test_other_bad_paths(finished_run, tmp_path):
    from jaxcart.train import main

    cases = []
    (tmp_path / "file").write_text("x")
    cases.append((["--out", str(tmp_path / "file")], "not a directory"))
    cases.append((["--out", str(finished_run)], "is not empty"))
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    if os.access(locked, os.W_OK):  # root ignores permissions: use a path under a file instead
        cases.append((["--out", str(tmp_path / "file" / "sub")], "cannot write"))
    else:
        cases.append((["--out", str(locked / "sub")], "cannot write"))
    cases.append((["--resume", str(tmp_path / "missing")], "cannot resume"))
    cases.append((["--resume", str(finished_run)], "nothing to resume. To train it further"))
    cases.append((["--resume", str(finished_run), "--seed", "3"], "drop --seed"))
    for argv, message in cases:
        FAULT_FIGURES["bad inputs tried"] += 1
        code, err = _capture(lambda argv=argv: main(argv))
        assert code == 2 and message in err and len(err.strip().splitlines()) == 1, (argv, err)
        FAULT_FIGURES["bad inputs rejected cleanly"] += 1

    import jaxcart

    for path in (tmp_path, tmp_path / "missing", tmp_path / "file"):
        FAULT_FIGURES["bad inputs tried"] += 1
        with pytest.raises(RunDirError):
            jaxcart.load_policy(path)
        FAULT_FIGURES["bad inputs rejected cleanly"] += 1


# --- one process per run directory ------------------------------------------------------


def _wait_for(predicate, timeout: float = WAIT_S) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError("timed out waiting")
        time.sleep(0.02)


@pytest.mark.slow
def test_concurrent_use_of_a_run_is_refused_and_a_killed_holder_never_blocks(tmp_path):
    out = tmp_path / "busy"
    holder = start_train(*RUN, "--out", str(out))
    _wait_for(lambda: (out / layout.CHECKPOINT_FILE).exists())
    second = _run("--resume", str(out), "--quiet", timeout=120)
    FAULT_FIGURES["concurrent starts tried"] += 1
    assert second.returncode == 2, second.stdout + second.stderr
    assert f"in use by another jaxcart process (PID {holder.pid})" in second.stderr
    assert len(second.stderr.strip().splitlines()) == 1 and "Traceback" not in second.stderr
    FAULT_FIGURES["concurrent starts refused"] += 1
    holder.kill()  # SIGKILL: the lock file stays, the lock does not
    holder.wait()
    assert (out / ".lock").exists()
    resumed = _run("--resume", str(out), "--quiet")
    assert resumed.returncode == 0, resumed.stdout + resumed.stderr


# --- signals at any moment ----------------------------------------------------------------


def _signal_when(proc, ready, sig: int, then: float = 0.0) -> str:
    _wait_for(lambda: ready() or proc.poll() is not None)
    if not ready():  # it ended before its moment came: say how, not "timed out"
        raise AssertionError(f"exited {proc.returncode} first:\n{proc.communicate()[0][-2000:]}")
    time.sleep(then)
    proc.send_signal(sig)
    text, _ = proc.communicate(timeout=300)
    return text


def _clean_stop(text: str, code: int, proc, sig: int) -> None:
    assert proc.returncode == code, text
    assert "Traceback" not in text and f"{signal.Signals(sig).name} received" in text
    FAULT_FIGURES[f"runs stopped by {signal.Signals(sig).name} cleanly"] += 1


@pytest.mark.slow
def test_sigint_during_compilation_is_acknowledged_at_once(tmp_path):
    out = tmp_path / "compiling"
    proc = start_train(*RUN, "--out", str(out), "--no-compile-cache")
    # the iteration-0 checkpoint is written just before compiling starts
    text = _signal_when(proc, lambda: (out / layout.CHECKPOINT_FILE).exists(), signal.SIGINT)
    _clean_stop(text, 128 + signal.SIGINT, proc, signal.SIGINT)
    # the message came before compilation ended, not after it
    assert text.index("SIGINT received") < text.index("compiled the fused training step")
    assert "stopped at iteration 0/200" in text and f"--resume {out}" in text
    assert read_checkpoint_meta(out / layout.CHECKPOINT_FILE)["iteration"] == 0


@pytest.mark.slow
def test_sigterm_during_initialisation_of_a_large_run(tmp_path):
    out = tmp_path / "init"
    big = ["--num-seeds", "30000", "--wave-size", "16384", "--num-envs", "1", "--num-steps", "64"]
    proc = start_train(*big, "--minibatch-size", "64", "--total-timesteps", "64", "--out", str(out))
    text = _signal_when(proc, lambda: (out / "config.json").exists(), signal.SIGTERM, 0.3)
    _clean_stop(text, 128 + signal.SIGTERM, proc, signal.SIGTERM)
    assert "stopped before training started" in text and f"--resume {out}" in text


@pytest.mark.slow
def test_sigint_during_evaluation_then_resume_evaluates(tmp_path):
    out = tmp_path / "evaluating"
    args = [*tiny_args(512, num_seeds=2, eval_episodes=200), "--out", str(out)]
    proc = start_train(*args)
    text = _signal_when(
        proc, lambda: (out / "metrics.csv").exists() or _trained(out), signal.SIGINT
    )
    if proc.returncode == 0:
        pytest.skip("the evaluation finished before SIGINT arrived")
    _clean_stop(text, 128 + signal.SIGINT, proc, signal.SIGINT)
    assert not (out / "evaluation.json").exists()
    resumed = _run("--resume", str(out), "--quiet")
    assert resumed.returncode == 0 and (out / "evaluation.json").exists(), resumed.stderr


def _trained(out: Path) -> bool:
    path = out / layout.CHECKPOINT_FILE
    try:
        return path.exists() and read_checkpoint_meta(path)["iteration"] == 4
    except RunDirError:
        return False


@pytest.mark.slow
def test_second_sigint_stops_at_once_and_leaves_the_checkpoint_valid(tmp_path):
    out = tmp_path / "twice"
    proc = start_train(*RUN, "--out", str(out), "--no-compile-cache")
    _wait_for(lambda: (out / layout.CHECKPOINT_FILE).exists())
    proc.send_signal(signal.SIGINT)
    time.sleep(0.3)
    proc.send_signal(signal.SIGINT)
    text, _ = proc.communicate(timeout=60)
    _clean_stop(text, 128 + signal.SIGINT, proc, signal.SIGINT)
    meta = read_checkpoint_meta(out / layout.CHECKPOINT_FILE)  # readable
    assert f"stopped at once; the checkpoint in {out} (at iteration {meta['iteration']}/" in text
    assert f"--resume {out}" in text
    resumed = _run("--resume", str(out), "--quiet")
    assert resumed.returncode == 0, resumed.stdout + resumed.stderr


# --- full and read-only disks -------------------------------------------------------------

SMALL_RUN = [*tiny_args(6400, num_seeds=2), "--seed", "5", "--no-compile-cache"]


@pytest.mark.slow
def test_a_failing_checkpoint_write_keeps_the_last_one_and_resume_finishes(
    tmp_path, monkeypatch, capsys
):
    """ENOSPC injected into the third checkpoint write: one line naming the file, exit 1,
    the previous checkpoint intact and no temporary left; --resume then finishes the run
    bit-identically once writes work again."""
    from jaxcart.rundir import files
    from jaxcart.train import main

    reference = tmp_path / "reference"
    assert main([*SMALL_RUN, "--out", str(reference)]) == 0
    out = tmp_path / "full-disk"
    real_fdopen, writes = files.os.fdopen, []

    def fdopen(fd, mode="r", *args, **kwargs):
        f = real_fdopen(fd, mode, *args, **kwargs)
        name = os.readlink(f"/proc/self/fd/{fd}")
        if ".checkpoint.npz." in name:
            writes.append(name)
            if len(writes) == 3:
                f.write = lambda data: (_ for _ in ()).throw(
                    OSError(errno.ENOSPC, "No space left on device")
                )
        return f

    monkeypatch.setattr(files.os, "fdopen", fdopen)
    capsys.readouterr()
    code = main([*SMALL_RUN, "--out", str(out), "--checkpoint-every", "0.001"])
    err = capsys.readouterr().err
    FAULT_FIGURES["failing writes injected"] += 1
    assert code == 1, err
    assert f"cannot write {out / 'checkpoint.npz'}: No space left on device" in err
    assert "resume with" in err and len(err.strip().splitlines()) == 1
    meta = read_checkpoint_meta(out / layout.CHECKPOINT_FILE)
    assert meta["iteration"] > 0 and f"(at iteration {meta['iteration']}/" in err
    assert not list(out.glob(".*.tmp"))
    monkeypatch.undo()
    assert main(["--resume", str(out), "--quiet"]) == 0
    assert_same_run_dirs(reference, out)
    FAULT_FIGURES["failing writes survived"] += 1


@pytest.mark.parametrize("existing", [False, True])
def test_a_run_that_fails_before_training_leaves_nothing(tmp_path, monkeypatch, capsys, existing):
    """XLA out of memory while compiling: one line and exit 1; the run directory this start
    created is gone (one that already existed is left empty), so the same command starts
    afresh."""
    from jaxcart.engine import loop
    from jaxcart.train import main

    def out_of_memory(*args, **kwargs):
        raise RuntimeError("RESOURCE_EXHAUSTED: Out of memory while trying to allocate 9 TB")

    out = tmp_path / "run"
    if existing:
        out.mkdir()
    real = loop.compiled_chunk
    monkeypatch.setattr(loop, "compiled_chunk", out_of_memory)
    capsys.readouterr()
    assert main([*SMALL_RUN, "--out", str(out), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "ran out of memory" in err and "--wave-size" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    assert (out.is_dir() and not list(out.iterdir())) if existing else not out.exists()
    monkeypatch.setattr(loop, "compiled_chunk", real)
    assert main([*SMALL_RUN, "--out", str(out), "--quiet"]) == 0  # the same command, afresh
    assert (out / layout.PARAMS_FILE).is_file()


@pytest.mark.slow
def test_a_full_small_filesystem(tmp_path):
    """A real 400 KiB tmpfs: the second checkpoint does not fit beside the first."""
    mount = tmp_path / "small"
    mount.mkdir()
    made = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=400k", "tmpfs", str(mount)])
    if made.returncode != 0:
        pytest.skip("cannot mount a tmpfs here (needs root)")
    try:
        out = mount / "run"
        done = _run(*SMALL_RUN, "--out", str(out), "--checkpoint-every", "0.001")
        FAULT_FIGURES["failing writes injected"] += 1
        assert done.returncode == 1, done.stdout + done.stderr
        assert "No space left on device" in done.stderr and "Traceback" not in done.stderr
        assert len(done.stderr.strip().splitlines()) == 1
        read_checkpoint_meta(out / layout.CHECKPOINT_FILE)
        moved = tmp_path / "moved"  # "space freed": the run continues elsewhere
        shutil.copytree(out, moved)
        resumed = _run("--resume", str(moved), "--quiet")
        assert resumed.returncode == 0, resumed.stdout + resumed.stderr
        FAULT_FIGURES["failing writes survived"] += 1
    finally:
        subprocess.run(["umount", str(mount)])


@pytest.mark.slow
def test_a_read_only_filesystem(tmp_path, finished_run):
    """--resume of an unfinished run on a read-only mount: one line, a non-zero exit."""
    mount = tmp_path / "ro"
    mount.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(mount)]).returncode:
        pytest.skip("cannot mount a tmpfs here (needs root)")
    try:
        shutil.copytree(finished_run, mount / "run")
        (mount / "run" / "evaluation.json").unlink()
        subprocess.run(["mount", "-o", "remount,ro", str(mount)], check=True)
        done = _run("--resume", str(mount / "run"), "--quiet")
        FAULT_FIGURES["failing writes injected"] += 1
        assert done.returncode == 1, done.stdout + done.stderr
        assert "Read-only file system" in done.stderr and "Traceback" not in done.stderr
        assert len(done.stderr.strip().splitlines()) == 1
        FAULT_FIGURES["failing writes survived"] += 1
    finally:
        subprocess.run(["umount", str(mount)])


# --- untrusted files ----------------------------------------------------------------------


def _rewrite_params(run: Path, change) -> None:
    from jaxcart.rundir import files

    arrays, _ = files.load_tree(run / "params.npz")
    change(arrays)
    np.savez(run / "params.npz", **arrays)


def _npy_entry(shape: tuple, data: bytes) -> bytes:
    import io

    buf = io.BytesIO()
    header = {"descr": "<f4", "fortran_order": False, "shape": shape}
    np.lib.format.write_array_header_1_0(buf, header)
    return buf.getvalue() + data


def _huge_declared_entry(run: Path) -> None:
    """A 1e12-element array declared in the header, 16 bytes of data behind it."""
    import zipfile

    with zipfile.ZipFile(run / "params.npz", "w") as zf:
        zf.writestr("params/actor/out/kernel.npy", _npy_entry((10**6, 10**6), b"\0" * 16))


def _zip_bomb_entry(run: Path) -> None:
    """A deflated entry that would expand to 2 GiB of zeros."""
    import zipfile

    with zipfile.ZipFile(run / "params.npz", "w", zipfile.ZIP_DEFLATED) as zf:
        with zf.open("params/actor/out/kernel.npy", "w", force_zip64=True) as f:
            f.write(_npy_entry((2**29,), b""))
            block = b"\0" * (1 << 24)
            for _ in range(128):
                f.write(block)


def _pickled_params(run: Path) -> None:
    np.savez(run / "params.npz", **{"params/actor/out/kernel": np.array([{"x": 1}], object)})


def _symlink_out(run: Path) -> None:
    outside = run.parent / "elsewhere.npz"
    (run / "params.npz").rename(outside)
    (run / "params.npz").symlink_to(outside)


CRAFTED = [
    (
        lambda r: _rewrite_params(r, lambda a: a.update({k: v[..., :1] for k, v in a.items()})),
        "does not hold this run's network",
    ),
    (
        lambda r: _rewrite_params(
            r, lambda a: a.update({k: v.astype(np.float64) for k, v in a.items()})
        ),
        "does not hold this run's network",
    ),
    (
        lambda r: _rewrite_params(
            r, lambda a: a["params/actor/out/kernel"].__setitem__((0, 0, 0), np.nan)
        ),
        "NaN or infinite",
    ),
    (lambda r: (r / "params.npz").write_bytes((r / "params.npz").read_bytes()[:5000]), "corrupted"),
    (_huge_declared_entry, "params.npz"),
    pytest.param(_zip_bomb_entry, "params.npz", marks=pytest.mark.slow),  # 2 GiB through deflate
    (_pickled_params, "params.npz"),
    (_symlink_out, "symbolic link"),
    (lambda r: (r / "config.json").write_text("[1, 2, 3]"), "not a JSON object"),
    (lambda r: (r / "config.json").write_text('{"config": {"num_envs": "many"}}'), "corrupted"),
    (lambda r: (r / "config.json").write_text("{" * 100000), "corrupted"),
]


@pytest.mark.parametrize("damage, message", CRAFTED, ids=[str(i) for i in range(len(CRAFTED))])
def test_crafted_run_directories_rejected_by_every_reader(damage, message, finished_run, tmp_path):
    """load_policy, evaluate and plot each refuse a crafted file with one line, quickly and
    without reading what the file claims to hold."""
    import resource

    import jaxcart
    from jaxcart import evaluate

    run = tmp_path / "crafted"
    shutil.copytree(finished_run, run)
    damage(run)
    seal(run)  # crafted, digests and all: the checks behind the manifest refuse it
    FAULT_FIGURES["crafted files tried"] += 1
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    with pytest.raises(RunDirError, match=message):
        jaxcart.load_policy(run)
    code, err = _capture(lambda: evaluate.main([str(run), "--episodes", "1"]))
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    grown_mib = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - peak) / 1024
    assert grown_mib < 200, f"reading a crafted file grew the process by {grown_mib:.0f} MiB"
    FAULT_FIGURES["crafted files rejected"] += 1


def _crafted_checkpoint(run: Path) -> None:
    from jaxcart.rundir import files

    arrays, meta = files.load_tree(run / layout.CHECKPOINT_FILE)
    name = next(k for k in arrays if k.endswith("actor/out/kernel"))
    arrays[name] = np.full_like(arrays[name], np.inf)
    files.save_tree(run / layout.CHECKPOINT_FILE, arrays, meta)


def _huge_checkpoint_config(run: Path) -> None:
    from jaxcart.rundir import files

    info = json.loads((run / "config.json").read_text())
    info["num_seeds"] = info["wave_size"] = 10**5  # the checkpoint holds 1 seed: refused
    # from the headers, before anything of that size is allocated (a config.json written so,
    # digest included: a hand edit alone is refused for its digest)
    info.pop(layout.DIGEST_KEY)
    info[layout.DIGEST_KEY] = files.json_digest(info)
    (run / "config.json").write_text(json.dumps(info))


@pytest.mark.parametrize(
    "damage, message",
    [(_crafted_checkpoint, "NaN or infinite"), (_huge_checkpoint_config, "shape/dtype")],
)
def test_crafted_checkpoints_rejected_on_resume(damage, message, finished_run, tmp_path):
    run = tmp_path / "crafted"
    shutil.copytree(finished_run, run)
    (run / "evaluation.json").unlink()
    damage(run)
    seal(run)  # crafted, digests and all: the checks behind the manifest refuse it
    FAULT_FIGURES["crafted files tried"] += 1
    done = _run("--resume", str(run), "--quiet", timeout=60)
    assert done.returncode == 2 and message in done.stderr, done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and "Traceback" not in done.stderr
    FAULT_FIGURES["crafted files rejected"] += 1


def test_nothing_is_ever_unpickled(finished_run, tmp_path, monkeypatch):
    """Every load goes through np.load with allow_pickle=False."""
    calls = []
    real = np.load

    def spy(*args, **kwargs):
        calls.append(kwargs.get("allow_pickle"))
        return real(*args, **kwargs)

    monkeypatch.setattr(np, "load", spy)
    import jaxcart

    jaxcart.load_policy(finished_run)
    read_checkpoint_meta(finished_run / layout.CHECKPOINT_FILE)
    assert calls and all(c is False for c in calls)


def _symlink_metrics_out(run: Path) -> None:
    (run / "metrics.csv").unlink()
    (run / "metrics.csv").symlink_to("/etc/passwd")


CRAFTED_OUTPUTS = [
    (lambda r: (r / "evaluation.json").write_text('{"seeds": '), "evaluation.json is corrupted"),
    (lambda r: (r / "evaluation.json").write_text('"text"'), "not a JSON object"),
    (
        lambda r: (r / "metrics.csv").write_text("seed_index,iteration\n" + "0,1\n" * 400000),
        "larger than",
    ),
    (lambda r: (r / "metrics.csv").write_text("seed_index,iteration,x\n-5,1,2\n"), "out of range"),
    (_symlink_metrics_out, "symbolic link"),
    (lambda r: (r / "config.json").write_text('{"config": {}, "num_seeds": -3}'), "corrupted"),
]


@pytest.mark.parametrize(
    "damage, message", CRAFTED_OUTPUTS, ids=[str(i) for i in range(len(CRAFTED_OUTPUTS))]
)
def test_crafted_outputs_rejected_by_plot_and_compare(damage, message, finished_run, tmp_path):
    from jaxcart import compare, plot

    run = tmp_path / "crafted"
    shutil.copytree(finished_run, run)
    damage(run)
    seal(run)  # crafted, digests and all: the checks behind the manifest refuse it
    for command in (plot.main, compare.main):
        FAULT_FIGURES["crafted files tried"] += 1
        code, err = _capture(lambda c=command: c([str(run), "--out", str(tmp_path / "o.png")]))
        assert code == 2 and message in err, err
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
        FAULT_FIGURES["crafted files rejected"] += 1


def _checkpoint_iteration(out: Path) -> int:
    try:
        return read_checkpoint_meta(out / layout.CHECKPOINT_FILE)["iteration"]
    except RunDirError:
        return -1


@pytest.mark.slow
@pytest.mark.parametrize("waves", [1, 4], ids=["one-batch", "in-4-waves"])
def test_soak_64_seeds_killed_every_few_seconds_until_done(tmp_path, monkeypatch, waves):
    """A 64-seed run SIGKILLed again and again (each time a few seconds after its newest
    checkpoint, always resumed) until it finishes: it ends bit-identical to the
    uninterrupted run, trained in one batch or in waves of 16."""
    # 200 iterations: a restart keeps what it checkpointed before its kill. The first five kills
    # come 0.02-0.5 s after a new checkpoint (so that a fast machine is still killed several
    # times), later ones 0.1-1 s after (so that a slow machine still finishes)
    soak = [*tiny_args(25600, num_seeds=64), "--seed", "17", "--checkpoint-every", "0.3"]
    if waves > 1:
        from jaxcart.core.config import preset
        from jaxcart.run.waves import PROCESS_RESERVE_BYTES, USABLE_FRACTION, bytes_per_run

        config = preset(
            "sb3",
            num_envs=4,
            num_steps=32,
            total_timesteps=25600,
            minibatch_size=64,
            update_epochs=2,
        )
        memory = PROCESS_RESERVE_BYTES + 16 * bytes_per_run(config, 2) / USABLE_FRACTION + 10
        monkeypatch.setitem(TRAIN_ENV, "JAXCART_MEMORY_BYTES", str(int(memory)))
    reference = tmp_path / "reference"
    done = _run(*soak, "--out", str(reference))
    assert done.returncode == 0, done.stdout + done.stderr
    out, rng, kills = tmp_path / "soaked", random.Random(64), 0
    proc = start_train(*soak, "--out", str(out))
    for _ in range(60):
        before, deadline = _checkpoint_iteration(out), time.monotonic() + WAIT_S
        while proc.poll() is None and _checkpoint_iteration(out) <= before:
            assert time.monotonic() < deadline, f"no checkpoint progress in {WAIT_S:.0f} s"
            time.sleep(0.05)
        try:
            proc.wait(timeout=rng.uniform(0.02, 0.5) if kills < 5 else rng.uniform(0.1, 1.0))
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            kills += 1
            FAULT_FIGURES["soak: kills (SIGKILL)"] += 1
        if (out / "evaluation.json").exists():
            break
        proc = start_train("--resume", str(out), "--quiet", "--checkpoint-every", "0.3")
    else:
        pytest.fail("the soak run did not finish after 60 restarts")
    assert kills >= 3, "the run finished before it was killed 3 times; the soak proved little"
    assert_same_run_dirs(reference, out)
    # every resume removed what the kill before it left half-written
    assert not [p for p in out.rglob("*") if layout.is_temporary(p)]
    if waves > 1:
        assert len(list((out / "waves").iterdir())) == waves
    FAULT_FIGURES[f"soak: 64-seed runs ({waves} wave(s)) ending bit-identical"] += 1

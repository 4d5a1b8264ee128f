"""The one writer of run directories: atomic, and files as readable as ``open()`` makes them
(``0o666 & ~umask``), so colleagues on a shared machine can read a run's results."""

from __future__ import annotations

import os
import stat
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from helpers import TRAIN_ENV

from jaxcart.rundir import files, layout


def mode_of(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def umask_mode() -> int:
    """``0o666 & ~umask``: the mode ``open()`` gives a new file."""
    umask = os.umask(0o022)
    os.umask(umask)
    return 0o666 & ~umask


def test_atomic_file_gives_the_mode_open_gives(tmp_path):
    with open(tmp_path / "plain", "w") as f:
        f.write("x")
    with files.atomic_file(tmp_path / "text.csv") as f:
        f.write("a,b\n1,2\n")
    files.atomic_write_bytes(tmp_path / "data.bin", b"\x00\x01")
    assert (tmp_path / "text.csv").read_bytes() == b"a,b\n1,2\n"  # no newline translation
    assert (tmp_path / "data.bin").read_bytes() == b"\x00\x01"
    assert mode_of(tmp_path / "text.csv") == mode_of(tmp_path / "plain") == umask_mode()
    assert mode_of(tmp_path / "data.bin") == umask_mode()


def test_a_failed_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    path = tmp_path / "metrics.csv"
    files.atomic_write_bytes(path, b"old")
    with pytest.raises(RuntimeError, match="midway"), files.atomic_file(path) as f:
        f.write("new, half")
        raise RuntimeError("midway")
    assert path.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["metrics.csv"]
    with pytest.raises(OSError) as caught:
        files.atomic_write_bytes(tmp_path / "missing" / "x.json", b"{}")
    assert caught.value.filename == str(tmp_path / "missing" / "x.json")


RUNS_UNDER_A_UMASK = textwrap.dedent(
    """
    import os, signal, sys
    os.umask(0o027)
    from pathlib import Path
    from jaxcart.core.config import PPOConfig
    from jaxcart.engine.signals import StopRequest
    from jaxcart.run import lifecycle, waves
    from jaxcart.run.spec import Hooks, RunOptions, RunSpec

    out = Path(sys.argv[1])
    small = PPOConfig(num_envs=4, num_steps=32, total_timesteps=1024, minibatch_size=64,
                      update_epochs=2)
    options = RunOptions(eval_episodes=2, compile_cache=False, chunk_size=2)
    # 4 seeds in 2 waves of 2: the waves/ files too
    per_run = waves.bytes_per_run(small, 2)
    two = waves.PROCESS_RESERVE_BYTES + 2 * per_run / waves.USABLE_FRACTION + 10
    os.environ[waves.MEMORY_ENV] = str(int(two))
    assert not lifecycle.run_new(RunSpec(small, num_seeds=4), out / "waved", options).stopped
    del os.environ[waves.MEMORY_ENV]
    sweep = RunSpec(small, num_seeds=1, sweep={"learning_rate": [1e-3, 3e-3]})
    assert not lifecycle.run_new(sweep, out / "sweep", options).stopped
    stop = StopRequest()
    hooks = Hooks(on_chunk=lambda p: p.iteration >= 4 and stop.request(signal.SIGINT))
    assert lifecycle.run_new(RunSpec(small), out / "stopped", options, hooks, stop).stopped
    """
)


@pytest.mark.slow
def test_every_file_of_a_run_directory_has_the_mode_open_gives(tmp_path):
    """Under umask 027 (neither 0600 nor 0644 is right): a finished run in waves, a sweep and
    an interrupted run's checkpoint, every file ``0o640``."""
    subprocess.run(
        [sys.executable, "-c", RUNS_UNDER_A_UMASK, str(tmp_path)],
        env=TRAIN_ENV,
        check=True,
        timeout=600,
    )
    found = {p.relative_to(tmp_path).as_posix(): mode_of(p) for p in tmp_path.rglob("*")}
    found = {name: mode for name, mode in found.items() if (tmp_path / name).is_file()}
    expected_files = {
        f"waved/{layout.CONFIG_FILE}",
        f"waved/{layout.METRICS_FILE}",
        f"waved/{layout.PARAMS_FILE}",
        f"waved/{layout.EVALUATION_FILE}",
        f"waved/{layout.CHECKPOINT_FILE}",
        f"waved/{layout.LOCK_FILE}",
        layout.wave_file("waved", 1).as_posix(),
        f"sweep/{layout.SWEEP_FILE}",
        f"{layout.combo_dir('sweep', 1).as_posix()}/{layout.PARAMS_FILE}",
        f"{layout.combo_dir('sweep', 1).as_posix()}/{layout.CONFIG_FILE}",
        f"stopped/{layout.CHECKPOINT_FILE}",
        f"stopped/{layout.METRICS_FILE}",
    }
    assert expected_files <= set(found), sorted(expected_files - set(found))
    wrong = {name: oct(mode) for name, mode in found.items() if mode != 0o666 & ~0o027}
    assert not wrong, wrong
    assert not [name for name in found if layout.is_temporary(name)]
    assert not os.path.exists(tmp_path / "stopped" / layout.PARAMS_FILE)


def test_taking_a_run_removes_what_killed_writes_left(tmp_path):
    """A write killed mid-way (SIGKILL) leaves its temporary; the next process to lock the
    run (``--resume``) removes those, in the run and in ``waves/``, and nothing else."""
    from jaxcart.rundir.directory import RunDir

    (tmp_path / layout.WAVES_DIR).mkdir()
    left = [
        tmp_path / f"{layout.temporary_prefix(layout.CHECKPOINT_FILE)}0123456789ab.tmp",
        tmp_path / layout.WAVES_DIR / f"{layout.temporary_prefix('wave-00001.npz')}ab.tmp",
    ]
    kept = [layout.wave_file(tmp_path, 0), tmp_path / "notes.tmp", tmp_path / ".notes"]
    for path in [*left, *kept]:
        path.write_bytes(b"x")
    run = RunDir.open(tmp_path)
    try:
        assert [p.exists() for p in left + kept] == [False] * len(left) + [True] * len(kept)
    finally:
        run.close()


def test_a_run_refused_while_taken_is_not_left_locked(tmp_path):
    """``waves/`` a link: taking the run refuses it, and releases the lock it took."""
    from jaxcart.rundir.directory import RunDir

    (tmp_path / "elsewhere").mkdir()
    (tmp_path / layout.WAVES_DIR).symlink_to(tmp_path / "elsewhere")
    with pytest.raises(files.RunDirError):
        RunDir.open(tmp_path)
    with files.RunLock(tmp_path):  # would raise RunInUse had the refused open kept it
        pass


def test_a_file_written_through_the_store_is_recorded_and_checked(tmp_path):
    """``record_json`` (a structural sweep's ``groups.json``) writes a file into the
    directory's manifest, as a run's files are; ``verified`` then refuses it once edited, and
    refuses a link or a FIFO in its place."""
    files.record_json(tmp_path, {layout.GROUPS_FILE: {"groups": [{"num_envs": 4}]}})
    listed = files.read_manifest(tmp_path)
    assert list(listed) == [layout.GROUPS_FILE] and len(listed[layout.GROUPS_FILE]) == 1
    info = {files.MANIFEST_FLAG: True}
    with files.opened(tmp_path) as directory:
        files.verified(directory, layout.GROUPS_FILE, info)
        assert files.read_json(directory, layout.GROUPS_FILE)["groups"] == [{"num_envs": 4}]
    path = tmp_path / layout.GROUPS_FILE
    path.write_text(path.read_text() + " ")
    with pytest.raises(files.RunDirError, match="not the file the run wrote"):
        with files.opened(tmp_path) as directory:
            files.verified(directory, layout.GROUPS_FILE, info)
    path.unlink()
    os.mkfifo(path)
    with pytest.raises(files.RunDirError, match="not a regular file"), files.opened(tmp_path) as d:
        files.verified(d, layout.GROUPS_FILE, info)
    path.unlink()
    path.symlink_to(tmp_path / layout.MANIFEST_FILE)
    with pytest.raises(files.RunDirError, match="symbolic link"), files.opened(tmp_path) as d:
        files.read_json(d, layout.GROUPS_FILE)

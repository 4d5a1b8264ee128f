"""``python -m jaxcart.tune`` against storage failures: an Optuna storage error is one line and
exit 2 with no trial left running, a rerun after a kill reaches ``--trials`` finished trials
without the killed batch's directory, and an in-memory database is refused."""

from __future__ import annotations

import shutil
import time

import pytest

optuna = pytest.importorskip("optuna")

from test_tune import BASE, _states, _tuner  # noqa: E402

from jaxcart import tune  # noqa: E402
from jaxcart.run import search  # noqa: E402
from jaxcart.rundir.reader import load_runs  # noqa: E402

LR = "learning_rate=log:1e-4:1e-2"
ARGV = [*BASE, "--trials", "2", "--batch-trials", "2", "--num-seeds", "1", "--quiet"]
ARGV += ["--heldout-top", "0"]  # the search alone


def _study_with_one_trial(db) -> str:
    """A study whose one complete trial drew the learning rate from a log-uniform float."""
    storage = f"sqlite:///{db}"
    study, _ = search.open_study(storage, "s")
    dist = optuna.distributions.FloatDistribution(1e-4, 1e-2, log=True)
    study.tell(study.ask({"learning_rate": dist}), 1.0)
    return storage


@pytest.mark.parametrize(
    "case",
    ["choice where the study drew a float", "read-only", "closed port", "in-memory", "a folder"],
)
def test_a_storage_error_is_one_line_and_leaves_no_trial_running(tmp_path, capsys, case):
    db = tmp_path / "study.db"
    storage, space = _study_with_one_trial(db), LR
    if case == "choice where the study drew a float":
        space = "learning_rate=0.001,0.01"
    elif case == "read-only":
        storage = f"sqlite:///file:{db}?mode=ro&uri=true"
    elif case == "closed port":  # refused, or no driver installed: either way one line
        storage = "postgresql://user:pw@127.0.0.1:9/jaxcart"
    elif case == "in-memory":
        storage = "sqlite:///:memory:"
    else:
        storage = f"sqlite:///{tmp_path}"
    argv = [*ARGV, "--storage", storage, "--study-name", "s", "--space", space]
    code = tune.main([*argv, "--out", str(tmp_path / "runs")])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith("error: ") and len(err.strip().splitlines()) == 1, err
    assert _states(f"sqlite:///{db}", "s") == ["COMPLETE"]  # nothing asked, nothing running
    assert not (tmp_path / "runs").exists()


@pytest.mark.slow
def test_a_stale_trials_directory_goes_unless_a_told_trial_or_another_folder_holds_it(
    tmp_path, monkeypatch
):
    monkeypatch.setattr(search, "STALE_GRACE_SECONDS", 1)
    storage, out = f"sqlite:///{tmp_path}/study.db", tmp_path / "runs"
    tuner = _tuner(storage, out)
    # a killed process's trials: 0 and 1 share a group, 0 was told before the kill;
    # 2 trained alone; 3 into a folder outside --out
    trials = tuner._ask(4, 4)
    shared, alone, elsewhere = out / "trials-00000-00001", out / "trials-00002", tmp_path / "x"
    for trial, run_dir in zip(trials, [shared / "combo-000", shared, alone, elsewhere]):
        run_dir.mkdir(parents=True, exist_ok=True)
        trial.set_user_attr("run_dir", str(run_dir))
    tuner.study.tell(trials[0], 1.0)
    time.sleep(2.5)  # SQLite keeps heartbeats to the second
    tuner._fail_stale_trials()
    assert _states(storage, "s") == ["COMPLETE", "FAIL", "FAIL", "FAIL"]
    assert shared.exists() and elsewhere.exists() and not alone.exists()


@pytest.mark.slow
def test_rerun_after_a_kill_waits_for_its_trials_then_finishes_the_study(
    tmp_path, capsys, monkeypatch
):
    monkeypatch.setattr(search, "STALE_GRACE_SECONDS", 1)
    monkeypatch.setattr(search, "WAIT_SECONDS", 0.2)
    storage, out = f"sqlite:///{tmp_path}/study.db", tmp_path / "runs"
    # what a process killed mid-batch leaves: 2 running trials with a heartbeat, and their
    # half-written run directory
    killed = _tuner(storage, out)
    trials = killed._ask(2, 2)
    for trial in trials:
        trial.set_user_attr("run_dir", str(out / "trials-00000-00001"))
    # a killed batch's heartbeat thread stamps its trials together; SQLite keeps the stamp to
    # the second, so stamp both early in one second, or they go stale one poll apart and the
    # rerun asks them again one at a time
    time.sleep(1.05 - time.time() % 1)
    search.record_heartbeats(killed.storage, killed.study, trials)
    (out / "trials-00000-00001").mkdir(parents=True)
    shutil.copy(__file__, out / "trials-00000-00001" / "config.json")  # not a run's config
    argv = [*ARGV, "--storage", storage, "--study-name", "s", "--space", LR, "--out", str(out)]
    assert tune.main([*argv, "--sampler", "random"]) == 0
    assert "waiting for 2 trial(s)" in capsys.readouterr().err
    assert sorted(_states(storage, "s")) == ["COMPLETE"] * 2 + ["FAIL"] * 2
    assert [d.name for d in out.iterdir()] == ["trials-00002-00003"]
    assert len(load_runs(list(out.iterdir()))) == 2  # compare and plot read the folder

"""``load_policy``'s options (every seed stacked, sampled actions), and runs that did not
finish: ``load_policy``, ``python -m jaxcart.evaluate`` and ``python -m jaxcart.plot`` read
them from the checkpoint, say so, and refuse crafted checkpoints."""

from __future__ import annotations

import io
import json
import os
import shutil
import signal
import zipfile

import numpy as np
import pytest
from helpers import TINY, seal

import jaxcart
from jaxcart import evaluate, plot
from jaxcart.core import networks
from jaxcart.core.config import PPOConfig
from jaxcart.engine.loop import METRIC_COLUMNS
from jaxcart.engine.signals import StopRequest
from jaxcart.results import figure
from jaxcart.run import lifecycle
from jaxcart.run.greedy import evaluate_params
from jaxcart.run.spec import Hooks, RunOptions, RunSpec
from jaxcart.rundir import files, layout
from jaxcart.rundir.files import RunDirError, read_stream
from jaxcart.rundir.layout import CHECKPOINT_FILE, METRICS_STREAM_FILE
from jaxcart.rundir.policy import run_params
from jaxcart.rundir.reader import load_runs

SMALL = PPOConfig(**{**TINY.to_dict(), "total_timesteps": 1024})  # 8 iterations
OPTIONS = RunOptions(eval_episodes=2, compile_cache=False, chunk_size=2)
SWEEP = {"learning_rate": [1e-3, 3e-3]}
ACTOR = "state/runners/params/params/actor/"
STOPPED_NOTE = "from the checkpoint at iteration 4/8: the run did not finish"


def _train(out, sweep=None, stop_at=None):
    """A run of SMALL (2 seeds), stopped like Ctrl-C after iteration ``stop_at`` if given."""
    stop = StopRequest()

    def on_chunk(progress):
        if stop_at is not None and progress.iteration >= stop_at and not stop():
            stop.request(signal.SIGINT)

    spec = RunSpec(SMALL, preset="custom", num_seeds=2, seed=5, sweep=sweep or {})
    outcome = lifecycle.run_new(spec, out, OPTIONS, Hooks(on_chunk=on_chunk), stop)
    assert outcome.stopped == (stop_at is not None)
    return out


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    base = tmp_path_factory.mktemp("policy")
    return {
        "finished": _train(base / "finished"),
        "stopped": _train(base / "stopped", stop_at=4),
        "sweep": _train(base / "sweep", sweep=SWEEP, stop_at=4),
    }


def _checkpoint_actions(run_dir, run: int, obs: np.ndarray) -> np.ndarray:
    """Greedy actions of run ``run`` computed straight from the checkpoint's arrays."""
    arrays, _ = files.load_tree(run_dir / CHECKPOINT_FILE)
    actor = {k[len(ACTOR) :]: v[run] for k, v in arrays.items() if k.startswith(ACTOR)}
    return networks.mlp(files.unflatten(actor), obs, "tanh", np).argmax(-1)


OBS = np.random.default_rng(0).normal(size=(64, 4)).astype(np.float32)


def test_all_seeds_stacked(runs):
    policy = jaxcart.load_policy(runs["finished"], seed_index="all")
    obs = np.stack([OBS, OBS[::-1]])  # [S=2, N=64, 4]
    actions = policy(obs)
    assert actions.shape == (2, 64)
    for s in range(2):
        one = jaxcart.load_policy(runs["finished"], seed_index=s)
        np.testing.assert_array_equal(actions[s], one(obs[s]))
    with pytest.raises(ValueError, match=r"\[2, N, 4\]"):
        policy(OBS)  # [N, 4] would broadcast wrongly against 2 stacked seeds
    with pytest.raises(RunDirError, match="'all'"):
        jaxcart.load_policy(runs["finished"], seed_index="every")


def test_sampled_actions_follow_the_policy_and_are_seedable(runs):
    greedy = jaxcart.load_policy(runs["finished"], seed_index=1)
    sampled = jaxcart.load_policy(runs["finished"], seed_index=1, deterministic=False, rng=3)
    again = jaxcart.load_policy(
        runs["finished"], 1, deterministic=False, rng=np.random.default_rng(3)
    )
    obs = np.repeat(OBS[:1], 20_000, axis=0)
    first = sampled(obs)
    np.testing.assert_array_equal(first, again(obs))  # the same seed, the same actions
    assert not np.array_equal(first, sampled(obs))  # the generator moves on
    logits = greedy.logits(OBS[0]).astype(float)
    p1 = np.exp(logits[1]) / np.exp(logits).sum()
    sigma = np.sqrt(p1 * (1 - p1) / len(obs))
    assert abs(first.mean() - p1) < 5 * sigma + 1e-3, (first.mean(), p1)
    assert isinstance(sampled(OBS[0]), int)
    assert greedy(OBS[0]) == int(logits.argmax())


def test_load_policy_of_a_stopped_run_uses_its_checkpoint(runs):
    stopped = runs["stopped"]
    assert not (stopped / "params.npz").exists()
    with pytest.warns(UserWarning, match=STOPPED_NOTE):
        policy = jaxcart.load_policy(stopped, seed_index=1)
    assert policy.note == STOPPED_NOTE
    np.testing.assert_array_equal(policy(OBS), _checkpoint_actions(stopped, 1, OBS))
    with pytest.warns(UserWarning):
        stacked = jaxcart.load_policy(stopped, seed_index="all")
    assert stacked(np.stack([OBS, OBS])).shape == (2, 64)


def test_load_policy_of_a_stopped_sweep_takes_a_combination(runs):
    sweep = runs["sweep"]
    assert not (sweep / "sweep.json").exists() and not (sweep / "combo-000").exists()
    with pytest.raises(RunDirError, match="is a sweep of 2 combinations"):
        jaxcart.load_policy(sweep)
    with pytest.raises(RunDirError, match="combination"):
        jaxcart.load_policy(sweep, combination=2)
    with pytest.warns(UserWarning, match=STOPPED_NOTE):
        policy = jaxcart.load_policy(sweep, seed_index=0, combination=1)
    # run r of the sweep's checkpoint is combination r // num_seeds, seed r % num_seeds
    np.testing.assert_array_equal(policy(OBS), _checkpoint_actions(sweep, 2, OBS))
    with pytest.raises(RunDirError, match="not a sweep"):
        jaxcart.load_policy(runs["finished"], combination=0)


def test_finished_sweep_combination_is_its_directory(runs, tmp_path):
    sweep = tmp_path / "sweep"
    for c in range(2):
        shutil.copytree(runs["finished"], layout.combo_dir(sweep, c))
    info = json.loads((runs["finished"] / "config.json").read_text())
    info.update(sweep=SWEEP, combinations=[{"learning_rate": v} for v in SWEEP["learning_rate"]])
    (sweep / "config.json").write_text(json.dumps(info))
    (sweep / "sweep.json").write_text("{}")
    seal(sweep)
    with pytest.raises(RunDirError, match="is a sweep"):
        jaxcart.load_policy(sweep)
    policy = jaxcart.load_policy(sweep, seed_index=1, combination=1)
    np.testing.assert_array_equal(policy(OBS), jaxcart.load_policy(runs["finished"], 1)(OBS))


def test_evaluate_cli_on_stopped_run_and_sweep(runs, capsys):
    assert evaluate.main([str(runs["stopped"]), "--episodes", "2"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == (
        f"note: parameters {STOPPED_NOTE} (resume with: python -m jaxcart.train --resume "
        f"{runs['stopped']})"
    )
    assert lines[2].split() == ["seed", "mean", "min", "solved"] and len(lines) == 7
    trained = run_params(runs["stopped"])
    returns = evaluate_params(trained, 2)
    assert returns.shape == (2, 2) and trained.note == STOPPED_NOTE

    assert evaluate.main([str(runs["sweep"]), "--episodes", "2"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert STOPPED_NOTE in lines[0]
    rows = [line.split() for line in lines[4:8]]
    assert [r[:3] for r in rows] == [
        ["0", "learning_rate=0.001", "0"],
        ["0", "learning_rate=0.001", "1"],
        ["1", "learning_rate=0.003", "0"],
        ["1", "learning_rate=0.003", "1"],
    ]
    assert lines[8].startswith("solved ") and "/4 seed(s)" in lines[8]
    assert evaluate.main([str(runs["sweep"]), "--episodes", "2", "--combination", "1"]) == 0
    assert "/2 seed(s)" in capsys.readouterr().out
    gif = runs["sweep"].parent / "x.gif"
    assert evaluate.main([str(runs["sweep"]), "--gif", str(gif)]) == 2
    assert "--combination" in capsys.readouterr().err


def test_plot_stopped_run_and_sweep(runs, tmp_path, monkeypatch, capsys):
    stopped = runs["stopped"]
    assert plot.main([str(stopped), "--out", str(tmp_path / "run.png"), "--dpi", "40"]) == 0
    captured = capsys.readouterr()
    assert captured.out.strip() == str(tmp_path / "run.png")
    assert f"curves drawn {STOPPED_NOTE}; no Gymnasium evaluation" in captured.err
    (run,) = load_runs([stopped])
    streamed = read_stream(stopped / METRICS_STREAM_FILE, METRIC_COLUMNS, 2, 4)
    np.testing.assert_array_equal(
        run.metrics["rollout/ep_rew_mean"], streamed["rollout/ep_rew_mean"]
    )
    # and the partial metrics.csv a stopped run writes holds the same rows
    csv_rows = np.loadtxt(stopped / "metrics.csv", delimiter=",", skiprows=1)
    assert csv_rows.shape[0] == 2 * 4
    np.testing.assert_array_equal(run.env_steps, np.arange(1, 5) * SMALL.batch_size)
    assert "not evaluated: " + STOPPED_NOTE in figure._summary_lines(run)[2]

    # A sweep killed before it wrote anything but its checkpoint: no metrics.csv either.
    sweep = tmp_path / "sweep"
    shutil.copytree(runs["sweep"], sweep)
    (sweep / "metrics.csv").unlink()
    monkeypatch.chdir(tmp_path)
    assert plot.main([str(sweep), "--dpi", "40"]) == 0
    captured = capsys.readouterr()
    # a sweep is drawn into its own folder, and nothing is left in the current directory
    assert captured.out.strip() == str(sweep / "curves.png") and (sweep / "curves.png").is_file()
    assert not (tmp_path / "comparison.png").exists()
    assert f"a sweep: its 2 combinations drawn {STOPPED_NOTE}" in captured.err
    combos = load_runs([sweep])
    assert [r.label for r in combos] == ["learning_rate=0.001", "learning_rate=0.003"]
    meta = files.read_meta(sweep / CHECKPOINT_FILE)
    streamed = read_stream(sweep / METRICS_STREAM_FILE, METRIC_COLUMNS, 4, meta["iteration"])
    metrics = streamed["train/approx_kl"]
    np.testing.assert_array_equal(combos[1].metrics["train/approx_kl"], metrics[:, 2:4])


def test_plot_of_a_run_stopped_before_its_first_iteration(runs, tmp_path, capsys):
    run = tmp_path / "early"
    shutil.copytree(runs["stopped"], run)
    arrays, meta = files.load_tree(run / CHECKPOINT_FILE)
    files.save_tree(run / CHECKPOINT_FILE, arrays, {**meta, "iteration": 0})
    seal(run)
    assert plot.main([str(run)]) == 2
    assert "iteration 0/8" in capsys.readouterr().err
    with pytest.warns(UserWarning, match="iteration 0/8"):
        jaxcart.load_policy(run)  # the initial parameters, and it says so


def _rewrite_checkpoint(run, change_arrays=None, change_meta=None):
    arrays, meta = files.load_tree(run / CHECKPOINT_FILE)
    if change_arrays:
        change_arrays(arrays)
    files.save_tree(run / CHECKPOINT_FILE, arrays, change_meta(meta) if change_meta else meta)


def _entry(run, shape, data: bytes) -> None:
    """Adds a float32 entry of ``shape`` with ``data`` behind its header to the checkpoint."""
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        buf, {"descr": "<f4", "fortran_order": False, "shape": shape}
    )
    with zipfile.ZipFile(run / CHECKPOINT_FILE, "a") as zf:
        zf.writestr("metrics/extra.npy", buf.getvalue() + data)


def _big_entry(run):
    """4 MiB more than this run's checkpoint can hold, honestly declared."""
    _entry(run, (1 << 20,), bytes(4 << 20))


def _lying_entry(run):
    """A 1e12-element array declared, 16 bytes behind it."""
    _entry(run, (10**6, 10**6), bytes(16))


def _link_out(run, name=CHECKPOINT_FILE):
    outside = run.parent / f"elsewhere-{name}"
    (run / name).rename(outside)
    (run / name).symlink_to(outside)


def _fifo(path):
    path.unlink()
    os.mkfifo(path)


CRAFTED = [
    (
        lambda r: _rewrite_checkpoint(
            r, lambda a: a[ACTOR + "out/kernel"].__setitem__((0, 0, 0), np.inf)
        ),
        "NaN or infinite",
    ),
    (
        lambda r: _rewrite_checkpoint(
            r, lambda a: a.update({ACTOR + "out/kernel": a[ACTOR + "out/kernel"][..., :1]})
        ),
        "does not hold this run's network",
    ),
    (
        lambda r: _rewrite_checkpoint(r, change_meta=lambda m: {**m, "num_runs": 10**9}),
        "num_runs out of range",
    ),
    (
        lambda r: _rewrite_checkpoint(r, change_meta=lambda m: {**m, "iteration": 10**6}),
        "does not belong",
    ),
    (_big_entry, "declares"),
    (_lying_entry, "does not match its header"),
    (_link_out, "symbolic link"),
    (lambda r: (r / CHECKPOINT_FILE).write_bytes(b"PK\x03\x04 torn"), "corrupted"),
    (
        lambda r: _rewrite_checkpoint(r, change_meta=lambda m: {**m, "metrics_columns": ["x"]}),
        "metrics_columns out of range",
    ),
    (lambda r: os.truncate(r / METRICS_STREAM_FILE, 100), "fewer than the 4 iterations"),
    (lambda r: (r / METRICS_STREAM_FILE).unlink(), "does not exist"),
    (lambda r: _link_out(r, METRICS_STREAM_FILE), "symbolic link"),
    (lambda r: _fifo(r / METRICS_STREAM_FILE), "not a regular file"),
    (lambda r: _edit_config(r, combinations="combo"), "combinations is not a list"),
    (lambda r: _edit_config(r, combinations=[{"learning_rate": "x"}]), "combinations is not"),
]


def _edit_config(run, **changes):
    info = json.loads((run / "config.json").read_text())
    (run / "config.json").write_text(json.dumps({**info, **changes}))


@pytest.mark.parametrize("damage, message", CRAFTED, ids=[str(i) for i in range(len(CRAFTED))])
def test_crafted_checkpoints_refused_by_every_reader(damage, message, runs, tmp_path, capsys):
    run = tmp_path / "crafted"
    shutil.copytree(runs["stopped"], run)
    damage(run)
    seal(run)  # crafted, digests and all: the checks behind the manifest refuse it
    with pytest.raises(RunDirError, match=message):
        jaxcart.load_policy(run)
    for command in (evaluate.main, plot.main):
        assert command([str(run), "--episodes" if command is evaluate.main else "--dpi", "1"]) == 2
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1 and "Traceback" not in err, err

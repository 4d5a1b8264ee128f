"""Checkpoint/resume bit-identity (trainer and CLI) and sweeps in one compiled program."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import jax
import numpy as np
import pytest
from helpers import assert_same_results, assert_same_run_dirs, tiny_args

from jaxcart import checkpoint, rundir
from jaxcart.config import PPOConfig
from jaxcart.sweep import parse_sweep
from jaxcart.train import main
from jaxcart.trainer import initial_state, train

TINY = PPOConfig(
    num_envs=4,
    num_steps=32,
    total_timesteps=4096,
    minibatch_size=64,
    update_epochs=2,
    learning_rate=1e-3,
    anneal_lr=True,
)


def test_resume_from_checkpoint_is_bit_identical(tmp_path):
    full = train(TINY, num_seeds=2, seed=3, chunk_size=2)
    assert not full.stopped and full.state.iteration == TINY.num_iterations == 32

    chunks = []
    part = train(
        TINY,
        num_seeds=2,
        seed=3,
        chunk_size=2,
        on_chunk=chunks.append,
        should_stop=lambda: len(chunks) == 5,
    )
    assert part.stopped and part.state.iteration == 10

    path = tmp_path / "checkpoint.npz"
    state = part.state
    checkpoint.save_checkpoint(
        path,
        {"runners": state.runners, "hyperparams": state.hyperparams},
        {"iteration": state.iteration, "elapsed": state.elapsed, "chunk_size": state.chunk_size},
        extras=state.metrics,
    )
    template = initial_state(TINY, 2, 3, chunk_size=2)
    loaded, meta = checkpoint.load_checkpoint(
        path, {"runners": template.runners, "hyperparams": template.hyperparams}
    )
    resumed_state = type(state)(
        loaded["runners"],
        loaded["hyperparams"],
        meta["iteration"],
        meta["elapsed"],
        checkpoint.load_extras(path),
        meta["chunk_size"],
    )
    resumed = train(TINY, num_seeds=2, seed=3, resume=resumed_state)
    assert resumed.state.iteration == 32 and not resumed.stopped
    assert_same_results(full.metrics, resumed.metrics, full.params, resumed.params)


def test_checkpoint_rejects_other_structures(tmp_path):
    state = initial_state(TINY, 2, 0)
    path = tmp_path / "c.npz"
    checkpoint.save_checkpoint(
        path, {"runners": state.runners, "hyperparams": state.hyperparams}, {"iteration": 0}
    )
    other = initial_state(PPOConfig(**{**TINY.to_dict(), "hidden_sizes": (32, 32)}), 2, 0)
    with pytest.raises(rundir.RunDirError, match="shape"):
        checkpoint.load_checkpoint(
            path, {"runners": other.runners, "hyperparams": other.hyperparams}
        )
    path.write_bytes(path.read_bytes()[:1000])  # torn file
    with pytest.raises(rundir.RunDirError, match="corrupted"):
        checkpoint.read_checkpoint_meta(path)


CLI_SMALL = [*tiny_args(12800, num_seeds=2), "--no-compile-cache"]


def _cli(*args):
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2"}
    return subprocess.Popen(
        [sys.executable, "-m", "jaxcart.train", *args],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


def test_cli_sigterm_then_resume_matches_uninterrupted(tmp_path):
    """SIGTERM mid-run: a checkpoint and a resume hint; --resume finishes bit-identically."""
    reference = tmp_path / "ref"
    assert main([*CLI_SMALL, "--out", str(reference)]) == 0

    out = tmp_path / "interrupted"
    proc = _cli(*CLI_SMALL, "--out", str(out), "--checkpoint-every", "0.05")
    deadline = time.monotonic() + 120
    while not (out / "checkpoint.npz").exists() and time.monotonic() < deadline:
        time.sleep(0.02)
    proc.send_signal(signal.SIGTERM)
    text, _ = proc.communicate(timeout=120)
    if proc.returncode == 0:
        pytest.skip("the run finished before SIGTERM arrived")
    assert proc.returncode == 128 + signal.SIGTERM, text
    assert "resume with: python -m jaxcart.train --resume" in text
    stopped_at = checkpoint.read_checkpoint_meta(out / "checkpoint.npz")["iteration"]
    assert 0 <= stopped_at < 100

    proc = _cli("--resume", str(out), "--quiet")
    text, _ = proc.communicate(timeout=300)
    assert proc.returncode == 0, text
    assert f"resuming from iteration {stopped_at}/100" in text
    assert_same_run_dirs(reference, out)


def test_resume_errors(tmp_path, capsys):
    assert main(["--resume", str(tmp_path / "missing")]) == 2
    assert "cannot resume" in capsys.readouterr().err
    assert main(["--resume", str(tmp_path), "--learning-rate", "1e-3"]) == 2
    assert "drop --learning-rate" in capsys.readouterr().err


def test_new_hyperparameter_values_do_not_recompile():
    """Float hyperparameters are traced: a second run with other values compiles nothing and
    the new values take effect."""
    from jaxcart.trainer import broadcast_hyperparams

    compiles = []

    def listener(event, duration, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            compiles.append(duration)

    jax.monitoring.register_event_duration_secs_listener(listener)
    hps = broadcast_hyperparams(TINY, 4)
    other = hps.replace(
        learning_rate=hps.learning_rate * 3,
        clip_coef=hps.clip_coef * 0.5,
        ent_coef=hps.ent_coef + 0.01,
    )
    first = train(TINY, 4, seed=1, hyperparams=hps)
    mid = len(compiles)
    second = train(TINY, 4, seed=1, hyperparams=other)
    assert first.extra["compiled"] and not second.extra["compiled"]
    assert len(compiles) == mid, "new hyperparameter values triggered a compilation"
    np.testing.assert_allclose(second.metrics["train/learning_rate"][0], 3e-3, rtol=1e-6)
    assert not np.allclose(first.metrics["train/value_loss"], second.metrics["train/value_loss"])


def test_sweep_cli_trains_every_combination(tmp_path, capsys):
    out = tmp_path / "sweep"
    argv = [
        *tiny_args(2048, num_seeds=2),
        "--no-compile-cache",
        "--sweep",
        "learning_rate=1e-4,1e-3,1e-2",
        "--sweep",
        "clip_coef=0.1,0.3",
        "--out",
        str(out),
    ]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert (
        "Sweep ranking" in text
        and "3 combinations" not in text
        and "6 combinations x 2 seed(s)" in text
    )
    ranking = json.loads((out / "sweep.json").read_text())["ranking"]
    assert len(ranking) == 6 and {r["learning_rate"] for r in ranking} == {1e-4, 1e-3, 1e-2}
    rates = [r["solve_rate"] for r in ranking]
    assert rates == sorted(rates, reverse=True)
    for c in range(6):
        info = json.loads((out / f"combo-{c:03d}" / "config.json").read_text())
        assert info["config"]["learning_rate"] == info["combination"]["learning_rate"]
        assert (out / f"combo-{c:03d}" / "params.npz").exists()
        assert (
            len(json.loads((out / f"combo-{c:03d}" / "evaluation.json").read_text())["seeds"]) == 2
        )
    m0 = rundir.read_metrics_csv(out / "combo-000" / "metrics.csv")
    m4 = rundir.read_metrics_csv(out / "combo-004" / "metrics.csv")
    np.testing.assert_allclose(m0["train/learning_rate"][0], [1e-4, 1e-4])
    np.testing.assert_allclose(m4["train/learning_rate"][0], [1e-2, 1e-2])
    assert not np.allclose(m0["train/value_loss"], m4["train/value_loss"])
    import jaxcart

    with pytest.raises(rundir.RunDirError, match="is a sweep"):
        jaxcart.load_policy(out)
    assert jaxcart.load_policy(out / "combo-001", seed_index=1)(np.zeros(4, np.float32)) in (0, 1)


@pytest.mark.parametrize(
    "spec, message",
    [
        (["learning_rate"], "malformed"),
        (["learning_rate=a,b"], "must be numbers"),
        (["num_envs=1,2"], "only float hyperparameters"),
        (["gamma=0.9,1.5"], None),
        (["clip_coef=0.1", "clip_coef=0.2"], "given twice"),
    ],
)
def test_bad_sweeps_rejected(spec, message, tmp_path, capsys):
    if message:
        with pytest.raises(ValueError, match=message):
            parse_sweep(spec)
    argv = [x for s in spec for x in ("--sweep", s)]
    assert main([*argv, "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x").exists()


def test_divergence_freezes_only_that_seed(tmp_path):
    """A seed whose update goes non-finite stops with its last finite state and is marked;
    the other seed trains exactly as it would have, and checkpoints stay finite."""
    from jaxcart.trainer import broadcast_hyperparams

    hps = broadcast_hyperparams(TINY, 2)
    bad = hps.replace(learning_rate=hps.learning_rate.at[1].set(1e35))
    good = train(TINY, 2, seed=5, hyperparams=hps)
    mixed = train(TINY, 2, seed=5, hyperparams=bad)
    diverged = np.asarray(mixed.runners.diverged_at)
    assert diverged[0] == -1 and diverged[1] >= 1
    for leaf in jax.tree.leaves(mixed.params):
        assert np.isfinite(np.asarray(leaf)).all()
    # seed 0 is untouched by seed 1's divergence
    for x, y in zip(jax.tree.leaves(good.params), jax.tree.leaves(mixed.params)):
        np.testing.assert_array_equal(np.asarray(x)[0], np.asarray(y)[0])
    # after the divergence seed 1 reports NaN metrics
    assert np.isnan(mixed.metrics["train/value_loss"][diverged[1] :, 1]).all()


def test_cli_reports_divergence(tmp_path, capsys):
    out = tmp_path / "div"
    argv = [
        *tiny_args(1024),
        "--no-compile-cache",
        "--sweep",
        "learning_rate=1e-3,1e35",
        "--out",
        str(out),
    ]
    assert main(argv) == 0
    captured = capsys.readouterr()
    assert "combo001-seed0 diverged at iteration" in captured.err
    seeds = json.loads((out / "combo-001" / "evaluation.json").read_text())["seeds"]
    assert seeds[0]["diverged_at_iteration"] >= 1
    ok = json.loads((out / "combo-000" / "evaluation.json").read_text())["seeds"]
    assert ok[0]["diverged_at_iteration"] is None
    ranking = json.loads((out / "sweep.json").read_text())["ranking"]
    assert {r["learning_rate"]: r["seeds_diverged"] for r in ranking} == {1e-3: 0, 1e35: 1}


def test_chunks_that_do_not_tile_the_run():
    """A chunk size that does not divide the iterations: the guarded program skips the
    overhang, and the run matches the tiled one (same per-iteration computation)."""
    tiled = train(TINY, 2, seed=9, chunk_size=2)
    ragged = train(TINY, 2, seed=9, chunk_size=5)  # 32 iterations = 6 chunks of 5 + 2
    assert ragged.state.iteration == 32 and ragged.metrics["train/value_loss"].shape == (32, 2)
    assert np.isfinite(ragged.metrics["train/value_loss"]).all()
    np.testing.assert_allclose(
        ragged.metrics["train/value_loss"], tiled.metrics["train/value_loss"], rtol=1e-4
    )

"""Structural sweeps: ``--sweep`` over settings that shape the program trains one program per
shape group, each group a run directory inside one sweep directory, every combination ranked
together in ``groups.json``; plot and compare read the sweep directory."""

from __future__ import annotations

import json
import signal

import numpy as np
import pytest
from helpers import assert_same_run_dirs

from jaxcart import train
from jaxcart.analysis.summary import auc
from jaxcart.core.config import ConfigError, PPOConfig
from jaxcart.run.spec import RunSpec, parse_sweep
from jaxcart.run.structural import group_spec
from jaxcart.rundir import files, layout, reader

BASE = [  # 2 envs or 4 envs x 32 steps, minibatches of 32: 4 or 8 iterations of 512 steps
    "--num-steps", "32", "--total-timesteps", "512", "--minibatch-size", "32",
    "--update-epochs", "2", "--eval-episodes", "2", "--num-seeds", "2", "--quiet",
]  # fmt: skip
SWEEP = ["--sweep", "num_envs=2,4", "--sweep", "learning_rate=1e-3,3e-3"]


def test_shape_axes_are_split_from_the_float_axes():
    floats, shapes = parse_sweep(["learning_rate=1e-3,3e-3", "hidden_sizes=32x32,64", "num_envs=4"])
    assert floats == {"learning_rate": [1e-3, 3e-3]}
    assert shapes == {"hidden_sizes": [(32, 32), (64,)], "num_envs": [4]}
    assert reader.sweep_combinations(shapes) == [
        {"hidden_sizes": (32, 32), "num_envs": 4},
        {"hidden_sizes": (64,), "num_envs": 4},
    ]
    with pytest.raises(ConfigError, match="'wide' is not a value like 64x64"):
        parse_sweep(["hidden_sizes=wide"])
    with pytest.raises(ConfigError, match="give distinct values"):
        parse_sweep(["num_envs=4,4"])
    with pytest.raises(ConfigError, match="group num_steps=32: minibatch_size=64 does not divide"):
        for group in [{"num_steps": 64}, {"num_steps": 32}]:
            group_spec(RunSpec(PPOConfig(num_steps=64)), group)


def test_a_structural_sweep_plans_one_program_per_group(capsys):
    assert train.main([*BASE, *SWEEP, "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "2 shape groups, so 2 programs compile" in out
    assert "num_envs=2:" in out and "num_envs=4:" in out


@pytest.mark.slow
def test_shape_groups_train_into_one_directory_ranked_together(tmp_path, capsys):
    out = tmp_path / "groups"
    assert train.main([*BASE, *SWEEP, "--score", "auc", "--out", str(out)]) == 0
    data = json.loads((out / layout.GROUPS_FILE).read_text())
    assert [g["num_envs"] for g in data["groups"]] == [2, 4]
    assert data["score"] == "auc" and data["saturated"] is False
    assert layout.GROUPS_FILE in files.read_manifest(out)  # written through the store
    ranking = data["ranking"]
    assert len(ranking) == 4  # every combination of both groups, one ranking
    iqms = [row["iqm"]["value"] for row in ranking]
    assert iqms == sorted(iqms, reverse=True)
    for row in ranking:  # each seed scored on its own group's curve (4 or 8 iterations)
        where = layout.combo_dir(out / f"group-{row['group']:03d}", row["group_combination"])
        curve = reader.read_metrics_csv(where / layout.METRICS_FILE)["rollout/ep_rew_mean"]
        np.testing.assert_allclose(row["scores"], auc(curve), rtol=1e-6)
        assert row["rank"] == 1 + sum(v > row["iqm"]["value"] for v in iqms)
    assert {(r["num_envs"], r["learning_rate"]) for r in ranking} == {
        (2, 1e-3), (2, 3e-3), (4, 1e-3), (4, 3e-3),
    }  # fmt: skip
    assert "Structural sweep ranking, 2 shape group(s)" in capsys.readouterr().out

    # a group is the sweep its shapes would train on their own
    alone = tmp_path / "alone"
    argv = [*BASE, "--num-envs", "4", "--sweep", "learning_rate=1e-3,3e-3", "--out", str(alone)]
    assert train.main(argv) == 0
    for c in range(2):
        assert_same_run_dirs(layout.combo_dir(out / "group-001", c), layout.combo_dir(alone, c))

    runs = reader.load_runs([out])
    assert [r.label for r in runs] == [
        "num_envs=2 learning_rate=0.001", "num_envs=2 learning_rate=0.003",
        "num_envs=4 learning_rate=0.001", "num_envs=4 learning_rate=0.003",
    ]  # fmt: skip
    from jaxcart import compare, plot

    assert plot.main([str(out)]) == 0 and (out / layout.CURVES_FILE).is_file()
    assert compare.main([str(out), "--out", str(tmp_path / "cmp"), "--reps", "100"]) == 0
    compared = json.loads((tmp_path / "cmp" / layout.COMPARE_FILE).read_text())
    assert len(compared["runs"]) == 4

    capsys.readouterr()
    assert train.main([*BASE, *SWEEP, "--out", str(out)]) == 2  # not empty: one line
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is not empty" in err


def _stopped_sweep(out, stop_in_group: int, groups: list[dict]):
    """A structural sweep through the library, stopped after the first chunk of group
    ``stop_in_group`` (as a signal would stop it): ``(spec, outcome)``."""
    from jaxcart.engine.signals import StopRequest
    from jaxcart.run import structural
    from jaxcart.run.spec import Hooks, RunOptions

    spec = RunSpec(
        PPOConfig(num_steps=32, total_timesteps=512, minibatch_size=32, update_epochs=2),
        num_seeds=2,
        sweep={"learning_rate": [1e-3, 3e-3]},
    )
    stop, chunks = StopRequest(), []

    def on_chunk(progress) -> None:
        chunks.append(progress.iteration)
        if progress.iteration == 1 and len(chunks) > 8 * stop_in_group:
            stop.request(signal.SIGTERM)

    hooks = Hooks(on_chunk=on_chunk)
    options = RunOptions(eval_episodes=2, chunk_size=1)
    return structural.run_groups(spec, groups, out, options, hooks, stop)


@pytest.mark.slow
def test_a_sweep_stopped_mid_group_resumes_as_a_whole_and_reads_at_any_stage(tmp_path, capsys):
    from jaxcart import compare, plot

    out = tmp_path / "groups"
    done = _stopped_sweep(out, 1, [{"num_envs": 2}, {"num_envs": 4}, {"num_envs": 8}])
    assert done.stopped and done.ranking == [] and not (out / layout.GROUPS_FILE).exists()
    # mid-sweep: group 0 finished, group 1 from its checkpoint, group 2 not started yet
    assert [r.label for r in reader.load_runs([out])] == [
        "num_envs=2 learning_rate=0.001", "num_envs=2 learning_rate=0.003",
        "num_envs=4 learning_rate=0.001", "num_envs=4 learning_rate=0.003",
    ]  # fmt: skip
    assert plot.main([str(out)]) == 0

    assert train.main(["--resume", str(out), "--quiet"]) == 0  # finishes every group
    assert "Structural sweep ranking, 3 shape group(s)" in capsys.readouterr().out
    data = json.loads((out / layout.GROUPS_FILE).read_text())
    assert [g["num_envs"] for g in data["groups"]] == [2, 4, 8]
    assert {(r["num_envs"], r["learning_rate"]) for r in data["ranking"]} == {
        (e, lr) for e in (2, 4, 8) for lr in (1e-3, 3e-3)
    }
    assert plot.main([str(out)]) == 0 and (out / layout.CURVES_FILE).is_file()
    assert compare.main([str(out), "--out", str(tmp_path / "cmp"), "--reps", "100"]) == 0
    compared = json.loads((tmp_path / "cmp" / layout.COMPARE_FILE).read_text())
    assert len(compared["runs"]) == 6

    # labels come from each group's own config.json, not from groups.json's free text
    data["groups"][0]["num_envs"] = 4096
    del data["groups"][2]
    (out / layout.GROUPS_FILE).write_text(json.dumps(data))
    labels = [r.label for r in reader.load_runs([out])]
    assert labels[0] == "num_envs=2 learning_rate=0.001" and len(labels) == 6
    assert not any("4096" in label for label in labels)
    assert compare.main([str(out), "--out", str(tmp_path / "cmp2"), "--reps", "100"]) == 0
    compared = json.loads((tmp_path / "cmp2" / layout.COMPARE_FILE).read_text())
    assert len(compared["runs"]) == 6 and "4096" not in json.dumps(compared)

"""Sweeps: every combination x seed in one compiled program, the run order, bad sweeps."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import tiny_args

from jaxcart.analysis import stats
from jaxcart.run.sweep import RunGrid, parse_sweep, rank
from jaxcart.rundir import reader
from jaxcart.rundir.files import RunDirError
from jaxcart.train import main


def test_run_grid_is_the_one_run_order():
    grid = RunGrid(3, ({"learning_rate": 1e-3}, {"learning_rate": 1e-2}))
    assert grid.num_runs == 6 and grid.num_combos == 2 and grid.is_sweep
    assert [grid.run_index(c, s) for c in range(2) for s in range(3)] == list(range(6))
    assert [(grid.combo_of(r), grid.seed_index_of(r)) for r in range(6)] == [
        (c, s) for c in range(2) for s in range(3)
    ]
    assert grid.seed_indices().tolist() == [0, 1, 2, 0, 1, 2]
    assert grid.runs_of(1) == slice(3, 6)
    assert grid.run_names()[4] == "combo001-seed1"
    plain = RunGrid(2)
    assert plain.num_runs == 2 and not plain.is_sweep and plain.run_names() == ["seed0", "seed1"]


@pytest.mark.slow
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
    assert "IQM gym return [95% CI]" in text and "P(> combo 0) [95% CI]" in text
    data = json.loads((out / "sweep.json").read_text())
    assert data["score"] == "eval" and "greedy return" in data["score_definition"]
    ranking = data["ranking"]
    assert {r["score"] for r in ranking} == {"eval"}
    assert len(ranking) == 6 and {r["learning_rate"] for r in ranking} == {1e-4, 1e-3, 1e-2}
    iqms = [r["iqm"]["value"] for r in ranking]
    assert iqms == sorted(iqms, reverse=True)

    def scores(c: int) -> list[float]:
        seeds = json.loads((out / f"combo-{c:03d}" / "evaluation.json").read_text())["seeds"]
        return [s["gymnasium_mean"] for s in seeds]

    for r in ranking:
        c = r["combination"]
        assert r["iqm"]["value"] == pytest.approx(stats.iqm(np.array(scores(c))))
        assert r["iqm"]["ci_low"] <= r["iqm"]["value"] <= r["iqm"]["ci_high"]
        poi = r["probability_of_improvement"]
        if c == 0:
            assert poi is None
        else:
            expected = stats.probability_of_improvement(scores(c), scores(0))
            assert poi["value"] == pytest.approx(expected)
    for c in range(6):
        info = json.loads((out / f"combo-{c:03d}" / "config.json").read_text())
        assert info["config"]["learning_rate"] == info["combination"]["learning_rate"]
        assert (out / f"combo-{c:03d}" / "params.npz").exists()
        assert (
            len(json.loads((out / f"combo-{c:03d}" / "evaluation.json").read_text())["seeds"]) == 2
        )
    m0 = reader.read_metrics_csv(out / "combo-000" / "metrics.csv")
    m4 = reader.read_metrics_csv(out / "combo-004" / "metrics.csv")
    np.testing.assert_allclose(m0["train/learning_rate"][0], [1e-4, 1e-4])
    np.testing.assert_allclose(m4["train/learning_rate"][0], [1e-2, 1e-2])
    assert not np.allclose(m0["train/value_loss"], m4["train/value_loss"])
    import jaxcart

    with pytest.raises(RunDirError, match="is a sweep"):
        jaxcart.load_policy(out)
    assert jaxcart.load_policy(out / "combo-001", seed_index=1)(np.zeros(4, np.float32)) in (0, 1)


def test_rank_by_iqm_with_probability_of_improvement():
    grid = RunGrid(4, ({"learning_rate": 1e-3}, {"learning_rate": 1e-2}, {"learning_rate": 0.1}))
    scores = np.array([500, 500, 100, 100, 400, 400, 400, 400, 500, 500, 500, 20], float)
    solved = scores == 500
    ranking = rank(grid, scores, solved, scores, np.full(12, np.inf))
    # IQM (mean of the middle two of four): 300, 400, 500; solve rates 0.5, 0, 0.75.
    assert [r["combination"] for r in ranking] == [2, 1, 0]
    assert [r["iqm"]["value"] for r in ranking] == [500.0, 400.0, 300.0]
    assert [r["solve_rate"] for r in ranking] == [0.75, 0.0, 0.5]
    poi = {r["combination"]: r["probability_of_improvement"] for r in ranking}
    assert poi[0] is None
    # 400 beats both 100s and loses to both 500s: 8 of 16 pairs.
    assert poi[1]["value"] == 0.5
    # each 500 ties two 500s (0.5 each) and beats two 100s: 3 x 3; the 20 wins nothing: 9 / 16.
    assert poi[2]["value"] == 0.5625
    assert poi[2]["ci_low"] <= 0.5625 <= poi[2]["ci_high"]
    assert ranking == rank(grid, scores, solved, scores, np.full(12, np.inf))  # deterministic


def test_rank_by_another_score():
    grid = RunGrid(2, ({"learning_rate": 1e-3}, {"learning_rate": 1e-2}))
    returns = np.array([[10, 20, np.nan, 30], [100, 200, 300, 400]], float)  # [2 its, 4 runs]
    steps, scores = np.array([128.0, 256.0]), np.full(4, 500.0)
    solved = np.ones(4, bool)
    args = (grid, scores, solved, scores, np.full(4, np.inf))
    by_auc = rank(*args, score="auc", returns=returns, env_steps=steps)
    # AUC per run (NaN as 0): 55, 110, 150, 215 -> IQM of two seeds is their mean.
    assert [(r["combination"], r["iqm"]["value"]) for r in by_auc] == [(1, 182.5), (0, 82.5)]
    assert {r["score"] for r in by_auc} == {"auc"}
    first = rank(*args, score="return-at:100", returns=returns, env_steps=steps)
    assert [r["iqm"]["value"] for r in first] == [15.0, 15.0]  # iteration 1; NaN counts as 0
    later = rank(*args, score="return-at:200", returns=returns, env_steps=steps)
    assert [(r["combination"], r["iqm"]["value"]) for r in later] == [(1, 350.0), (0, 150.0)]
    assert rank(*args)[0]["iqm"]["value"] == 500.0  # eval: the greedy scores
    with pytest.raises(ValueError, match="never reaches"):
        rank(*args, score="return-at:1000", returns=returns, env_steps=steps)


@pytest.mark.parametrize(
    "spec, message",
    [
        (["learning_rate"], "malformed"),
        (["learning_rate=a,b"], "must be numbers"),
        (["activation=1,2"], "only float hyperparameters"),  # shapes: test_structural_sweep
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


def _sweep_config(tmp_path, data: dict):
    run = tmp_path / "run"
    run.mkdir(parents=True)
    base = {"format_version": 1, "preset": "sb3", "num_seeds": 2, "seed": 0, "config": {}}
    (run / "config.json").write_text(json.dumps({**base, **data}))
    return run


def test_config_json_records_the_sweep_and_the_reader_derives_its_combinations(tmp_path):
    """A million-combination sweep would write 70 MB of combinations; the reader derives them
    from the sweep in the one run order, checks an older run's recorded list against it, and
    bounds the count before building any list."""
    sweep = {"learning_rate": [1e-3, 2e-3], "clip_coef": [0.1, 0.2, 0.3]}
    info = reader.read_run_config(_sweep_config(tmp_path / "a", {"sweep": sweep}))
    assert info["combinations"] == [
        {"learning_rate": lr, "clip_coef": c}
        for lr in sweep["learning_rate"]
        for c in [0.1, 0.2, 0.3]
    ]
    older = {"sweep": sweep, "combinations": info["combinations"]}
    assert (
        reader.read_run_config(_sweep_config(tmp_path / "b", older))["combinations"]
        == older["combinations"]
    )
    swapped = {"sweep": sweep, "combinations": info["combinations"][::-1]}
    with pytest.raises(RunDirError, match="do not match the sweep"):
        reader.read_run_config(_sweep_config(tmp_path / "c", swapped))
    huge = {f"f{i}": [float(v) for v in range(100)] for i in range(10)}  # 10^20 combinations
    with pytest.raises(RunDirError, match="combinations is over"):
        reader.read_run_config(_sweep_config(tmp_path / "d", {"sweep": huge}))


def test_a_sweeps_config_json_holds_no_combinations_list(tmp_path):
    out = tmp_path / "sweep"
    argv = [*tiny_args(1024), "--sweep", "learning_rate=1e-4,1e-3", "--out", str(out)]
    assert main(argv) == 0
    recorded = json.loads((out / "config.json").read_text())
    assert "combinations" not in recorded and recorded["sweep"] == {"learning_rate": [1e-4, 1e-3]}
    assert json.loads((out / "combo-001" / "config.json").read_text())["combination"] == {
        "learning_rate": 1e-3
    }

"""Sweeps: every combination x seed in one compiled program, the run order, bad sweeps."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import tiny_args

from jaxcart.analysis import stats
from jaxcart.analysis.summary import Score, auc
from jaxcart.run.spec import parse_sweep
from jaxcart.run.sweep import RunGrid, rank, ranking_notes, saturated
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
        "--score",
        "auc",
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
    # two seeds: the interval is their range, and the table says so
    assert "IQM auc [range of 2 seeds]" in text and "P(> combo 0) [range of 2 seeds]" in text
    assert "95% CI" not in text
    data = json.loads((out / "sweep.json").read_text())
    assert data["score"] == "auc" and "rollout/ep_rew_mean" in data["score_definition"]
    assert data["saturated"] is False
    ranking = data["ranking"]
    assert {r["score"] for r in ranking} == {"auc"}
    assert len(ranking) == 6 and {r["learning_rate"] for r in ranking} == {1e-4, 1e-3, 1e-2}
    iqms = [r["iqm"]["value"] for r in ranking]
    assert iqms == sorted(iqms, reverse=True)
    assert [r["rank"] for r in ranking] == [1 + iqms.index(v) for v in iqms]

    def scores(c: int) -> np.ndarray:  # compare --score auc's, from the combination's metrics
        metrics = reader.read_metrics_csv(out / f"combo-{c:03d}" / "metrics.csv")
        return auc(metrics["rollout/ep_rew_mean"])

    scores_of = {r["combination"]: r["scores"] for r in ranking}
    for r in ranking:
        c = r["combination"]
        np.testing.assert_allclose(r["scores"], scores(c), rtol=1e-6)  # csv: float32
        assert r["iqm"]["value"] == pytest.approx(stats.iqm(np.array(r["scores"])))
        assert r["iqm"]["ci_low"] <= r["iqm"]["value"] <= r["iqm"]["ci_high"]
        poi = r["probability_of_improvement"]
        if c == 0:
            assert poi is None
        else:
            expected = stats.probability_of_improvement(r["scores"], scores_of[0])
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


def test_rank_by_another_score_states_ties_and_saturation():
    grid = RunGrid(2, ({"learning_rate": 1e-3}, {"learning_rate": 1e-2}, {"learning_rate": 0.1}))
    returns = np.array([[10, 20, np.nan, 30, 10, 20], [100, 200, 300, 400, 100, 200]], float)
    steps, gym = np.array([128.0, 256.0]), np.full(6, 500.0)  # every seed solved: saturated
    solved = np.ones(6, bool)

    def ranked(score: str) -> list[dict]:  # scored as compare scores, then ranked
        scores = Score.parse(score).compute(gym, returns, steps)
        return rank(grid, scores, solved, gym, np.full(6, np.inf), score=score)

    by_auc = ranked("auc")
    # AUC per run (NaN as 0 on CartPole): 55, 110, 150, 215, 55, 110 -> IQM of two: the mean
    assert [(r["combination"], r["iqm"]["value"], r["rank"]) for r in by_auc] == [
        (1, 182.5, 1),
        (0, 82.5, 2),
        (2, 82.5, 2),  # tied with 0: the same rank, ordered by the tie-breakers alone
    ]
    assert {r["score"] for r in by_auc} == {"auc"} and not saturated(by_auc)
    (tie,) = ranking_notes(by_auc)
    assert "2 combinations share rank 2" in tie and "auc" in tie
    first = ranked("return-at:100")
    assert [r["iqm"]["value"] for r in first] == [15.0, 15.0, 15.0]  # NaN counts as 0
    by_eval = ranked("eval")
    assert saturated(by_eval) and {r["rank"] for r in by_eval} == {1}
    (note,) = ranking_notes(by_eval)
    assert note.startswith("saturated: every seed of every combination scores 500 by eval")
    assert "--score auc" in note


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


@pytest.mark.parametrize(
    "extra, message",
    [
        ([], "--score ranks the combinations of a --sweep"),
        (["--sweep", "learning_rate=1e-3,1e-2", "--score", "return-at:1e6"], "some trials end"),
        (["--sweep", "learning_rate=1e-3,1e-2", "--score", "best"], "unknown score 'best'"),
    ],
)
def test_a_score_that_cannot_rank_is_one_line_before_training(tmp_path, capsys, extra, message):
    argv = [*tiny_args(2048), "--out", str(tmp_path / "x"), *(extra or ["--score", "auc"])]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x").exists()

"""``python -m jaxcart.compare`` end to end on small real runs and a sweep, a run in the format
of ``python -m jaxcart.sb3``, and bad inputs (one line, exit code 2)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from helpers import tiny_args
from PIL import Image
from scipy.stats import trim_mean

from jaxcart import compare
from jaxcart.analysis import stats
from jaxcart.core.config import PPOConfig
from jaxcart.core.networks import ActorCritic
from jaxcart.engine.trainer import METRIC_COLUMNS
from jaxcart.run import sb3
from jaxcart.train import main as train_main


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> tuple[Path, Path]:
    """A 4-seed run ``a`` and a sweep of two learning rates x 2 seeds (4 runs as well: one
    compiled program serves both)."""
    root = tmp_path_factory.mktemp("compare")
    a, sweep = root / "a", root / "sweep"
    assert train_main([*tiny_args(1024, num_seeds=4), "--no-compile-cache", "--out", str(a)]) == 0
    argv = [*tiny_args(1024, num_seeds=2), "--no-compile-cache", "--out", str(sweep)]
    assert train_main([*argv, "--sweep", "learning_rate=1e-3,1e-2"]) == 0
    return a, sweep


def sb3_run(out: Path, num_seeds: int) -> Path:
    """A run directory written by ``python -m jaxcart.sb3``'s own writer, from made-up SB3
    logs (no ``rollout/ep_rew_max``: SB3 does not log it) and freshly initialised networks."""
    iterations = 5
    per_seed = []
    for s in range(num_seeds):
        metrics = {name: np.full(iterations, np.nan) for name in METRIC_COLUMNS}
        metrics["rollout/ep_rew_mean"] = np.linspace(20, 120 + 10 * s, iterations)
        metrics["time/fps"] = np.full(iterations, 1000.0)
        metrics["time/elapsed"] = np.arange(1.0, iterations + 1) * 2
        per_seed.append(metrics)
    evaluations = [np.full(20, 150.0 + 25 * s) for s in range(num_seeds)]
    network = ActorCritic.from_config(PPOConfig())
    results = [
        sb3.SeedResult(m, network.init(np.random.default_rng(s)), r, 10.0)
        for s, (m, r) in enumerate(zip(per_seed, evaluations))
    ]
    out.mkdir()
    sb3.write_run(out, PPOConfig(), results)
    return out


def assert_png(path: Path) -> None:
    with Image.open(path) as image:
        assert image.format == "PNG" and image.size[0] > 1000 and image.size[1] > 800
        pixels = np.asarray(image.convert("RGB"), float)
    assert pixels.std() > 10 and len(np.unique(pixels.reshape(-1, 3), axis=0)) > 20


def read_scores(run_dir: Path) -> list[float]:
    seeds = json.loads((run_dir / "evaluation.json").read_text())["seeds"]
    return [s["gymnasium_mean"] for s in seeds]


def test_compare_runs_and_a_sweep(runs, tmp_path, capsys):
    a, sweep = runs
    out = tmp_path / "cmp"
    assert compare.main([str(a), str(sweep), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    lines = text.splitlines()
    assert "baseline a" in lines[0] and "2000 resamples, seed 0" in lines[0]
    assert "IQM [95% CI]" in lines[1] and "P(> baseline) [95% CI]" in lines[1]
    names = [line.split()[0] for line in lines[3:6]]
    assert names == ["a", "learning_rate=0.001", "learning_rate=0.01"]
    assert "baseline" in lines[3]
    assert "note: seed counts differ (4 for a; 2 for 2 runs)" in text
    assert f"wrote {out / 'compare.json'} and {out / 'compare.png'}" in text

    data = json.loads((out / "compare.json").read_text())
    assert data["baseline"] == "a" and data["bootstrap"]["reps"] == 2000
    assert [r["name"] for r in data["runs"]] == names
    for r, path in zip(data["runs"], [a, sweep / "combo-000", sweep / "combo-001"]):
        scores = read_scores(path)
        assert r["scores"] == scores and r["num_seeds"] == len(scores)
        assert r["iqm"]["value"] == pytest.approx(trim_mean(scores, 0.25))
        assert r["mean"]["value"] == pytest.approx(np.mean(scores))
        assert r["median"]["value"] == pytest.approx(np.median(scores))
        gap = np.mean(np.maximum(500 - np.array(scores), 0))
        assert r["optimality_gap"]["value"] == pytest.approx(gap)
        for key in ("mean", "median", "iqm", "optimality_gap"):
            assert r[key]["ci_low"] <= r[key]["value"] <= r[key]["ci_high"]
        assert len(r["steps_to_500"]) == len(scores)
    assert data["runs"][0]["probability_of_improvement"] is None
    for r in data["runs"][1:]:
        poi = stats.probability_of_improvement(r["scores"], data["runs"][0]["scores"])
        assert r["probability_of_improvement"]["value"] == pytest.approx(poi)
    assert_png(out / "compare.png")
    assert not (a / "compare.json").exists()

    # The same runs give the same output.
    assert compare.main([str(a), str(sweep), "--out", str(tmp_path / "again")]) == 0
    again = (tmp_path / "again" / "compare.json").read_text()
    assert again == (out / "compare.json").read_text()


def test_a_sweep_alone_agrees_with_its_ranking(runs, tmp_path, monkeypatch, capsys):
    _, sweep = runs
    monkeypatch.chdir(tmp_path)
    assert compare.main([str(sweep)]) == 0
    capsys.readouterr()
    [out] = tmp_path.glob("compare-*")  # the default: a new directory here
    data = json.loads((out / "compare.json").read_text())
    ranking = {
        r["combination"]: r for r in json.loads((sweep / "sweep.json").read_text())["ranking"]
    }
    assert data["baseline"] == "learning_rate=0.001"  # combination 0
    for c, r in enumerate(data["runs"]):
        assert r["iqm"] == pytest.approx(ranking[c]["iqm"])
        if c == 0:
            assert (
                r["probability_of_improvement"] is ranking[c]["probability_of_improvement"] is None
            )
        else:
            assert r["probability_of_improvement"] == pytest.approx(
                ranking[c]["probability_of_improvement"]
            )
        steps = [np.inf if s is None else s for s in r["steps_to_500"]]
        assert np.median(steps) == ranking[c]["median_steps_to_500"]


def test_baseline_option(runs, tmp_path, capsys):
    a, sweep = runs
    assert compare.main([str(sweep), "--baseline", str(a), "--out", str(tmp_path / "x")]) == 0
    data = json.loads((tmp_path / "x" / "compare.json").read_text())
    names = [r["name"] for r in data["runs"]]
    assert names == ["a", "learning_rate=0.001", "learning_rate=0.01"] and data["baseline"] == "a"
    baseline = str(sweep / "combo-001")
    assert (
        compare.main([str(a), str(sweep), "--baseline", baseline, "--out", str(tmp_path / "y")])
        == 0
    )
    data = json.loads((tmp_path / "y" / "compare.json").read_text())
    assert data["baseline"] == "learning_rate=0.01" and len(data["runs"]) == 3
    assert [r["probability_of_improvement"] is None for r in data["runs"]] == [False, False, True]
    assert "baseline learning_rate=0.01" in capsys.readouterr().out


def test_sb3_format_and_single_seed(runs, tmp_path, capsys):
    a, _ = runs
    single = sb3_run(tmp_path / "sb3-torch", num_seeds=1)
    assert compare.main([str(a), str(single), "--out", str(tmp_path / "cmp")]) == 0
    text = capsys.readouterr().out
    assert "note: sb3-torch has a single seed: its confidence intervals are degenerate" in text
    assert "note: seed counts differ (4 for a; 1 for sb3-torch)" in text
    assert "greedy evaluation episodes per seed differ (2, 20)" in text
    assert "sb3-torch did not record rollout/ep_rew_max" in text
    data = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    sb3 = data["runs"][1]
    assert sb3["scores"] == [150.0] and sb3["steps_to_500"] is None
    assert sb3["iqm"] == {"value": 150.0, "ci_low": 150.0, "ci_high": 150.0}
    assert_png(tmp_path / "cmp" / "compare.png")
    several = sb3_run(tmp_path / "sb3-3", num_seeds=3)
    assert compare.main([str(several), "--out", str(tmp_path / "one")]) == 0
    assert "one run only" in capsys.readouterr().out


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: "), err
    assert "Traceback" not in err
    return err


def test_bad_inputs_exit_2_with_one_line(runs, tmp_path, capsys):
    a, sweep = runs
    out = ["--out", str(tmp_path / "out")]
    no_eval = tmp_path / "no-eval"
    shutil.copytree(a, no_eval)
    (no_eval / "evaluation.json").unlink()
    corrupted = tmp_path / "corrupted"
    shutil.copytree(a, corrupted)
    (corrupted / "evaluation.json").write_text('{"seeds": [{"solved": true}]}')
    cases = [
        ([str(tmp_path / "missing"), *out], "is not a directory"),
        ([str(tmp_path), *out], "not a jaxcart run directory"),
        ([str(a), str(no_eval), *out], "has no evaluation.json"),
        ([str(corrupted), *out], "is corrupted"),
        ([str(a), "--out", str(a / "cmp")], "inside the run directory"),
        ([str(sweep), "--out", str(sweep / "combo-000" / "cmp")], "inside the run directory"),
        ([str(a), "--baseline", str(sweep), *out], "is a sweep"),
        ([str(a), str(a), *out], "given twice"),
        ([str(a), "--reps", "10", *out], "--reps"),
        ([], "RUN_DIR"),
    ]
    for argv, message in cases:
        assert compare.main(argv) == 2, argv
        assert message in one_line_error(capsys), argv
    assert not (a / "cmp").exists() and not (tmp_path / "out").exists()

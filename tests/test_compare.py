"""``python -m jaxcart.compare`` end to end on small real runs and a sweep, runs in the format
of ``python -m jaxcart.sb3``, every ``--score``, saturation, arms over configurations, and bad
inputs (one line, exit code 2)."""

from __future__ import annotations

import csv
import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from helpers import distinct_colours, seal, tiny_args
from PIL import Image
from scipy.stats import trim_mean

from jaxcart import compare
from jaxcart.analysis import stats, summary
from jaxcart.core.config import PPOConfig
from jaxcart.core.networks import ActorCritic
from jaxcart.engine.loop import METRIC_COLUMNS
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


def sb3_run(out: Path, num_seeds: int, score: float | None = None) -> Path:
    """A run directory written by ``python -m jaxcart.sb3``'s own writer, from made-up SB3
    logs (no ``rollout/ep_rew_max``: SB3 does not log it) and freshly initialised networks;
    every greedy episode scores ``score`` when given."""
    iterations = 5
    per_seed = []
    for s in range(num_seeds):
        metrics = {name: np.full(iterations, np.nan) for name in METRIC_COLUMNS}
        metrics["rollout/ep_rew_mean"] = np.linspace(20, 120 + 10 * s, iterations)
        metrics["time/fps"] = np.full(iterations, 1000.0)
        metrics["time/elapsed"] = np.arange(1.0, iterations + 1) * 2
        per_seed.append(metrics)
    evaluations = [
        np.full(20, 150.0 + 25 * s if score is None else score) for s in range(num_seeds)
    ]
    network = ActorCritic.from_config(PPOConfig())
    results = [
        sb3.SeedResult(m, network.host_init(np.random.default_rng(s)), r, 10.0)
        for s, (m, r) in enumerate(zip(per_seed, evaluations))
    ]
    out.mkdir()
    sb3.write_run(out, PPOConfig(), results)
    return out


def assert_png(path: Path) -> None:
    with Image.open(path) as image:
        assert image.format == "PNG" and image.size[0] > 1000 and image.size[1] > 800
        pixels = np.asarray(image.convert("RGB"), float)
    assert pixels.std() > 10 and distinct_colours(pixels) > 20


def printed(capsys: pytest.CaptureFixture) -> str:
    """What the command printed, with the notes it wrapped to 100 columns read as one line."""
    return capsys.readouterr().out.replace("\n  ", " ")


def read_scores(run_dir: Path) -> list[float]:
    seeds = json.loads((run_dir / "evaluation.json").read_text())["seeds"]
    return [s["gymnasium_mean"] for s in seeds]


def test_compare_runs_and_a_sweep(runs, tmp_path, capsys):
    a, sweep = runs
    out = tmp_path / "cmp"
    assert compare.main([str(a), str(sweep), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    lines = text.splitlines()
    assert max(len(line) for line in lines if not line.startswith("wrote ")) <= 100
    heading = " ".join(lines[:2])
    assert "baseline a" in heading and "2000 resamples, seed 0" in heading
    # 4 seeds and 2: a 2-seed run's interval is its seeds' range, and the header says so
    first = next(i for i, line in enumerate(lines) if "IQM [95% CI; range below 5 seeds]" in line)
    names = [line.split()[0] for line in lines[first + 2 : first + 5]]
    assert names == ["a", "learning_rate=0.001", "learning_rate=0.01"]
    second = next(i for i, line in enumerate(lines) if "P(> baseline) [95% CI; range" in line)
    assert lines[second + 2].split()[0] == "a" and "baseline" in lines[second + 2]
    text = text.replace("\n  ", " ")  # notes wrapped to 100 columns, read as one line
    assert "note: seed counts differ (4 for a; 2 for 2 runs)" in text
    assert f"wrote {out / 'compare.json'}, {out / 'compare.png'}, {out / 'curves.csv'}" in text
    assert "saturated: no" in text and "2 comparison(s) against a baseline" in text
    assert "up to 10% chance that at least one misses" in text
    assert "P(row > column)" in text  # three runs: the all-pairs matrix

    data = json.loads((out / "compare.json").read_text())
    assert data["baseline"] == "a" and data["bootstrap"]["reps"] == 2000
    assert data["score"] == "eval" and data["saturated"] is False
    assert len(data["probability_of_improvement_matrix"]["values"]) == 3
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
        assert len(r["steps_to_500"]) == len(scores) and r["score"] == "eval"
        solved = sum(
            s["solved"] for s in json.loads((path / "evaluation.json").read_text())["seeds"]
        )
        assert r["solved"] == stats.wilson_interval(solved, len(scores)).to_dict()
    assert data["runs"][0]["probability_of_improvement"] is None
    assert data["runs"][0]["difference_iqm"] is None
    for r in data["runs"][1:]:
        poi = stats.probability_of_improvement(r["scores"], data["runs"][0]["scores"])
        assert r["probability_of_improvement"]["value"] == pytest.approx(poi)
        gap = stats.iqm(r["scores"]) - stats.iqm(data["runs"][0]["scores"])
        assert r["difference_iqm"]["value"] == pytest.approx(gap)
        assert r["difference_iqm"]["ci_low"] <= gap <= r["difference_iqm"]["ci_high"]
    assert_png(out / "compare.png")
    assert not (a / "compare.json").exists()

    # The same runs give the same output (compare.json; the figure of these runs was drawn,
    # saved and checked above, so the repeat does not render it again).
    from jaxcart.results import figure

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(figure, "save", lambda fig, out, dpi=100: None)
        assert compare.main([str(a), str(sweep), "--out", str(tmp_path / "again")]) == 0
    again = (tmp_path / "again" / "compare.json").read_text()
    assert again == (out / "compare.json").read_text()


def test_a_sweep_alone_agrees_with_its_ranking(runs, tmp_path, monkeypatch, capsys):
    _, sweep = runs
    monkeypatch.chdir(tmp_path)
    assert compare.main([str(sweep)]) == 0
    capsys.readouterr()
    # the default: a new directory beside the compared run, nothing in the current directory
    [out] = sweep.parent.glob("compare-*")
    assert sweep.parent != tmp_path and not list(tmp_path.iterdir())
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
    assert "baseline learning_rate=0.01" in printed(capsys)


def test_sb3_format_and_single_seed(runs, tmp_path, capsys, no_warnings):
    a, _ = runs
    single = sb3_run(tmp_path / "sb3-torch", num_seeds=1)
    assert compare.main([str(a), str(single), "--out", str(tmp_path / "cmp")]) == 0
    text = printed(capsys)
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
    assert "one run only" in printed(capsys)


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
    seal(corrupted)
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
        ([str(a), "--score", "mean", *out], "unknown score"),
        ([str(a), "--score", "return-at:x", *out], "STEPS expected a whole number"),
        ([], "RUN_DIR"),
    ]
    for argv, message in cases:
        assert compare.main(argv) == 2, argv
        assert message in one_line_error(capsys), argv
    assert not (a / "cmp").exists() and not (tmp_path / "out").exists()


def metrics_auc(run_dir: Path) -> list[float]:
    """Each seed's AUC from metrics.csv with csv and NumPy alone: the mean over its rows of
    rollout/ep_rew_mean, an empty or nan value counting as 0."""
    per_seed: dict[int, list[float]] = {}
    with open(run_dir / "metrics.csv", newline="") as f:
        for row in csv.DictReader(f):
            value = float(row["rollout/ep_rew_mean"] or "nan")
            per_seed.setdefault(int(row["seed_index"]), []).append(
                0.0 if np.isnan(value) else value
            )
    return [float(np.mean(per_seed[s])) for s in sorted(per_seed)]


def test_auc_score_is_recomputable_from_metrics_csv(runs, tmp_path, capsys):
    a, sweep = runs
    out = tmp_path / "auc"
    assert (
        compare.main(
            [str(a), str(sweep), "--baseline", str(a), "--score", "auc", "--out", str(out)]
        )
        == 0
    )
    text = printed(capsys)
    assert "score = auc" in text
    data = json.loads((out / "compare.json").read_text())
    assert data["score"] == "auc" and data["runs"][0]["name"] == "a"
    for r, path in zip(data["runs"], [a, sweep / "combo-000", sweep / "combo-001"]):
        aucs = metrics_auc(path)
        assert r["score"] == "auc" and r["scores"] == pytest.approx(aucs)
        assert r["iqm"]["value"] == pytest.approx(trim_mean(aucs, 0.25))
        assert set(r["solved"]) == {"value", "ci_low", "ci_high"}
        assert r["solved"]["ci_low"] <= r["solved"]["value"] <= r["solved"]["ci_high"]
    for r in data["runs"][1:]:
        assert set(r["difference_iqm"]) == {"value", "ci_low", "ci_high"}
    # curves.csv: every seed's learning curve, the same numbers as the runs' metrics.csv.
    with open(out / "curves.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    a_rows = [r for r in rows if r["run"] == "a"]
    assert len(a_rows) == 4 * (1024 // 128)  # 4 seeds x 8 iterations
    seed1 = [float(r["ep_rew_mean"]) for r in a_rows if r["seed"] == "1"]
    assert np.mean(np.nan_to_num(seed1)) == pytest.approx(metrics_auc(a)[1])


def test_return_at_score(runs, tmp_path, capsys):
    a, _ = runs
    run = compare.runs.load_entries([a], score=summary.Score("return-at", 500))[0][0]
    returns = run.run.metrics["rollout/ep_rew_mean"]
    assert run.scores.tolist() == np.nan_to_num(returns[3]).tolist()  # 512 steps: iteration 4
    assert compare.main([str(a), "--score", "return-at:1_000", "--out", str(tmp_path / "r")]) == 0
    data = json.loads((tmp_path / "r" / "compare.json").read_text())
    assert data["score"] == "return-at:1000" and data["runs"][0]["score"] == "return-at:1000"
    assert data["runs"][0]["scores"] == np.nan_to_num(returns[7]).tolist()
    capsys.readouterr()
    assert compare.main([str(a), "--score", "return-at:1e5", "--out", str(tmp_path / "x")]) == 2
    assert "never reaches 100000 env steps" in one_line_error(capsys)
    with pytest.raises(compare.runs.CompareError, match="never reaches 100000 env steps"):
        compare.runs.load_entries([a], score=summary.Score("return-at", 100_000))


def test_the_eval_score_names_the_runs_env():
    """One wording of a score for every reader (the train sweep's ranking, compare's table,
    its JSON and figure): ``eval`` names the env the runs were evaluated in."""
    score = summary.Score.parse("eval")
    assert "gymnasium.make('CartPole-v1')" in score.definition()
    assert "gymnasium.make('Acrobot-v1')" in score.definition(["Acrobot-v1", "Acrobot-v1"])
    assert "each run's env" in score.definition(["Acrobot-v1", "CartPole-v1"])
    assert "100,000 env steps" in summary.Score.parse("return-at:100000").definition()


def test_saturated_scores_are_said_out_loud(tmp_path, capsys):
    x, y = sb3_run(tmp_path / "x", 3, score=500.0), sb3_run(tmp_path / "y", 3, score=500.0)
    assert compare.main([str(x), str(y), "--out", str(tmp_path / "eval")]) == 0
    text = printed(capsys)
    assert (
        "every seed of every run scores 500 by eval: the score cannot tell the runs apart" in text
    )
    assert "--score auc" in text
    data = json.loads((tmp_path / "eval" / "compare.json").read_text())
    assert data["saturated"] is True
    assert data["runs"][0]["solved"]["value"] == 1.0 and data["runs"][0]["solved"]["ci_low"] < 1
    assert data["runs"][1]["probability_of_improvement"]["value"] == 0.5
    assert_png(tmp_path / "eval" / "compare.png")
    # The learning curves still differ between seeds: the AUC can tell them apart.
    assert compare.main([str(x), str(y), "--score", "auc", "--out", str(tmp_path / "auc")]) == 0
    assert "saturated: no" in printed(capsys)
    assert json.loads((tmp_path / "auc" / "compare.json").read_text())["saturated"] is False


def test_arms_over_configurations(tmp_path, capsys):
    runs = {f"{arm}{k}": sb3_run(tmp_path / f"{arm}{k}", 2 + k) for arm in "pq" for k in (0, 1)}
    argv = ["--arm", f"p={runs['p0']},{runs['p1']}", "--arm", f"q={runs['q0']},{runs['q1']}"]
    out = tmp_path / "arms"
    assert (
        compare.main([*argv, "--baseline", "q", "--adjust", "bonferroni", "--out", str(out)]) == 0
    )
    text = printed(capsys)
    assert "Arms over 2 configuration(s)" in text and "baseline arm q" in text
    data = json.loads((out / "compare.json").read_text())
    assert data["baseline"] == "q" and [a["name"] for a in data["arms"]] == ["q", "p"]
    scores = {r["name"]: r["scores"] for r in data["runs"]}
    p_tasks, q_tasks = [scores["p0"], scores["p1"]], [scores["q0"], scores["q1"]]
    assert data["arms"][1]["iqm"] == stats.bootstrap_ci(p_tasks, stats.iqm).to_dict()
    # 2 runs against their configuration's q run + 1 arm against arm q: 3 comparisons.
    assert data["comparisons"]["count"] == 3
    assert data["comparisons"]["confidence_each"] == pytest.approx(1 - 0.05 / 3)
    confidence = data["comparisons"]["confidence_each"]
    expected = stats.difference_ci(p_tasks, q_tasks, confidence=confidence)
    assert data["arms"][1]["difference_iqm"] == pytest.approx(expected.to_dict())
    assert {r["name"]: r["reference"] for r in data["runs"]}["p1"] == "q1"
    assert data["probability_of_improvement_matrix"] is None
    bad = [
        ([*argv, "--arm", f"r={runs['p0']}"], "one run per configuration"),
        (["--arm", f"p={runs['p0']}"], "at least two arms"),
        (["--arm", "p"], "expected NAME=RUN_DIR"),
        ([*argv, "--baseline", "z"], "is not an arm"),
        ([*argv, str(runs["p0"])], "not both"),
    ]
    for args, message in bad:
        assert compare.main([*args, "--out", str(tmp_path / "bad")]) == 2, args
        assert message in one_line_error(capsys), args


def test_help_defines_every_statistic(capsys):
    assert compare.main(["--help"]) == 0
    text = printed(capsys)
    for name in summary.DEFINITIONS:
        assert f"\n{name}: " in text, name
    assert "median over seeds" in text and "--score" in text and "--arm" in text


def saved_figure(command) -> object:
    """Runs ``command`` (a comparison that writes compare.png) and returns the figure it drew
    and saved, as saving left it (laid out)."""
    from jaxcart.results import figure

    drawn = []
    with pytest.MonkeyPatch.context() as mp:
        real = figure.draw_comparison
        mp.setattr(figure, "draw_comparison", lambda c: drawn.append(real(c)) or drawn[-1])
        command()
    [fig] = drawn
    return fig


def test_figure_panels_share_one_score_axis_and_show_small_differences_small(
    runs, tmp_path, no_warnings
):
    from jaxcart.results import figure

    a, sweep = runs
    fig = saved_figure(lambda: compare.compare_runs([a, sweep], out=tmp_path / "cmp"))
    by_title = {ax.get_title(): ax for ax in fig.axes}
    location = [by_title[figure.ESTIMATE_TITLES[n]].get_xlim() for n in ("iqm", "median", "mean")]
    assert location[0] == location[1] == location[2]
    low, high = location[0]
    least = figure.MIN_SPAN * 500  # a tenth of CartPole's returns, [0, 500]
    assert high - low >= least and high <= 500 * 1.05 and low >= -500 * 0.05
    titles = {title.format(target="500") for title in figure.ESTIMATE_TITLES.values()}
    for ax in fig.axes:  # every interval panel writes its numbers out
        if ax.get_title() in titles:
            assert any("[" in t.get_text() for t in ax.texts)

    # Two estimates 1.6 points apart near 500 get a panel at least 50 points wide within [0, 500].
    close = [stats.Estimate(498.4, 497.0, 499.5), stats.Estimate(500.0, 499.0, 500.0)]
    low, high = figure._limits(close, 0.0, 500.0, 498.4, 500.0)
    assert high - low >= least and high < 500 + 0.05 * least + 1


def test_acrobot_scores_are_read_against_its_own_returns(tmp_path, no_warnings):
    """An env whose returns are negative (Acrobot-v1: [-500, 0], solved at -100): the
    optimality gap and "reached" measure against -100, and every panel shows the scores."""
    from jaxcart.results import figure
    from jaxcart.rundir.reader import RunCurves

    steps = np.arange(1.0, 5.0) * 1024

    def entry(name: str, scores: list[float], reached_at: int) -> compare.runs.Entry:
        best = np.full((len(steps), len(scores)), -300.0)
        best[reached_at:] = -90.0  # a training episode at -90 from this iteration on
        metrics = {"rollout/ep_rew_max": best, "rollout/ep_rew_mean": best - 20}
        run = RunCurves(tmp_path / name, name, metrics, steps, None, len(scores), None)
        run = dataclasses.replace(run, env="Acrobot-v1")
        x = np.asarray(scores)
        return compare.runs.Entry(run, x, solved=int((x >= -100).sum()), episodes=20)

    a = entry("a", [-80.0, -90.0, -120.0, -85.0], 1)
    b = entry("b", [-82.0, -95.0, -500.0, -81.0], 2)
    comparison = compare.runs.build_comparison([a, b], reps=200)
    assert comparison.runs[0]["optimality_gap"].value == pytest.approx(20 / 4)  # -120: 20 short
    assert comparison.runs[1]["optimality_gap"].value == pytest.approx(400 / 4)
    assert summary.first_reached(a.run, steps).tolist() == [2048.0] * 4
    text = compare.report_text(comparison)
    assert "reached -100" in text and "gymnasium.make('Acrobot-v1')" in text
    fig = figure.draw_comparison(comparison)
    by_title = {ax.get_title(): ax for ax in fig.axes}
    for name in ("IQM over seeds", "median over seeds", "mean over seeds"):
        low, high = by_title[name].get_xlim()
        assert -520 < low < -120 and -81 < high < 20, name
    assert by_title["optimality gap: mean of -100 - score"].get_xlim()[1] > 100
    profile = by_title["performance profile (eval); dot: fraction at -100"]
    assert profile.get_xlim()[0] == -500
    assert "a training episode at -100 (rollout/ep_rew_max)" in by_title


@pytest.mark.parametrize(
    ("seeds", "scores"),
    [(1, (500.0, 480.0)), (8, (500.0, 500.0)), (8, (500.0, None))],
    ids=["one-seed-each", "eight-seeds-all-500", "saturated-and-not"],
)
def test_the_courses_comparisons_draw_cleanly(tmp_path, seeds, scores, no_warnings):
    """The course's comparisons, long run names included, lay out (no matplotlib warning) and
    write every number inside its panel, with no panel's labels running into another's."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.transforms import Bbox

    names = ("course-base", "course-linear")
    dirs = [sb3_run(tmp_path / name, seeds, score) for name, score in zip(names, scores)]
    result = []
    fig = saved_figure(
        lambda: result.append(compare.compare_runs(dirs, out=tmp_path / "cmp", reps=200))
    )
    assert_png(result[0].figure_path)
    renderer = FigureCanvasAgg(fig).get_renderer()  # the figure as saved: laid out
    boxes = [ax.get_tightbbox(renderer) for ax in fig.axes]
    for ax, box in zip(fig.axes, boxes):
        inside = ax.get_window_extent(renderer)
        for text in ax.texts:  # value [low, high] and notes: within the panel
            extent = text.get_window_extent(renderer)
            assert inside.x0 - 1 <= extent.x0 and extent.x1 <= inside.x1 + 1, text.get_text()
        for other in boxes[: fig.axes.index(ax)]:  # titles, tick and axis labels apart
            common = Bbox.intersection(box, other)
            assert common is None or min(common.width, common.height) < 2, ax.get_title()

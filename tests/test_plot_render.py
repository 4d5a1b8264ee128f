"""Learning-curve plots (``python -m jaxcart.plot``), GIF rendering and the evaluate CLI."""

from __future__ import annotations

import csv
import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from helpers import distinct_colours, seal, tiny_args
from PIL import Image, ImageSequence

from jaxcart import evaluate, plot
from jaxcart.analysis import stats
from jaxcart.results import figure as figures
from jaxcart.results import gif as render
from jaxcart.rundir.files import RunDirError
from jaxcart.rundir.reader import RunCurves, load_runs
from jaxcart.train import main as train_main

TINY = [*tiny_args(2048, num_seeds=2), "--no-compile-cache"]


def balancing_policy(obs: np.ndarray) -> int:
    """Pushes towards the side the pole falls to: keeps it up, wobbling, for 100+ steps."""
    return int(obs[2] + 0.2 * obs[3] > 0)


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "tiny"
    assert train_main([*TINY, "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def single_seed_run(tiny_run, tmp_path_factory):
    """``tiny_run`` cut down to its first seed, with NaN returns in its first iterations."""
    out = tmp_path_factory.mktemp("runs") / "single"
    shutil.copytree(tiny_run, out)
    info = json.loads((out / "config.json").read_text())
    info["num_seeds"] = 1
    (out / "config.json").write_text(json.dumps(info))
    evaluation = json.loads((out / "evaluation.json").read_text())
    evaluation["seeds"] = evaluation["seeds"][:1]  # one entry per seed, as plot checks
    (out / "evaluation.json").write_text(json.dumps(evaluation))
    with open(tiny_run / "metrics.csv", newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["seed_index"] == "0"]
    for r in rows[:3]:
        r["rollout/ep_rew_mean"] = "nan"
    with open(out / "metrics.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    seal(out)  # crafted by someone who recomputes the manifest: the checks behind it run
    return out


def assert_nontrivial_png(path, min_size=(600, 400)):
    with Image.open(path) as image:
        assert image.format == "PNG"
        assert image.size[0] >= min_size[0] and image.size[1] >= min_size[1]
        pixels = np.asarray(image.convert("RGB"), float)
    assert pixels.std() > 10  # not blank
    assert distinct_colours(pixels) > 20  # curves, bands, text
    # Curves in the first run's colour (Okabe and Ito's blue) are drawn.
    blue = (np.abs(pixels - [0, 114, 178]).sum(-1) < 30).sum()
    assert blue > 100


def mean_and_band(values, bounds=(-np.inf, np.inf)):
    """What the plot draws: the mean across seeds and its band, clipped to the metric's range."""
    return stats.curve_band(values, "mean", bounds=bounds)


def test_mean_and_band_ignores_nan_needs_two_seeds_and_stays_in_range():
    values = np.array([[np.nan, np.nan], [1.0, 3.0], [2.0, np.nan], [5.0, 5.0]])
    mean, low, high = mean_and_band(values)
    np.testing.assert_allclose(mean, [np.nan, 2.0, 2.0, 5.0])
    # Bootstrap of two seeds {1, 3}: resampled means 1, 2, 3 (P = 1/4, 1/2, 1/4), so the 95%
    # interval is [1, 3] (a Student-t interval would be 2 ± 12.7).
    np.testing.assert_allclose([low[1], high[1]], [1.0, 3.0])
    assert np.isnan(low[[0, 2]]).all() and np.isnan(high[[0, 2]]).all()
    np.testing.assert_allclose([low[3], high[3]], [5.0, 5.0])
    again = mean_and_band(values)  # deterministic
    np.testing.assert_array_equal(np.nan_to_num(again[1]), np.nan_to_num(low))
    # A metric's range clips the band: explained variance <= 1, clip fraction in [0, 1].
    rng = np.random.default_rng(0)
    ev = np.stack([rng.uniform(-20, 1, 8), np.ones(8)])
    _, low, high = mean_and_band(ev, figures.METRIC_BOUNDS["train/explained_variance"])
    assert (high <= 1).all() and low[0] < -5
    _, low, high = mean_and_band(np.array([[0.5, 3.0]]), (0.0, 1.0))
    assert low[0] == 0.5 and high[0] == 1.0
    assert figures.METRIC_BOUNDS["rollout/ep_rew_mean"] == (0.0, 500.0)
    assert figures.METRIC_BOUNDS["train/approx_kl"][0] == 0.0
    # On another env: its returns' range, and the entropy of its three actions.
    assert figures.metric_bounds("rollout/ep_rew_mean", "Acrobot-v1") == (-500.0, 0.0)
    assert figures.metric_bounds("train/entropy_loss", "Acrobot-v1") == (-np.log(3), 0.0)
    assert figures.metric_bounds("train/approx_kl", "Acrobot-v1") == (0.0, np.inf)


def test_plot_one_run_default_path(tiny_run, capsys, no_warnings):
    assert plot.main([str(tiny_run)]) == 0
    out = tiny_run / "curves.png"
    assert capsys.readouterr().out.strip() == str(out)
    assert_nontrivial_png(out, min_size=(1000, 700))


@pytest.mark.slow
def test_plot_overlay_and_single_seed(
    tiny_run, single_seed_run, tmp_path, monkeypatch, capsys, no_warnings
):
    # The single-seed run (no band, NaN returns at first) overlaid on the two-seed one; several
    # runs go to comparison.png in the current directory, not into a run directory, and the
    # command prints its full path.
    monkeypatch.chdir(tmp_path)
    assert plot.main([str(single_seed_run), str(tiny_run), "--dpi", "50"]) == 0
    assert capsys.readouterr().out.strip() == str(Path.cwd() / "comparison.png")
    assert_nontrivial_png(tmp_path / "comparison.png")
    assert not (single_seed_run / "comparison.png").exists()
    runs = load_runs([single_seed_run, tiny_run])
    assert "different seed counts (1, 2)" in figures.wall_time_notes(runs)[0]
    out = tmp_path / "both.png"
    fig = plot.plot_runs([tiny_run, single_seed_run], out, ["a", "b"], dpi=50)
    # two seeds: the band is their range, and the title says so (not a confidence interval)
    assert fig.axes and "shaded range of 2 seeds" in fig._suptitle.get_text()
    assert "confidence interval" in figures.draw_figure([synthetic_run("x")])._suptitle.get_text()
    assert_nontrivial_png(out)
    before = sorted(tmp_path.iterdir())
    alone = plot.plot_runs([single_seed_run])  # a notebook's figure: no file written
    assert sorted(tmp_path.iterdir()) == before
    assert "1 seed: no confidence band" in alone._suptitle.get_text()
    labels = ["course-base", "course-linear"]  # the course's single-seed runs, side by side
    both = plot.plot_runs([single_seed_run, single_seed_run], tmp_path / "two.png", labels)
    assert "2 runs, 1 seed per run: no confidence band" in both._suptitle.get_text()
    with Image.open(out) as image:
        pixels = np.asarray(image.convert("RGB"), float)
    orange = (np.abs(pixels - [230, 159, 0]).sum(-1) < 30).sum()  # the second run's colour
    assert orange > 100


def synthetic_run(name: str, iterations: int = 200, seeds: int = 4, **fields) -> RunCurves:
    """A run in memory: returns rising to 500; an approx KL whose mean stays under 0.02
    while one seed's spikes stretch its bootstrap band far above that."""
    rng = np.random.default_rng(len(name))
    steps = np.arange(1, iterations + 1) * 2048.0
    rise = np.minimum(500.0, 20 + steps / 100)[:, None] + rng.uniform(-5, 0, (iterations, seeds))
    kl = rng.uniform(0.004, 0.012, (iterations, seeds))
    kl[::20, 0] = 0.06
    metrics = {
        figures.RETURN_METRIC: np.clip(rise, 0, 500),
        "train/approx_kl": kl,
        "train/clip_fraction": rng.uniform(0.0, 0.2, (iterations, seeds)),
        "train/entropy_loss": -rng.uniform(0.5, 0.6, (iterations, seeds)),
        "train/value_loss": rng.uniform(0, 50, (iterations, seeds)),
        "train/explained_variance": rng.uniform(-1, 1, (iterations, seeds)),
    }
    run = RunCurves(Path(name), name, metrics, steps, steps / 5000, seeds, None)
    return dataclasses.replace(run, **fields)


def panel(fig, title: str):
    (ax,) = [ax for ax in fig.axes if ax.get_title() == title]
    return ax


def test_curve_limits_fit_the_means_within_the_metric_range():
    curves = [np.array([np.nan, 0.001, 0.03]), np.array([0.02, 0.025])]
    low, high = figures.curve_limits(curves, (0.0, np.inf))
    assert low == 0.0  # 0.001 - 8% of 0.029 would be below zero: KL's range stops it
    assert high == pytest.approx(0.03 + 0.08 * 0.029)
    low, high = figures.curve_limits([np.array([0.01, 0.03])], (0.0, np.inf))
    assert (low, high) == pytest.approx((0.01 - 0.0016, 0.03 + 0.0016))
    low, high = figures.curve_limits([np.array([0.5, 1.0])], (-np.inf, 1.0))
    assert low == pytest.approx(0.46) and high == pytest.approx(1.04)  # at the edge: still room
    low, high = figures.curve_limits([np.zeros(5)])  # flat: a margin all the same
    assert low < 0 < high
    low, high = figures.curve_limits([np.full(3, -0.6)])
    assert low < -0.6 < high and high - low < 0.2
    assert figures.curve_limits([np.full(3, np.nan)]) is None
    assert figures.curve_limits([]) is None


def test_step_ticks_are_few_and_short():
    from matplotlib.figure import Figure

    fig = Figure(figsize=(4.3, 3))
    ax = fig.add_subplot()
    figures.step_axis(ax.xaxis)
    for right, expected in [
        (409_600, ["0", "100k", "200k", "300k", "400k"]),
        (2_000_896, ["0", "500k", "1M", "1.5M", "2M"]),
        (20_480, ["0", "5k", "10k", "15k", "20k"]),
    ]:
        ax.set_xlim(0, right)
        fig.draw_without_rendering()
        shown = [t for t in ax.get_xticklabels() if 0 <= t.get_position()[0] <= right]
        assert [t.get_text() for t in shown] == expected
    assert ax.xaxis.get_offset_text().get_text() == ""  # no "1e6" in the corner


def test_wrap_to_width_keeps_indentation_and_cuts_long_words():
    assert figures.wrap_to_width("ab cd ef", 5) == "ab cd\n  ef"
    assert figures.wrap_to_width("  one two three", 9) == "  one two\n    three"
    assert figures.wrap_to_width("abcdefghij", 4) == "abcd\n  ef\n  gh\n  ij"
    assert figures.wrap_to_width("short\n\n  x", 20) == "short\n\n  x"


def test_run_styles_differ_and_later_runs_draw_on_top():
    styles = figures.run_styles(30)
    pairs = [(s["color"], str(s["ls"])) for s in styles]
    assert len(set(pairs[:28])) == 28 and pairs[28] == pairs[0]
    assert all(a["color"] != b["color"] and a["ls"] != b["ls"] for a, b in zip(styles, styles[1:]))
    assert all(a["zorder"] < b["zorder"] for a, b in zip(styles, styles[1:]))
    # Two equal curves (the same settings run twice): the second is broken and drawn later.
    fig = figures.draw_figure([synthetic_run("x"), synthetic_run("x")])
    first, second = panel(fig, "approx KL").lines
    np.testing.assert_array_equal(first.get_ydata(), second.get_ydata())
    assert first.get_linestyle() == "-" and second.get_linestyle() != "-"
    assert second.get_zorder() > first.get_zorder()
    assert second.get_linewidth() < first.get_linewidth()


def test_the_periodic_evaluation_is_drawn_where_it_ran():
    run = synthetic_run("evaluated", iterations=30)
    evaluated = np.full((30, 4), np.nan)
    evaluated[9::10] = [[100.0, 200, 300, 400]]  # --eval-every 10
    run.metrics[figures.EVAL_METRIC] = evaluated
    fig = figures.draw_figure([run])
    ax = panel(fig, f"episode return vs env steps (dots: {figures.EVAL_METRIC})")
    (dots,) = [line for line in ax.lines if line.get_label() == figures.EVAL_METRIC]
    np.testing.assert_array_equal(dots.get_xdata(), run.env_steps[9::10])
    np.testing.assert_array_equal(dots.get_ydata(), [250.0] * 3)  # the mean over seeds
    assert panel(figures.draw_figure([synthetic_run("x")]), "episode return vs env steps")


def test_axes_fit_the_curves_and_bands_run_past_them():
    run = synthetic_run("spiky")
    fig = figures.draw_figure([run])
    ax = panel(fig, "approx KL")
    mean, _, high = mean_and_band(run.metrics["train/approx_kl"], (0.0, np.inf))
    assert np.nanmax(high) > 2 * np.nanmax(mean)  # the band reaches far above the curve
    pad = 0.08 * np.ptp(mean)
    assert ax.get_ylim() == pytest.approx((mean.min() - pad, mean.max() + pad))
    (band,) = ax.collections  # drawn whole, past the top, and clipped there by the axes
    assert band.get_clip_on() and band.get_paths()[0].vertices[:, 1].max() > ax.get_ylim()[1]
    assert panel(fig, "episode return vs env steps").get_ylim() == (0, 520)


@pytest.mark.slow
def test_notes_legend_and_ticks_stay_readable(tmp_path, no_warnings):
    note = "from the checkpoint at iteration 245/977: the run did not finish"
    runs = [synthetic_run("stopped-" + "x" * 80, note=note, iterations=245)]
    runs += [synthetic_run(f"run-{i}", seeds=1 + i % 3) for i in range(11)]
    fig = figures.draw_figure(runs)
    renderer = fig.canvas.get_renderer()
    figure_box = fig.bbox
    summary = fig.axes[-1]
    box = summary.get_window_extent(renderer)
    texts = summary.texts
    for text in texts:  # wrapped to the panel, none cut off by the panel or the figure
        extent = text.get_window_extent(renderer)
        assert box.x0 - 1 <= extent.x0 and extent.x1 <= box.x1 + 1, text.get_text()
        assert box.y0 - 1 <= extent.y0 and extent.y1 <= box.y1 + 1, text.get_text()
    first = "".join(texts[0].get_text().split())
    assert "".join(f"notevaluated:{note}".split()) in first and "x" * 80 in first
    assert "more run(s): see the legend" in texts[-1].get_text()  # 12 runs do not all fit
    # The wall-time notes sit under their panel, inside the figure, off the data.
    time_panel = panel(fig, "episode return vs wall time")
    (caption,) = [t for t in time_panel.texts if t.get_text().startswith("note:")]
    extent = caption.get_window_extent(renderer)
    panel_box = time_panel.get_window_extent(renderer)
    assert extent.y1 < panel_box.y0 and figure_box.y0 <= extent.y0
    assert panel_box.x0 - 1 <= extent.x0 and extent.x1 <= panel_box.x1 + 1
    # The legend is below every panel, inside the figure.
    (legend,) = fig.legends
    assert len(legend.get_texts()) == 12
    legend_box = legend.get_window_extent(renderer)
    assert legend_box.y1 < min(ax.get_window_extent(renderer).y0 for ax in fig.axes)
    assert figure_box.x0 <= legend_box.x0 and legend_box.x1 <= figure_box.x1
    assert figure_box.y0 <= legend_box.y0
    # Tick labels of the step axes do not run into each other.
    for ax in fig.axes[:-1]:
        labels = [t.get_window_extent(renderer) for t in ax.get_xticklabels() if t.get_text()]
        labels = [b for b in labels if box_inside(b, ax.get_window_extent(renderer))]
        assert all(a.x1 + 2 < b.x0 for a, b in zip(labels, labels[1:])), ax.get_title()


def box_inside(label, axes_box) -> bool:
    """A tick label under the axes (matplotlib keeps labels of ticks outside the limits)."""
    centre = (label.x0 + label.x1) / 2
    return axes_box.x0 - 1 <= centre <= axes_box.x1 + 1


@pytest.mark.slow
def test_a_comparison_never_overwrites_an_earlier_one(
    tiny_run, single_seed_run, tmp_path, monkeypatch, capsys
):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "comparison.png").write_bytes(b"an earlier comparison")
    for expected in ("comparison-2.png", "comparison-3.png"):
        assert plot.main([str(tiny_run), str(single_seed_run), "--dpi", "50"]) == 0
        captured = capsys.readouterr()
        assert captured.out.strip() == str(Path.cwd() / expected)  # the full path
        assert f"comparison.png exists and is kept: drew into {expected}" in captured.err
        assert_nontrivial_png(tmp_path / expected, min_size=(400, 300))
    assert (tmp_path / "comparison.png").read_bytes() == b"an earlier comparison"
    help_text = " ".join(plot.build_parser().format_help().split())
    assert "comparison-2.png" in help_text and "never overwritten" in help_text
    # --out names the file, and replaces it.
    out = tmp_path / "comparison.png"
    assert plot.main([str(tiny_run), str(single_seed_run), "--dpi", "50", "--out", str(out)]) == 0
    assert capsys.readouterr().err == ""
    assert_nontrivial_png(out, min_size=(400, 300))


def fake_sweep(tiny_run, out, rates=(0.001, 0.01)):
    """A sweep directory whose combinations are copies of ``tiny_run``."""
    out.mkdir()
    for c, rate in enumerate(rates):
        combo = out / f"combo-{c:03d}"
        shutil.copytree(tiny_run, combo)
        info = json.loads((combo / "config.json").read_text())
        info["combination"] = {"learning_rate": rate, "clip_coef": 0.2}
        (combo / "config.json").write_text(json.dumps(info))
        seal(combo)
    shutil.copy(tiny_run / "config.json", out / "config.json")
    (out / "sweep.json").write_text(json.dumps({"ranking": []}))
    seal(out)
    return out


def test_plot_expands_sweeps_into_labelled_combinations(tiny_run, tmp_path, monkeypatch):
    sweep = fake_sweep(tiny_run, tmp_path / "sweep")
    runs = load_runs([sweep])
    assert [r.label for r in runs] == [
        "learning_rate=0.001,clip_coef=0.2",
        "learning_rate=0.01,clip_coef=0.2",
    ]
    assert [r.path for r in runs] == [sweep / "combo-000", sweep / "combo-001"]
    assert "share its wall time" in figures.wall_time_notes(runs)[0]
    labelled = load_runs([tiny_run, sweep], labels=["base", "lr"])
    assert [r.label for r in labelled] == ["base", *(f"lr {r.label}" for r in runs)]
    # The same combinations from two sweeps are told apart by the sweep's name.
    other = fake_sweep(tiny_run, tmp_path / "other")
    both = [r.label for r in load_runs([sweep, other])]
    assert both[0] == "sweep/learning_rate=0.001,clip_coef=0.2"
    assert both[2] == "other/learning_rate=0.001,clip_coef=0.2"
    monkeypatch.chdir(tmp_path)
    assert plot.main([str(sweep), "--dpi", "50"]) == 0
    assert_nontrivial_png(sweep / "curves.png")  # one directory: drawn into it
    assert not (tmp_path / "comparison.png").exists()
    empty = tmp_path / "empty"
    empty.mkdir()
    shutil.copy(sweep / "config.json", empty)
    shutil.copy(sweep / "sweep.json", empty)
    seal(empty)
    with pytest.raises(RunDirError, match="without combination directories"):
        load_runs([empty])


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: "), err
    assert "Traceback" not in err
    return err


@pytest.mark.parametrize("module", [plot, evaluate])
def test_bad_paths_exit_2_with_one_line(module, tiny_run, tmp_path, capsys):
    assert module.main([str(tmp_path / "missing")]) == 2
    assert "is not a directory" in one_line_error(capsys)
    assert module.main([str(tmp_path)]) == 2
    assert "not a jaxcart run directory" in one_line_error(capsys)
    assert module.main([str(tiny_run / "config.json")]) == 2
    one_line_error(capsys)
    assert module.main([]) == 2
    one_line_error(capsys)


def test_plot_bad_options(tiny_run, tmp_path, capsys):
    assert plot.main([str(tiny_run), "--label", "a", "--label", "b"]) == 2
    assert "--label" in one_line_error(capsys)
    assert plot.main([str(tiny_run), "--out", str(tmp_path / "nope" / "x.png")]) == 2
    assert "does not exist" in one_line_error(capsys)
    assert plot.main([str(tiny_run), "--out", str(tmp_path / "x.jpg")]) == 2
    one_line_error(capsys)
    broken = tmp_path / "broken"
    broken.mkdir()
    shutil.copy(tiny_run / "config.json", broken)
    seal(broken)
    assert plot.main([str(broken)]) == 2
    assert "metrics.csv" in one_line_error(capsys)


def gif_frames(path) -> list[np.ndarray]:
    with Image.open(path) as image:
        assert image.format == "GIF"
        return [np.asarray(f.convert("RGB")) for f in ImageSequence.Iterator(image)]


def assert_shows_cart(frame: np.ndarray) -> None:
    """A black cart about 25x15 px (Gymnasium's 50x30 at scale 0.5) and a tan pole."""
    black = (frame.sum(-1) < 60)[40:]  # below the caption
    rows = np.nonzero(black.sum(1) >= 12)[0]  # the cart's rows (the track is 1 px, grey)
    assert 10 <= len(rows) <= 20, len(rows)
    assert rows.max() - rows.min() == len(rows) - 1  # one block
    pole = (np.abs(frame.astype(int) - [202, 152, 101]).sum(-1) < 40).sum()
    assert pole > 50


@pytest.mark.parametrize("backend", ["gymnasium", "pillow"])
def test_render_gif(backend, tmp_path):
    if backend == "gymnasium" and not render.pygame_available():
        pytest.skip("pygame is not installed")
    path = tmp_path / "balance.gif"
    result = render.render_gif(balancing_policy, path, seed=0, max_steps=100, backend=backend)
    assert result.path == path and result.steps == 100 and result.episode_return == 100.0
    assert result.backend == backend and result.frames == 51  # steps 0, 2, ..., 100
    frames = gif_frames(path)
    assert len(frames) == 51 and frames[0].shape == (200, 300, 3)
    for frame in frames[:: len(frames) // 5]:
        assert_shows_cart(frame)
    # The scene itself moves (the caption, which changes every frame, is left out).
    scene = [f[40:].astype(int) for f in frames]
    changed = [np.abs(a - b).sum() > 0 for a, b in zip(scene, scene[1:])]
    assert np.mean(changed) > 0.8, changed
    assert len({f.tobytes() for f in scene}) > 30
    assert path.stat().st_size < 200_000


def test_gymnasium_and_pillow_frames_agree():
    if not render.pygame_available():
        pytest.skip("pygame is not installed")
    gym = list(render.episode_frames(balancing_policy, 1, 10, backend="gymnasium"))
    own = list(render.episode_frames(balancing_policy, 1, 10, backend="pillow"))
    assert gym[-1][2] == own[-1][2] == 10.0
    for (a, _, _), (b, _, _) in zip(gym, own):
        differ = (np.abs(a.astype(int) - b).max(-1) > 60).sum()
        assert differ < 150  # only anti-aliased edges differ (~3,400 drawn pixels)


def test_render_gif_rejects_bad_options(tmp_path):
    with pytest.raises(ValueError, match="frame_skip"):
        render.render_gif(balancing_policy, tmp_path / "x.gif", frame_skip=0)
    with pytest.raises(FileNotFoundError):
        render.render_gif(balancing_policy, tmp_path / "no" / "x.gif")


def test_evaluate_cli_table_and_gif(tiny_run, tmp_path, capsys):
    gif = tmp_path / "seed1.gif"
    argv = [str(tiny_run), "--episodes", "3", "--gif", str(gif), "--seed-index", "1"]
    assert evaluate.main(argv) == 0
    captured = capsys.readouterr()
    lines = captured.out.splitlines()
    assert "3 episodes per seed" in lines[0]
    assert lines[1].split() == ["seed", "mean", "min", "solved"]
    rows = [line.split() for line in lines[3:5]]
    assert [r[0] for r in rows] == ["0", "1"]
    assert all(float(r[1]) >= float(r[2]) > 0 and r[3] in ("yes", "no") for r in rows)
    assert lines[5].startswith("solved ") and "/2 seed(s)" in lines[5]
    assert f"wrote {gif}: seed 1" in lines[6]
    frames = gif_frames(gif)
    assert len(frames) > 3
    assert_shows_cart(frames[0])


def test_evaluate_cli_bad_options(tiny_run, tmp_path, capsys):
    assert evaluate.main([str(tiny_run), "--episodes", "0"]) == 2
    assert "--episodes" in one_line_error(capsys)
    argv = [str(tiny_run), "--gif", str(tmp_path / "x.gif"), "--seed-index", "2"]
    assert evaluate.main(argv) == 2
    assert "--seed-index" in one_line_error(capsys)
    assert evaluate.main([str(tiny_run), "--gif", str(tmp_path / "nope" / "x.gif")]) == 2
    assert "does not exist" in one_line_error(capsys)

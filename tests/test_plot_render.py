"""Learning-curve plots (``python -m jaxcart.plot``), GIF rendering and the evaluate CLI."""

from __future__ import annotations

import csv
import json
import shutil

import numpy as np
import pytest
from helpers import tiny_args
from PIL import Image, ImageSequence

from jaxcart import evaluate, plot
from jaxcart.gym import render
from jaxcart.rundir.files import RunDirError
from jaxcart.rundir.runs import load_runs
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
    return out


def assert_nontrivial_png(path, min_size=(600, 400)):
    with Image.open(path) as image:
        assert image.format == "PNG"
        assert image.size[0] >= min_size[0] and image.size[1] >= min_size[1]
        pixels = np.asarray(image.convert("RGB"), float)
    assert pixels.std() > 10  # not blank
    assert len(np.unique(pixels.reshape(-1, 3), axis=0)) > 20  # curves, bands, text
    # Curves in matplotlib's first colours (C0 blue) are drawn.
    blue = (np.abs(pixels - [31, 119, 180]).sum(-1) < 30).sum()
    assert blue > 100


def test_mean_and_band_ignores_nan_needs_two_seeds_and_stays_in_range():
    values = np.array([[np.nan, np.nan], [1.0, 3.0], [2.0, np.nan], [5.0, 5.0]])
    mean, low, high = plot.mean_and_band(values)
    np.testing.assert_allclose(mean, [np.nan, 2.0, 2.0, 5.0])
    # Bootstrap of two seeds {1, 3}: resampled means 1, 2, 3 (P = 1/4, 1/2, 1/4), so the 95%
    # interval is [1, 3] (a Student-t interval would be 2 ± 12.7).
    np.testing.assert_allclose([low[1], high[1]], [1.0, 3.0])
    assert np.isnan(low[[0, 2]]).all() and np.isnan(high[[0, 2]]).all()
    np.testing.assert_allclose([low[3], high[3]], [5.0, 5.0])
    again = plot.mean_and_band(values)  # deterministic
    np.testing.assert_array_equal(np.nan_to_num(again[1]), np.nan_to_num(low))
    # A metric's range clips the band: explained variance <= 1, clip fraction in [0, 1].
    rng = np.random.default_rng(0)
    ev = np.stack([rng.uniform(-20, 1, 8), np.ones(8)])
    _, low, high = plot.mean_and_band(ev, plot.METRIC_BOUNDS["train/explained_variance"])
    assert (high <= 1).all() and low[0] < -5
    _, low, high = plot.mean_and_band(np.array([[0.5, 3.0]]), (0.0, 1.0))
    assert low[0] == 0.5 and high[0] == 1.0
    assert plot.METRIC_BOUNDS["rollout/ep_rew_mean"] == (0.0, 500.0)
    assert plot.METRIC_BOUNDS["train/approx_kl"][0] == 0.0


def test_plot_one_run_default_path(tiny_run, capsys):
    assert plot.main([str(tiny_run)]) == 0
    out = tiny_run / "curves.png"
    assert capsys.readouterr().out.strip() == str(out)
    assert_nontrivial_png(out, min_size=(1000, 700))


def test_plot_overlay_and_single_seed(tiny_run, single_seed_run, tmp_path, monkeypatch):
    # The single-seed run (no band, NaN returns at first) overlaid on the two-seed one; several
    # runs go to comparison.png in the current directory, not into a run directory.
    monkeypatch.chdir(tmp_path)
    assert plot.main([str(single_seed_run), str(tiny_run), "--dpi", "50"]) == 0
    assert_nontrivial_png(tmp_path / "comparison.png")
    assert not (single_seed_run / "comparison.png").exists()
    runs = load_runs([single_seed_run, tiny_run])
    assert "different seed counts (1, 2)" in plot.wall_time_notes(runs)[0]
    out = plot.plot_runs([tiny_run, single_seed_run], tmp_path / "both.png", ["a", "b"], dpi=50)
    assert out == tmp_path / "both.png"
    assert_nontrivial_png(out)
    with Image.open(out) as image:
        pixels = np.asarray(image.convert("RGB"), float)
    orange = (np.abs(pixels - [255, 127, 14]).sum(-1) < 30).sum()  # the second run (C1)
    assert orange > 100


def fake_sweep(tiny_run, out, rates=(0.001, 0.01)):
    """A sweep directory whose combinations are copies of ``tiny_run``."""
    out.mkdir()
    for c, rate in enumerate(rates):
        combo = out / f"combo-{c:03d}"
        shutil.copytree(tiny_run, combo)
        info = json.loads((combo / "config.json").read_text())
        info["combination"] = {"learning_rate": rate, "clip_coef": 0.2}
        (combo / "config.json").write_text(json.dumps(info))
    shutil.copy(tiny_run / "config.json", out / "config.json")
    (out / "sweep.json").write_text(json.dumps({"ranking": []}))
    return out


def test_plot_expands_sweeps_into_labelled_combinations(tiny_run, tmp_path, monkeypatch):
    sweep = fake_sweep(tiny_run, tmp_path / "sweep")
    runs = load_runs([sweep])
    assert [r.label for r in runs] == [
        "learning_rate=0.001,clip_coef=0.2",
        "learning_rate=0.01,clip_coef=0.2",
    ]
    assert [r.path for r in runs] == [sweep / "combo-000", sweep / "combo-001"]
    assert "share its wall time" in plot.wall_time_notes(runs)[0]
    labelled = load_runs([tiny_run, sweep], labels=["base", "lr"])
    assert [r.label for r in labelled] == ["base", *(f"lr {r.label}" for r in runs)]
    # The same combinations from two sweeps are told apart by the sweep's name.
    other = fake_sweep(tiny_run, tmp_path / "other")
    both = [r.label for r in load_runs([sweep, other])]
    assert both[0] == "sweep/learning_rate=0.001,clip_coef=0.2"
    assert both[2] == "other/learning_rate=0.001,clip_coef=0.2"
    monkeypatch.chdir(tmp_path)
    assert plot.main([str(sweep), "--dpi", "50"]) == 0
    assert_nontrivial_png(tmp_path / "comparison.png")
    empty = tmp_path / "empty"
    empty.mkdir()
    shutil.copy(sweep / "config.json", empty)
    shutil.copy(sweep / "sweep.json", empty)
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
    gym_frames, ret, _ = render.render_frames(balancing_policy, 1, 10, backend="gymnasium")
    own_frames, own_ret, _ = render.render_frames(balancing_policy, 1, 10, backend="pillow")
    assert ret == own_ret == 10.0
    for a, b in zip(gym_frames, own_frames):
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

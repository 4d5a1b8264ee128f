"""``python -m jaxcart.sb3``: SB3's log and weights as a jaxcart run directory.

The writer and the parameter mapping are checked without SB3 (made-up SB3 logs and weights in
SB3's layout); the command itself trains SB3 only where SB3 and PyTorch are installed.
"""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from jaxcart import evaluate, load_policy
from jaxcart import plot as plot_command
from jaxcart import sb3 as sb3_command
from jaxcart.core.config import PPOConfig
from jaxcart.engine.loop import METRIC_COLUMNS
from jaxcart.run import sb3
from jaxcart.run.greedy import evaluate_gymnasium, evaluate_params
from jaxcart.rundir import layout, reader
from jaxcart.rundir.policy import run_params


def fake_state_dict(rng: np.random.Generator, hidden=(64, 64)) -> dict[str, np.ndarray]:
    """Random weights under SB3 MlpPolicy's names and PyTorch's ``weight [out, in]``."""
    state = {}
    for body, head, out in (
        ("mlp_extractor.policy_net", "action_net", 2),
        ("mlp_extractor.value_net", "value_net", 1),
    ):
        sizes = (4, *hidden)
        for i in range(len(hidden)):
            state[f"{body}.{2 * i}.weight"] = rng.normal(0, 0.5, (sizes[i + 1], sizes[i]))
            state[f"{body}.{2 * i}.bias"] = rng.normal(0, 0.1, sizes[i + 1])
        state[f"{head}.weight"] = rng.normal(0, 0.5, (out, hidden[-1]))
        state[f"{head}.bias"] = rng.normal(0, 0.1, out)
    return {k: v.astype(np.float32) for k, v in state.items()}


def sb3_forward(state: dict[str, np.ndarray], obs: np.ndarray) -> int:
    """SB3's greedy action as PyTorch computes it: ``x @ weight.T + bias``, tanh between."""
    x = obs.astype(np.float32)
    for i in range(2):
        layer = f"mlp_extractor.policy_net.{2 * i}"
        x = np.tanh(x @ state[f"{layer}.weight"].T + state[f"{layer}.bias"])
    return int(np.argmax(x @ state["action_net.weight"].T + state["action_net.bias"]))


def fake_rows(iterations: int) -> list[dict]:
    """SB3's progress.csv: one row per rollout (train/* of the previous update), then the
    final dump with the last update's train/* only."""
    rows = []
    for i in range(iterations):
        row = {
            "time/total_timesteps": str(2048 * (i + 1)),
            "time/iterations": str(i + 1),
            "time/fps": "1000",
            "time/time_elapsed": str(2 * (i + 1)),
            "rollout/ep_rew_mean": str(20.0 + 10 * i),
            "rollout/ep_len_mean": str(20.0 + 10 * i),
        }
        if i > 0:
            row["train/approx_kl"] = str(0.01 * i)  # the update of iteration i - 1
        rows.append(row)
    rows.append({"train/approx_kl": str(0.01 * iterations)})
    return rows


def test_to_metrics_puts_each_update_on_its_own_iteration():
    metrics = sb3.to_metrics(fake_rows(3))
    assert set(metrics) == set(METRIC_COLUMNS)
    np.testing.assert_allclose(metrics["train/approx_kl"], [0.01, 0.02, 0.03])
    np.testing.assert_allclose(metrics["rollout/ep_rew_mean"], [20, 30, 40])
    np.testing.assert_allclose(metrics["time/elapsed"], [2, 4, 6])
    assert np.isnan(metrics["train/clip_fraction"]).all()  # SB3 logged none here


def test_writer_and_mapping_without_sb3(tmp_path, capsys):
    """A run directory from made-up SB3 results: jaxcart reads it, and the mapped actor acts
    as SB3's forward pass does, observation by observation and episode by episode."""
    rng = np.random.default_rng(0)
    states = [fake_state_dict(rng) for _ in range(2)]
    config = PPOConfig(total_timesteps=3 * 2048)
    results = [
        sb3.SeedResult(
            sb3.to_metrics(fake_rows(3)),
            sb3.sb3_params(state, config),
            evaluate_gymnasium(
                lambda obs, s=state: np.array([[sb3_forward(s, o) for o in obs[0]]]), 1, 3
            )[0],
            12.5,
        )
        for state in states
    ]
    out = tmp_path / "sb3-run"
    out.mkdir()
    sb3.write_run(out, config, results, first_seed=7)

    info = reader.read_run_config(out)
    assert info["framework"] == sb3.FRAMEWORK and info["num_seeds"] == 2 and info["seed"] == 7
    params = reader.load_params(out)  # checks names, shapes and dtypes against the config
    kernel = params["params"]["critic"]["out"]["kernel"]
    assert kernel.shape == (2, 64, 1)
    np.testing.assert_array_equal(kernel[1], states[1]["value_net.weight"].T)
    metrics = reader.read_metrics_csv(out / layout.METRICS_FILE)
    np.testing.assert_allclose(metrics["train/approx_kl"][:, 1], [0.01, 0.02, 0.03])

    observations = rng.normal(0, 1, (200, 4)).astype(np.float32)
    for s, state in enumerate(states):
        policy = load_policy(out, seed_index=s)
        assert [policy(o) for o in observations] == [sb3_forward(state, o) for o in observations]

    # jaxcart's evaluation of the mapped weights scores what SB3's forward pass scored
    evaluation = json.loads((out / layout.EVALUATION_FILE).read_text())
    assert [s["gymnasium_returns"] for s in evaluation["seeds"]] == [
        r.returns.tolist() for r in results
    ]
    np.testing.assert_array_equal(
        evaluate_params(run_params(out), 3), np.stack([r.returns for r in results])
    )
    assert evaluate.main([str(out), "--episodes", "3"]) == 0
    assert "solved 0/2 seed(s)" in capsys.readouterr().out


def test_without_sb3_one_line_names_the_install(monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(sb3.importlib.util, "find_spec", lambda name: None)
    assert sb3_command.main(["--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and sb3.TORCH_CPU_INSTALL in err and "jaxcart[sb3]" in err
    assert not (tmp_path / "x").exists()


@pytest.mark.slow
def test_sb3_trains_into_a_run_directory(tmp_path, capsys):
    pytest.importorskip("torch")
    pytest.importorskip("stable_baselines3")
    out = tmp_path / "sb3"
    assert sb3_command.main(["--total-timesteps", "2048", "--out", str(out)]) == 0
    assert "run directory" in capsys.readouterr().out
    assert reader.read_run_config(out)["framework"] == sb3.FRAMEWORK
    metrics = reader.read_metrics_csv(out / layout.METRICS_FILE)
    assert metrics["train/approx_kl"].shape == (1, 1)  # one rollout of 2048 steps, one seed
    assert np.isfinite(metrics["train/approx_kl"]).all()
    evaluation = json.loads((out / layout.EVALUATION_FILE).read_text())
    # the mapped weights act as SB3's model did: jaxcart's evaluation scores the same
    again = evaluate_params(run_params(out), 20)
    assert again[0].tolist() == evaluation["seeds"][0]["gymnasium_returns"]


def fake_train_seed(seed: int, total_timesteps: int, threads: int = 1, on_row=None):
    """A made-up SB3 seed, a function of its seed alone, whose log rows go to ``on_row``."""
    for row in [{}, *fake_rows(3)] if on_row is not None else []:
        on_row(row)
    rng = np.random.default_rng(seed)
    state = fake_state_dict(rng)
    config = PPOConfig(total_timesteps=total_timesteps)
    return sb3.SeedResult(
        sb3.to_metrics(fake_rows(3)),
        sb3.sb3_params(state, config),
        rng.integers(9, 500, sb3.NUM_EVAL_EPISODES).astype(float),
        1.5,
    )


@pytest.fixture
def fake_sb3(monkeypatch):
    monkeypatch.setattr(sb3, "check_available", lambda: None)
    monkeypatch.setattr(sb3, "train_seed", fake_train_seed)


def test_an_interrupted_run_keeps_its_finished_seeds_and_resumes(
    fake_sb3, monkeypatch, tmp_path, capsys
):
    """Ctrl-C after two of four seeds: one line names the resume command, the two seeds are
    kept, and the resumed run trains only the other two and equals an uninterrupted run."""
    argv = ["--num-seeds", "4", "--first-seed", "5", "--total-timesteps", "6144"]
    whole = tmp_path / "whole"
    assert sb3_command.main([*argv, "--out", str(whole)]) == 0
    assert sorted(p.name for p in whole.iterdir()) == sorted(
        [
            layout.CONFIG_FILE,
            layout.METRICS_FILE,
            layout.PARAMS_FILE,
            layout.EVALUATION_FILE,
            layout.MANIFEST_FILE,
        ]
    )

    trained = []

    def interrupted_after_two(seed, total, threads=1, on_row=None):
        if len(trained) == 2:
            raise KeyboardInterrupt
        trained.append(seed)
        return fake_train_seed(seed, total, threads, on_row)

    monkeypatch.setattr(sb3, "train_seed", interrupted_after_two)
    out = tmp_path / "cut"
    capsys.readouterr()
    assert sb3_command.main([*argv, "--out", str(out)]) == 130
    err = capsys.readouterr().err
    assert "2 finished seed(s) kept" in err and f"python -m jaxcart.sb3 --resume {out}" in err
    assert "Traceback" not in err
    assert not (out / layout.EVALUATION_FILE).exists()
    # plot and evaluate say what the directory is, and how to finish it
    for command in (evaluate.main, plot_command.main):
        assert command([str(out)]) == 2
        err = capsys.readouterr().err
        assert "interrupted python -m jaxcart.sb3 run (2 seed(s) kept)" in err, err
        assert f"python -m jaxcart.sb3 --resume {out}" in err

    again = []
    monkeypatch.setattr(
        sb3,
        "train_seed",
        lambda s, t, threads=1, on_row=None: again.append(s) or fake_train_seed(s, t),
    )
    assert sb3_command.main(["--resume", str(out)]) == 0
    assert "2 already kept" in capsys.readouterr().out
    assert trained == [5, 6] and again == [7, 8]
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in whole.iterdir())
    for name in (layout.METRICS_FILE, layout.PARAMS_FILE):
        assert (out / name).read_bytes() == (whole / name).read_bytes()
    evaluation = [json.loads((d / layout.EVALUATION_FILE).read_text()) for d in (out, whole)]
    for seeds in (e["seeds"] for e in evaluation):
        for s in seeds:
            s.pop("train_seconds")
    assert evaluation[0] == evaluation[1]


@pytest.mark.parametrize(
    "damage, message",
    [
        (lambda out: None, "a finished run"),
        (lambda out: (out / layout.EVALUATION_FILE).unlink() or None, "no plan"),
    ],
    ids=["finished", "not-sb3"],
)
def test_resume_refuses_what_is_not_an_unfinished_sb3_run(
    damage, message, fake_sb3, tmp_path, capsys
):
    out = tmp_path / "r"
    assert sb3_command.main(["--total-timesteps", "2048", "--out", str(out)]) == 0
    damage(out)
    capsys.readouterr()
    assert sb3_command.main(["--resume", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_resume_refuses_a_damaged_kept_seed_and_other_settings(
    fake_sb3, monkeypatch, tmp_path, capsys
):
    out = tmp_path / "r"
    monkeypatch.setattr(sb3, "write_run", lambda *a, **k: (_ for _ in ()).throw(KeyboardInterrupt))
    assert sb3_command.main(["--num-seeds", "2", "--out", str(out)]) == 130
    kept = layout.sb3_seed_file(out, 0)
    kept.write_bytes(kept.read_bytes()[:100])
    capsys.readouterr()
    assert sb3_command.main(["--resume", str(out)]) == 2
    assert "seed-0.npz" in capsys.readouterr().err
    assert sb3_command.main(["--resume", str(out), "--num-seeds", "3"]) == 2
    assert "drop --num-seeds" in capsys.readouterr().err


@pytest.mark.slow
def test_the_chapters_swanlab_comparison_shares_one_folder(fake_sb3, monkeypatch, tmp_path):
    """``python -m jaxcart.sb3 --logger swanlab`` and ``python -m jaxcart.train --logger
    swanlab`` both write into ./swanlog (the chapter's ``swanlab watch swanlog``), read back
    with SwanLab's own reader, under SB3's names."""
    pytest.importorskip("swanlab")
    from helpers import read_swanlog, tiny_args

    from jaxcart.train import main as train_main

    monkeypatch.chdir(tmp_path)  # SwanLab also reads ./.env and ./swanlab.yaml
    monkeypatch.delenv("SWANLAB_LOG_DIR", raising=False)
    monkeypatch.setenv("CI", "true")
    argv = ["--total-timesteps", "6144", "--out", "runs/sb3-torch", "--logger", "swanlab"]
    assert sb3_command.main(argv) == 0
    tiny = tiny_args(384, num_seeds=1)  # 3 iterations of 128 steps
    argv = [*tiny, "--out", "runs/jaxcart", "--logger", "swanlab", "--quiet"]
    assert train_main(argv) == 0

    logged = read_swanlog(tmp_path / "swanlog")
    assert set(logged) == {"sb3-torch", "jaxcart"}
    for name, batch, epochs in (("sb3-torch", 2048, 10), ("jaxcart", 128, 2)):
        scalars = logged[name]
        steps = [batch * i for i in (1, 2, 3)]
        for key in ("time/time_elapsed", "rollout/ep_rew_mean", "train/approx_kl"):
            assert [s for s, _ in scalars[key]] == steps, (name, key)
        assert [v for _, v in scalars["train/n_updates"]] == [epochs * i for i in (1, 2, 3)]
        np.testing.assert_allclose([v for _, v in scalars["train/clip_range"]], 0.2)
        assert "time/elapsed" not in scalars
    # SB3's own log, as the fake seed made it: time_elapsed 2, 4, 6 s
    assert [v for _, v in logged["sb3-torch"]["time/time_elapsed"]] == [2.0, 4.0, 6.0]


def watch_logger(monkeypatch, out, seen: list, read, rollouts: int = 3) -> None:
    """Wraps ``sb3.train_seed`` (in this process: ``--jobs 1``): right after SB3 writes the row
    of rollout ``rollouts``, waits (up to 60 s) for the logger's folder, as ``read()`` reads
    it, to hold the iterations before it, then appends what it holds to ``seen`` and whether
    the run directory was finished by then."""
    from test_loggers import wait_for_steps

    real = sb3.train_seed
    wanted = [2048 * i for i in range(1, rollouts)]

    def train_seed(seed, total, threads=1, on_row=None):
        count = 0

        def watched(row):
            nonlocal count
            on_row(row)
            count += bool(row.get("time/total_timesteps"))
            if count == rollouts and not seen:
                scalars = wait_for_steps(read, "train/approx_kl", wanted)
                seen.append((scalars, (out / layout.EVALUATION_FILE).exists()))

        return real(seed, total, threads, watched)

    monkeypatch.setattr(sb3, "train_seed", train_seed)


def tensorboard_reader(out):
    """Reads the TensorBoard files of the run's first seed (the writer may be mid-record)."""
    from helpers import read_tensorboard

    def read() -> dict:
        try:
            return read_tensorboard(out / "tensorboard" / "seed0")
        except (OSError, struct.error, ValueError):
            return {}

    return read


@pytest.mark.slow  # about 30 s with TensorBoard and a made-up SB3
@pytest.mark.parametrize("real", [False, True], ids=["fake-sb3", "real-sb3"])
@pytest.mark.parametrize("logger", ["tensorboard", "swanlab"])
def test_sb3s_curves_reach_the_logger_while_it_trains(logger, real, monkeypatch, tmp_path, capsys):
    """After SB3's third rollout, the logger's folder (TensorBoard's, or SwanLab's records file:
    issue 40) already holds the first two iterations (their rollout and their update), and a
    progress bar counts the seed's env steps."""
    if logger == "tensorboard":
        pytest.importorskip("tensorboardX")
        read = tensorboard_reader(tmp_path / "live")
    else:
        pytest.importorskip("swanlab.sdk.internal.core_python.store")  # before training
        from test_loggers import read_live_swanlog

        monkeypatch.chdir(tmp_path)
        monkeypatch.setenv("CI", "true")
        monkeypatch.delenv("SWANLAB_LOG_DIR", raising=False)
        read = lambda: read_live_swanlog(tmp_path / "swanlog")
    if real:
        pytest.importorskip("torch")
        pytest.importorskip("stable_baselines3")
    else:
        monkeypatch.setattr(sb3, "check_available", lambda: None)
        monkeypatch.setattr(sb3, "train_seed", fake_train_seed)
    out, seen = tmp_path / "live", []
    watch_logger(monkeypatch, out, seen, read)
    argv = ["--total-timesteps", str(4 * 2048), "--out", str(out), "--logger", logger]
    assert sb3_command.main(argv) == 0
    (scalars, finished), *_ = seen
    assert not finished
    for key in ("rollout/ep_rew_mean", "train/approx_kl", "time/time_elapsed", "train/n_updates"):
        assert [s for s, _ in scalars[key]] == [2048, 4096], key
    assert [v for _, v in scalars["train/n_updates"]] == [10, 20]
    if not real:  # the made-up log's values
        np.testing.assert_allclose([v for _, v in scalars["train/approx_kl"]], [0.01, 0.02])
    err = capsys.readouterr().err
    assert "seed 0:" in err and f"/{4 * 2048}" in err and "step/s" in err


def test_swanlab_folder_from_logger_dir_then_the_environment(fake_sb3, monkeypatch, tmp_path):
    pytest.importorskip("swanlab")
    from helpers import read_swanlog

    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("CI", "true")
    monkeypatch.setenv("SWANLAB_LOG_DIR", str(tmp_path / "from-env"))
    base = ["--total-timesteps", "2048", "--logger", "swanlab"]
    assert sb3_command.main([*base, "--out", "runs/a"]) == 0
    assert sb3_command.main([*base, "--out", "runs/b", "--logger-dir", "chosen"]) == 0
    assert set(read_swanlog(tmp_path / "from-env")) == {"a"}
    assert set(read_swanlog(tmp_path / "chosen")) == {"b"}
    assert not (tmp_path / "swanlog").exists()

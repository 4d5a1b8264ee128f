"""Transfer studies: ``python -m jaxcart.evaluate --out`` writes an evaluation on other physics
(``--env-param``) or at each value of one field (``--sweep``, with ``robustness.png``), which
``python -m jaxcart.compare`` reads like a run, with the numbers evaluate printed; bad
options are one line and exit 2."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import seal, tiny_args
from PIL import Image

from jaxcart import compare, evaluate, plot
from jaxcart.rundir import layout, reader
from jaxcart.train import main as train_main


@pytest.fixture(scope="module")
def arms(tmp_path_factory) -> tuple[Path, Path]:
    """Two 3-seed runs of CartPole-v1, learning rates 1e-3 and 3e-2 (one sweep: one program),
    short enough that their seeds score apart."""
    sweep = tmp_path_factory.mktemp("transfer") / "sweep"
    argv = [*tiny_args(2048, num_seeds=3), "--no-compile-cache", "--out", str(sweep)]
    assert train_main([*argv, "--sweep", "learning_rate=1e-3,3e-2"]) == 0
    return layout.combo_dir(sweep, 0), layout.combo_dir(sweep, 1)


def printed_rows(text: str, header: str) -> list[list[str]]:
    """The rows of the table under the line that starts with ``header``, with the columns of
    the tables that continue it (``cli.format_table`` moves columns that would make a line too
    wide, as a long run path does, into further tables that repeat the first column)."""
    lines = text.splitlines()
    first = header.split()[:1]
    start = next(i for i, line in enumerate(lines) if line.split()[:1] == first)
    rows: list[list[str]] | None = None
    while start < len(lines) and lines[start].split()[:1] == first:
        table, end = [], start + 2
        while end < len(lines) and (lines[end].startswith((" ", "/")) or lines[end][:1].isdigit()):
            table.append(lines[end].split())
            end += 1
        if rows is None:
            rows = table
        elif [t[0] for t in table] == [r[0] for r in rows]:
            rows = [r + t[1:] for r, t in zip(rows, table)]
        else:
            break
        start = end + (end < len(lines) and not lines[end].strip())  # one blank line between
    return rows or []


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: "), err
    return err


def test_an_evaluation_reads_back_in_compare_with_the_printed_numbers(arms, tmp_path, capsys):
    run = arms[0]
    out = tmp_path / "long"
    argv = [str(run), "--episodes", "3", "--env-param", "length=1", "--out", str(out)]
    assert evaluate.main(argv) == 0
    text = capsys.readouterr().out
    assert "with length=1" in text and f"wrote {out}; compare:" in text
    means = [float(row[1]) for row in printed_rows(text, "seed")]
    assert len(means) == 3
    # a run directory without training: config.json, evaluation.json, both in its manifest
    info = json.loads((out / layout.CONFIG_FILE).read_text())
    assert info["env_params"] == {"length": 1.0} and info["eval_episodes"] == 3
    assert info[layout.EVALUATION_OF_KEY]["run"] == str(run)
    listed = json.loads((out / layout.MANIFEST_FILE).read_text())["files"]
    assert sorted(listed) == [layout.CONFIG_FILE, layout.EVALUATION_FILE]

    # the transfer against the run's own (nominal) evaluation
    cmp = tmp_path / "cmp"
    assert compare.main([str(run), str(out), "--out", str(cmp)]) == 0
    text = capsys.readouterr().out.replace("\n  ", " ")
    assert "long (length=1): an evaluation of a trained run" in text
    data = json.loads((cmp / "compare.json").read_text())
    assert data["runs"][1]["name"] == "long (length=1)"
    assert data["runs"][1]["scores"] == pytest.approx(means, abs=0.05)
    assert data["runs"][1]["evaluation_episodes"] == 3

    # the reader checks it as it checks a run: edited bytes are refused
    evaluation = out / layout.EVALUATION_FILE
    evaluation.write_text(evaluation.read_text().replace('"episodes": 3', '"episodes": 3 '))
    assert compare.main([str(out), "--out", str(tmp_path / "edited")]) == 2
    assert "is not the file the run wrote" in one_line_error(capsys)


def test_a_physics_sweep_of_two_runs_draws_one_figure_and_compares_per_value(
    arms, tmp_path, capsys, no_warnings
):
    out = tmp_path / "robust"
    argv = [*map(str, arms), "--sweep", "env.length=0.25,0.5,1", "--episodes", "3"]
    assert evaluate.main([*argv, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    rows = printed_rows(text, "run")
    assert [(Path(r[0]).name, r[1]) for r in rows] == [
        (arm.name, value) for arm in arms for value in ("0.25", "0.5", "1")
    ]
    printed = [[float(x.strip("[],")) for x in r[3:6]] for r in rows]  # IQM [low, high]
    with Image.open(out / layout.ROBUSTNESS_FIGURE_FILE) as image:
        assert image.format == "PNG" and image.size[0] > 600

    # one sweep of evaluations per run, in the run's name: its combinations are the values
    first, second = (out / arm.name for arm in arms)
    ranking = json.loads((first / layout.SWEEP_FILE).read_text())
    assert ranking["sweep"] == {"env.length": [0.25, 0.5, 1.0]}
    combo = json.loads((layout.combo_dir(first, 2) / layout.CONFIG_FILE).read_text())
    assert combo["combination"] == {"env.length": 1.0} and combo["env_params"] == {"length": 1.0}

    # compare pairs the arms value by value, with the intervals evaluate printed
    cmp = tmp_path / "cmp"
    arm_options = ["--arm", f"low={first}", "--arm", f"high={second}"]
    assert compare.main([*arm_options, "--out", str(cmp)]) == 0
    data = json.loads((cmp / "compare.json").read_text())
    assert [r["name"].split("/")[1] for r in data["runs"]] == [
        f"env.length={value}" for _ in arms for value in ("0.25", "0.5", "1")
    ]
    for r, (value, low, high) in zip(data["runs"], printed):
        assert [r["iqm"][k] for k in ("value", "ci_low", "ci_high")] == pytest.approx(
            [value, low, high], abs=0.05
        )
    assert [r["iqm"] for r in data["runs"][:3]] == [p["iqm"] for p in ranking["values"]]
    assert data["runs"][4]["reference"] == data["runs"][1]["name"]  # same length, other arm
    assert [a["name"] for a in data["arms"]] == ["low", "high"]

    one = tmp_path / "one"  # one run: the output is its sweep, the figure inside
    assert evaluate.main([str(arms[0]), "--sweep", "env.masspole=0.1,0.2", "--out", str(one)]) == 0
    assert (one / layout.ROBUSTNESS_FIGURE_FILE).is_file() and reader.is_sweep(one)
    assert compare.main([str(one), "--out", str(tmp_path / "cmp-one")]) == 0


def test_bad_transfer_options_are_one_line_and_exit_2(arms, tmp_path, capsys):
    run = str(arms[0])
    evaluation = tmp_path / "evaluation"
    assert evaluate.main([run, "--episodes", "2", "--out", str(evaluation)]) == 0
    capsys.readouterr()
    new = str(tmp_path / "new")
    cases = [
        ([run, "--env-param", "length=-1", "--out", new], "env param length must be > 0"),
        ([run, "--env-param", "wheels=4", "--out", new], "CartPole has no env param 'wheels'"),
        ([run, "--sweep", "env.wheels=1,2", "--out", new], "CartPole has no env param 'wheels'"),
        ([run, "--sweep", "env.length=1,-2", "--out", new], "env param length must be > 0"),
        ([run, "--sweep", "length=1,2"], "one field: env.NAME=V1,V2"),
        ([run, "--sweep", "env.length=1", "--env-param", "length=2"], "both swept and set"),
        ([run, "--out", str(evaluation)], f"--out {evaluation} exists"),
        ([str(arms[0].parent), "--out", new], "is a sweep: --sweep and --out evaluate one run"),
        ([str(evaluation)], f"is an evaluation of {run}"),
    ]
    for argv, message in cases:
        assert evaluate.main(argv) == 2, argv
        assert message in one_line_error(capsys), argv
    assert not Path(new).exists()
    assert plot.main([str(evaluation), "--out", str(tmp_path / "p.png")]) == 2
    assert "no learning curves to plot" in one_line_error(capsys)


def test_a_physics_sweep_of_another_env_is_refused(arms, tmp_path, capsys):
    pytest.importorskip("gymnax")
    acrobot = tmp_path / "acrobot"  # the run's config.json, naming Acrobot-v1
    acrobot.mkdir()
    info = json.loads((arms[0] / layout.CONFIG_FILE).read_text())
    info["config"]["env"] = "Acrobot-v1"
    (acrobot / layout.CONFIG_FILE).write_text(json.dumps(info))
    seal(acrobot)
    new = tmp_path / "new"
    assert evaluate.main([str(acrobot), "--sweep", "env.length=1,2", "--out", str(new)]) == 2
    assert f"--sweep sets CartPole's physics; {acrobot} trained Acrobot-v1" in one_line_error(
        capsys
    )
    assert not new.exists()


def test_evaluate_help_imports_no_jax():
    """``python -m jaxcart.evaluate --help`` answers without importing JAX (start-up time);
    the command imports it once its options are read."""
    code = (
        "import sys\n"
        "from jaxcart import evaluate\n"
        "code = evaluate.main(['--help'])\n"
        "print(code, 'jax' in sys.modules)\n"
        "evaluate.main(['--episodes', '0', 'no-such-run'])\n"
        "print('jax' in sys.modules)"
    )
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).parents[1])}
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True
    ).stdout
    assert out.splitlines()[-2:] == ["0 False", "False"]

"""``python -m benchmarks.train_speed``'s contender names and seed counts (``--time-to-solve``,
``--seeds-for``) and its time-to-solve table, on made-up results: nothing is trained or timed."""

from __future__ import annotations

import importlib

import pytest


@pytest.fixture(scope="module")
def ts():
    # The command's module is the package's __main__ (importing it runs nothing).
    return importlib.import_module("benchmarks.train_speed.__main__")


def names(ts, argv: list[str]) -> list[str]:
    return ts.contender_names(ts.seeds_by_group(ts.build_parser().parse_args(argv)))


def test_default_contenders_are_unchanged(ts):
    assert names(ts, []) == [
        "sb3",
        "sb3-1thread",
        *(f"jaxcart-sb3-x{s}" for s in (1, 8, 64)),
        *(f"jaxcart-fast-x{s}" for s in (1, 8)),
        *(f"rejax-sb3-x{s}" for s in (1, 8, 64)),
    ]


def test_time_to_solve_runs_one_process_per_seed_tools_at_64_only_with_slow(ts):
    fast = names(ts, ["--time-to-solve"])
    assert "jaxcart-purejaxrl-x64" in fast and "rejax-cartpole-x64" in fast
    assert "sbx-zoo-x1" in fast and "sb3-zoo-x1" in fast
    assert not [n for n in fast if n.startswith(("sb3", "sbx")) and n.endswith("-x64")]
    slow = names(ts, ["--time-to-solve", "--slow"])
    assert {"sb3-default-x64", "sb3-zoo-x64", "sbx-default-x64", "sbx-zoo-x64"} <= set(slow)
    # SB3's one-seed rows are the table's reference: there even when only N = 64 is asked for
    only64 = names(ts, ["--time-to-solve", "--seeds", "64"])
    assert {"sb3", "sb3-1thread", "jaxcart-fast-x64"} <= set(only64)
    assert "jaxcart-fast-x1" not in only64


def test_seeds_for_sets_a_group_or_a_tool(ts):
    picked = names(ts, ["--seeds-for", "sbx=1,4", "--seeds-for", "jaxcart-fast=2"])
    assert {"sbx-default-x4", "sbx-zoo-x1", "jaxcart-fast-x2"} <= set(picked)
    assert "jaxcart-fast-x1" not in picked
    for bad in ("nope=1", "sbx", "sb3-1thread=2", "sbx=0"):
        with pytest.raises(SystemExit):
            ts.build_parser().parse_args(["--seeds-for", bad])


def made_up_row(ts, name: str, wall: float, seeds: int = 1, **extra) -> dict:
    row = {
        "contender": name,
        "warm_cache": False,
        "status": "ok",
        "num_seeds": seeds,
        "env_steps": 1000 * seeds,
        "compile_seconds": 0.0 if name.startswith("sb3") else 2.0,
        "setup_seconds": 2.0,
        "train_seconds": wall - 4.0,
        "train_cpu_seconds": wall - 4.0,
        "process_wall_seconds": wall,
        "peak_rss_mib": 500.0,
        "process_cpu_seconds": wall,
        "process_cpu_ratio": 1.0,
        "eval_seconds": 0.5,
        "eval_mean": [500.0] * seeds,
        "solved": seeds,
    }
    row.update(extra)
    ts.add_rates(row)
    return row


def test_time_to_solve_table(ts):
    sbx = {"compile_seconds": None, "jobs": 2, "processes_peak_rss_mib": 1500.0}
    results = [
        made_up_row(ts, "sb3", 60.0),
        made_up_row(ts, "sb3-1thread", 50.0),
        made_up_row(ts, "jaxcart-fast-x64", 25.0, 64),
        made_up_row(ts, "sbx-zoo-x64", 400.0, 64, **sbx),
        made_up_row(ts, "jaxcart-fast-x1", 5.0),
    ]
    settings = {"quick": False, "time_to_solve": True, "slow": True, "warm_cache": False}
    settings |= {"rejax_python": "r", "sbx_python": "s"}
    report = {"settings": settings, "results": results, "command": "c", "load_average_end": None}
    report["machine"] = ts.lib.machine_info()
    text = ts.markdown(report)
    table = text[text.index("## Time to solve") : text.index("## Training speed")]
    lines = [line for line in table.splitlines() if line.startswith("| ")][2:]
    assert [line.split(" | ")[2] for line in lines] == ["1", "1", "1", "64", "64"]
    cells = [line.strip("| ").split(" | ") for line in lines]
    ratios = {(c[1].split(",")[0], c[2]): c[-1] for c in cells}
    # SB3's reference is its faster one-seed row, 50 s
    assert ratios[("`fast` preset", "1")] == "10x"
    assert ratios[("`fast` preset", "64")] == "2.0x"
    assert sorted(c[-1] for c in cells if c[0] == "SB3 (PyTorch)") == ["0.83x", "1.0x"]
    sbx_line = next(line for line in lines if line.startswith("| sbx"))
    assert "| in training |" in sbx_line and "1,500†" in sbx_line and "2 at a time" in sbx_line
    assert sbx_line.endswith("| 0.12x |")


def test_acrobot_contenders_run_only_when_named(ts):
    only = "jaxcart-acrobot,rejax-acrobot"
    argv = ["--only", only, "--seeds", "64"]
    for mode in ([], ["--time-to-solve"]):
        assert ts.selected(names(ts, mode + argv), only) == [
            "jaxcart-acrobot-x64",
            "rejax-acrobot-x64",
        ]
    # a tool's name and its seed counts stand for its CartPole groups only
    assert not [n for n in names(ts, ["--only", "jaxcart"]) if "acrobot" in n]
    assert not [n for n in names(ts, ["--seeds-for", "rejax=1"]) if "acrobot" in n]
    assert not [n for n in names(ts, ["--time-to-solve"]) if "acrobot" in n]
    assert ts.env_of("rejax-acrobot-x64") == "Acrobot-v1"
    assert ts.env_of("rejax-cartpole-x64") == "CartPole-v1"


def test_acrobot_rows_compare_with_rejax_on_acrobot_not_with_sb3(ts):
    acrobot = {"env_id": "Acrobot-v1", "eval_mean": [-80.0] * 64}
    results = [
        made_up_row(ts, "sb3", 60.0),
        made_up_row(ts, "jaxcart-acrobot-x64", 30.0, 64, **acrobot),
        made_up_row(ts, "rejax-acrobot-x64", 60.0, 64, **acrobot),
    ]
    settings = {"quick": False, "time_to_solve": True, "slow": False, "warm_cache": False}
    settings |= {"rejax_python": "r", "sbx_python": "s"}
    report = {"settings": settings, "results": results, "command": "c", "load_average_end": None}
    report["machine"] = ts.lib.machine_info()
    text = ts.markdown(report)
    assert text.startswith("# PPO time to solve on CartPole-v1 and Acrobot-v1")
    table = text[text.index("## Time to solve") : text.index("## Training speed")]
    lines = [line for line in table.splitlines() if line.startswith("| ")][2:]
    assert [line.split(" | ")[0] for line in lines] == ["| SB3 (PyTorch)", "| jaxcart", "| rejax"]
    assert [line.endswith("| - |") for line in lines] == [False, True, True]
    # the speed-up table's row (the last of the two): no SB3 ratios, and rejax's Acrobot row
    # at the same seeds as the reference (setup + train 58 s against 28 s)
    ratio = [line for line in text.splitlines() if line.startswith("| jaxcart acrobot x64")][-1]
    assert ratio.split(" | ")[1:5] == ["-", "-", "-", ts.lib.format_ratio(58 / 28)]


def test_a_step_budget_goes_to_jaxcart_and_rejax_only(ts, tmp_path):
    """``--timesteps N``: one point of the time-to-solve curve; other tools are refused before
    anything runs, and the budget reaches the children's command line."""
    argv = ["--only", "sb3", "--timesteps", "1000", "--out", str(tmp_path)]
    with pytest.raises(SystemExit, match="--timesteps sets jaxcart and rejax contenders only"):
        ts.main(argv)
    args = ts.build_parser().parse_args(["--timesteps", "51200"])
    assert args.timesteps == 51200


def test_the_budget_curve_reads_every_budgets_rows(tmp_path):
    """``benchmarks.train_speed.budgets``: one point per contender and budget, by env steps."""
    import json

    from benchmarks.train_speed import budgets

    def row(name: str, steps: int, wall: float, solved: int) -> dict:
        return {
            "contender": name, "status": "ok", "env_steps": 64 * steps, "num_seeds": 64,
            "process_wall_seconds": wall, "compile_seconds": 10.0, "train_seconds": wall / 2,
            "solved": solved, "env_id": "Acrobot-v1",
        }  # fmt: skip

    for budget, (wall, solved) in {102400: (43.0, 59), 51200: (50.0, 16)}.items():
        (tmp_path / str(budget)).mkdir()
        rows = [row("jaxcart-acrobot-x64", budget, wall, solved), {"status": "failed"}]
        path = tmp_path / str(budget) / f"{budgets.TIME_TO_SOLVE_STEM}.json"
        path.write_text(json.dumps({"results": rows}))
    points = budgets.read_points([tmp_path / "102400", tmp_path / "51200"])
    assert [r["solved"] for r in points["jaxcart-acrobot"]] == [16, 59]  # by env steps
    assert "| jaxcart | 51,200 | 50.0 | 10.0 | 25.0 | 16/64 |" in budgets.table(points)
    budgets.draw(points, tmp_path / "curve.png")
    assert (tmp_path / "curve.png").stat().st_size > 0

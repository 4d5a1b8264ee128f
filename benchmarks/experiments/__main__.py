"""The course's CartPole claims as experiments: each one trains its arms with 64 seeds (from a
base seed used nowhere else in the project) and compares them with ``python -m
jaxcart.compare``, writing ``<out>/<name>/`` (compare.json, compare.png and the table).
``--out`` defaults to the ignored ``benchmarks/results/scratch/experiments``; the committed
figures are ``--out docs/experiments``, and ``docs/experiments.md`` holds the conclusions.

    python -m benchmarks.experiments --out docs/experiments    # every experiment available
    python -m benchmarks.experiments --only activation         # one of them
    python -m benchmarks.experiments --seeds 8 --runs runs/exp8  # a quick look

Every arm is ``python -m jaxcart.train`` with the options below, so a figure can be redone
by hand. Runs already present in ``--runs`` are reused (delete them to retrain).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

from benchmarks import lib
from jaxcart.rundir.reader import load_run

ROOT = lib.REPO_ROOT
BASE_SEED = 314159  # unseen: not used by tests, presets, benchmarks or the README
# An arm trained by Stable-Baselines3 itself (benchmarks.experiments.sb3_reference, PyTorch, in
# the benchmark venv) instead of by ``python -m jaxcart.train``.
SB3_TORCH = ["<stable-baselines3 (torch) via python -m benchmarks.experiments.sb3_reference>"]
SB3_PYTHON = ROOT / "benchmarks" / ".venv-bench" / "bin" / "python"

EXPERIMENTS: dict[str, dict[str, list[str]]] = {
    # 1. Treating the 500-step truncation as termination ("learns that 500 steps is bad").
    "truncation-sb3": {
        "sb3": ["--preset", "sb3"],
        "sb3-no-bootstrap": ["--preset", "sb3", "--no-bootstrap-truncation"],
    },
    "truncation-purejaxrl": {
        "purejaxrl-bootstrap": ["--preset", "purejaxrl"],
        "purejaxrl-no-bootstrap": ["--preset", "purejaxrl", "--no-bootstrap-truncation"],
    },
    # 2. The chapter's from-scratch PPO uses ReLU; SB3 uses tanh.
    "activation": {
        "sb3": ["--preset", "sb3"],  # the same run as truncation-sb3's baseline
        "sb3-relu": ["--preset", "sb3", "--activation", "relu"],
    },
    # 3. "A linear policy softmax(Ws + b) can work on CartPole."
    "linear-policy": {
        "sb3": ["--preset", "sb3"],
        "sb3-linear-actor": ["--preset", "sb3", "--linear-actor"],
    },
    # 4. Orthogonal initialisation with a 0.01 policy head against the default initialisation.
    "initialisation": {
        "sb3": ["--preset", "sb3"],  # orthogonal, 0.01 policy head
        "sb3-default-init": ["--preset", "sb3", "--weight-init", "default"],
    },
    # 5. Stable-Baselines3 itself (baseline) against jaxcart's sb3 preset, same hyperparameters.
    "sb3-torch": {
        "sb3-torch": SB3_TORCH,
        "sb3": ["--preset", "sb3"],
    },
}


def train(name: str, options: list[str], seeds: int, runs: Path, jobs: int = 2) -> Path:
    """Trains one arm (or reuses a finished one) and returns its run directory."""
    out = runs / name
    if (out / "evaluation.json").exists():
        print(f"{name}: reusing {out}", flush=True)
        return out
    if options is SB3_TORCH:
        if not SB3_PYTHON.exists():
            raise SystemExit(f"{name} needs {SB3_PYTHON}: run bash benchmarks/setup_venvs.sh")
        command = lib.module_command("benchmarks.experiments.sb3_reference", SB3_PYTHON)
        command += ["--num-seeds", str(seeds)]
        command += ["--first-seed", str(BASE_SEED), "--jobs", str(jobs), "--out", str(out)]
        print(" ".join(command), flush=True)
        subprocess.run(command, check=True, cwd=ROOT)
        return out
    command = [sys.executable, "-m", "jaxcart.train", *options, "--num-seeds", str(seeds)]
    command += ["--seed", str(BASE_SEED), "--quiet", "--out", str(out)]
    print(" ".join(command[1:]), flush=True)
    subprocess.run(command, check=True, cwd=ROOT)
    return out


def _relative(path: Path) -> str:
    """``path`` relative to the repository when it is inside it (for portable outputs)."""
    path = path.resolve()
    return str(path.relative_to(ROOT)) if ROOT in path.parents else str(path)


def training_return_table(arms: list[Path]) -> str:
    """The training return (``rollout/ep_rew_mean``) at half, three quarters and all of the
    shortest run's env steps: its IQM across seeds with a 95% bootstrap interval, and P(arm >
    the first arm) over seed pairs with its interval (``jaxcart.analysis``, the statistics of
    ``jaxcart.compare``). Each seed's value is read with ``summary.return_at``: at the first
    iteration at or past those steps, a seed with no value there (not yet, or diverged)
    counting as the env's worst return (0 on CartPole)."""
    from jaxcart.analysis import stats, summary

    runs = [load_run(a) for a in arms]
    shortest = min(runs, key=lambda r: r.env_steps[-1])
    n = len(shortest.env_steps)
    budgets = [float(shortest.env_steps[i]) for i in (n // 2 - 1, (3 * n) // 4 - 1, n - 1)]
    values = [
        [
            summary.return_at(r.metrics[summary.RETURN_METRIC], r.env_steps, b, r.env)
            for b in budgets
        ]
        for r in runs
    ]
    steps = " / ".join(f"{b / 1e3:,.0f}k" for b in budgets)
    lines = [f"training return at {steps} env steps: IQM [95% CI]; P(> {arms[0].name}) [95% CI]"]
    for k, arm in enumerate(arms):
        cells = []
        for i in range(len(budgets)):
            e = stats.bootstrap_ci(values[k][i], stats.iqm)
            cell = f"{e.value:.1f} [{e.ci_low:.1f}, {e.ci_high:.1f}]"
            if k:
                p = stats.probability_of_improvement_ci(values[k][i], values[0][i])
                cell += f"; P {p.value:.2f} [{p.ci_low:.2f}, {p.ci_high:.2f}]"
            cells.append(cell)
        lines.append(f"  {arm.name}: " + " / ".join(cells))
    return "\n".join(lines) + "\n"


def compare(arms: list[Path], out: Path, score: str = "eval") -> str:
    """``python -m jaxcart.compare --score SCORE`` on the arms (the first is the baseline) and
    the training return table; writes and returns both."""
    paths = [_relative(a) for a in arms]
    command = [sys.executable, "-m", "jaxcart.compare", *paths, "--score", score]
    command += ["--out", _relative(out)]
    done = subprocess.run(command, check=True, cwd=ROOT, capture_output=True, text=True)
    text = done.stdout + "\n" + training_return_table(arms)
    (out / "table.txt").write_text(text)
    return text


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=lib.program_name(), description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", default=",".join(EXPERIMENTS), help="comma-separated names")
    parser.add_argument("--seeds", type=int, default=64)
    parser.add_argument(
        "--jobs", type=int, default=2, help="Stable-Baselines3 seeds trained at once (per core)"
    )
    parser.add_argument("--runs", type=Path, default=ROOT / "runs" / "experiments")
    parser.add_argument(
        "--out",
        type=Path,
        default=lib.SCRATCH_DIR / "experiments",
        help="where each experiment's comparison goes (default benchmarks/results/scratch/"
        "experiments, not committed; --out docs/experiments replaces the committed ones)",
    )
    parser.add_argument(
        "--score",
        default="eval",
        help="each seed's score in the comparison: eval, auc or return-at:STEPS "
        "(python -m jaxcart.compare --score; default eval)",
    )
    args = parser.parse_args(argv)
    lib.output_dir(args.out)
    names = [n for n in args.only.split(",") if n]
    unknown = sorted(set(names) - set(EXPERIMENTS))
    if unknown:
        parser.error(f"unknown experiment(s) {unknown}; choose from {', '.join(EXPERIMENTS)}")
    args.runs.mkdir(parents=True, exist_ok=True)
    for name in names:
        arms = [
            train(arm, opts, args.seeds, args.runs, args.jobs)
            for arm, opts in EXPERIMENTS[name].items()
        ]
        out = args.out / name
        out.mkdir(parents=True, exist_ok=True)
        print(compare(arms, out, args.score), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Hyperparameter search throughput: jaxcart's ``tune`` against rl-zoo3-style Optuna with
Stable-Baselines3, the same search space, trial budget and training budget per trial.

- ``jaxcart``: ``python -m jaxcart.tune --score eval``, ``--batch-trials`` trials x
  ``--num-seeds`` seeds per compiled program, TPE.
- ``sb3-zoo``: :mod:`benchmarks.tune.sb3_study`, as rl-zoo3's ``--optimize`` runs it:
  ``study.optimize(n_jobs=cores)``, one trial per job, one seed per trial, one torch thread
  per job, TPE, the trial's greedy mean return over 20 episodes.

Each contender is one whole process (imports, compiles and evaluation included), timed from
outside; its study goes to an SQLite file in the output folder, from which the report reads
trials per hour and the best score reached against wall time::

    .venv/bin/python -m benchmarks.tune --quick                      # smoke test, seconds
    .venv/bin/python -m benchmarks.tune --sb3-python benchmarks/.venv-bench/bin/python
    .venv/bin/python -m benchmarks.tune --only jaxcart --trials 32 --num-seeds 4

The SB3 venv needs ``optuna`` too (``benchmarks/.venv-bench/bin/pip install optuna``).
"""

from __future__ import annotations

import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

from benchmarks import lib

CONTENDERS = ("jaxcart", "sb3-zoo")
SPACE = ("learning_rate=log:1e-5:1e-2", "clip_coef=0.1:0.3")
QUICK = {"trials": 4, "batch_trials": 2, "num_seeds": 2, "timesteps": 4096}
SB3_VENV = Path("benchmarks/.venv-bench/bin/python")


def parse_args():
    parser = lib.arg_parser(__doc__)
    parser.add_argument("--only", type=lib.split_list, default=list(CONTENDERS))
    parser.add_argument("--trials", type=int, default=32)
    parser.add_argument("--batch-trials", type=int, default=8)
    parser.add_argument("--num-seeds", type=int, default=4, help="jaxcart's seeds per trial")
    parser.add_argument("--timesteps", type=int, default=80_000, help="env steps per seed")
    parser.add_argument("--space", action="append", default=None, help=f"default: {SPACE}")
    parser.add_argument("--sb3-python", type=Path, default=SB3_VENV)
    parser.add_argument("--quick", action="store_true", help=f"a smoke test: {QUICK}")
    parser.add_argument(
        "--pruner",
        default="none",
        choices=["none", "median", "halving"],
        help="jaxcart's pruner (run once with none and once with one to measure what it saves)",
    )
    parser.add_argument(
        "--sampler-seed", type=int, default=None, help="seed of jaxcart's TPE sampler"
    )
    lib.add_output_options(parser)
    return parser.parse_args()


def commands(args, out: Path) -> dict[str, list[str]]:
    """Each contender's command line, its study in ``out/NAME.db``."""
    space = [w for s in args.space for w in ("--space", s)]
    return {
        "jaxcart": [
            sys.executable,
            "-m",
            "jaxcart.tune",
            "--score",
            "eval",
            "--quiet",
            "--trials",
            str(args.trials),
            "--batch-trials",
            str(args.batch_trials),
            "--num-seeds",
            str(args.num_seeds),
            "--total-timesteps",
            str(args.timesteps),
            "--storage",
            f"sqlite:///{out / 'jaxcart.db'}",
            "--study-name",
            "jaxcart",
            "--out",
            str(out / "jaxcart-runs"),
            "--pruner",
            args.pruner,
            "--heldout-top",  # the search alone, as the SB3 contender runs it
            "0",
            *(["--sampler-seed", str(args.sampler_seed)] if args.sampler_seed is not None else []),
            *space,
        ],
        "sb3-zoo": [
            str(args.sb3_python),
            "-m",
            "benchmarks.tune.sb3_study",
            "--trials",
            str(args.trials),
            "--timesteps",
            str(args.timesteps),
            "--storage",
            f"sqlite:///{out / 'sb3-zoo.db'}",
            "--study-name",
            "sb3-zoo",
            *space,
        ],
    }


def study_curve(storage: str, name: str, started: float) -> list[tuple[float, float]]:
    """``[(seconds since the process started, best score so far)]`` at each finished trial."""
    import optuna

    study = optuna.load_study(study_name=name, storage=storage)
    done = sorted(
        (t.datetime_complete.timestamp() - started, t.value)
        for t in study.get_trials(deepcopy=False)
        if t.value is not None
    )
    curve, best = [], float("-inf")
    for seconds, value in done:
        best = max(best, value)
        curve.append((round(seconds, 2), best))
    return curve


def run_contender(name: str, command: list[str], out: Path) -> dict:
    db = out / f"{name}.db"
    db.unlink(missing_ok=True)  # a fresh study, and no earlier run directories
    shutil.rmtree(out / f"{name}-runs", ignore_errors=True)
    if not Path(command[0]).exists():
        print(f"{name}: {command[0]} not found; skipped (benchmarks/setup_venvs.sh)", flush=True)
        return {"contender": name, "error": [f"{command[0]} not found"]}
    started = time.time()
    done = subprocess.run(command, capture_output=True, text=True)
    wall = time.time() - started
    if done.returncode != 0:
        tail = (done.stderr or done.stdout).strip().splitlines()[-3:]
        print(f"{name}: exit {done.returncode}: {' | '.join(tail)}", flush=True)
        return {"contender": name, "error": tail, "command": shlex.join(command)}
    curve = study_curve(f"sqlite:///{db}", name, started)
    return {
        "contender": name,
        "command": shlex.join(command),
        "wall_seconds": round(wall, 2),
        "trials": len(curve),
        "trials_per_hour": round(3600 * len(curve) / wall, 1),
        "best": curve[-1][1] if curve else None,
        "curve": curve,
    }


def markdown(report: dict) -> str:
    s = report["settings"]
    rows = [
        [
            r["contender"],
            str(r.get("trials", "-")),
            str(s["num_seeds"] if r["contender"] == "jaxcart" else 1),
            f"{r['wall_seconds']:.1f}" if "wall_seconds" in r else "failed",
            f"{r['trials_per_hour']:,.0f}" if "trials_per_hour" in r else "-",
            f"{r['best']:.1f}" if r.get("best") is not None else "-",
        ]
        for r in report["results"]
    ]
    table = lib.markdown_table(
        ["contender", "trials", "seeds per trial", "wall s", "trials/hour", "best score"], rows
    )
    lines = [
        "# Hyperparameter search: jaxcart tune against rl-zoo3-style SB3 + Optuna",
        "",
        f"Space {', '.join(s['space'])}; {s['timesteps']:,} env steps per seed; score: greedy "
        "mean return (20 episodes). Whole processes, timed from outside.",
        "",
        table,
        "",
        *lib.provenance_markdown(report),
    ]
    return "\n".join(lines) + "\n"


def plot(report: dict, path: Path) -> None:
    plt = lib.pyplot()
    fig, ax = plt.subplots(figsize=(6, 4))
    for r in report["results"]:
        if r.get("curve"):
            xs, ys = zip(*r["curve"])
            ax.step(xs, ys, where="post", label=r["contender"])
    ax.set_xlabel("wall seconds (whole process)")
    ax.set_ylabel("best trial score so far")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    args = parse_args()
    if args.from_json:
        lib.rerender(args.from_json, "tune", markdown, plot)
        return
    args.space = args.space or list(SPACE)
    if args.quick:
        for key, value in QUICK.items():
            setattr(args, key, value)
    out = lib.output_dir(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    settings = {
        "trials": args.trials,
        "batch_trials": args.batch_trials,
        "num_seeds": args.num_seeds,
        "timesteps": args.timesteps,
        "space": args.space,
    }
    report = lib.new_report("tune", settings, args.only)
    every = commands(args, out)
    for name in args.only:
        print(f"{name}: {shlex.join(every[name])}", flush=True)
        report["results"].append(run_contender(name, every[name], out))
    lib.save_report(report, out, "tune", markdown, plot)


if __name__ == "__main__":
    main()

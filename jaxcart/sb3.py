"""``python -m jaxcart.sb3``: train Stable-Baselines3's own PPO (PyTorch) into a jaxcart run
directory, so that ``plot``, ``compare`` and ``evaluate`` put SB3 beside jaxcart.

Each seed is ``PPO("MlpPolicy", "CartPole-v1", seed=s).learn(80_000)``; the library side is
:mod:`jaxcart.run.sb3`. Needs the ``sb3`` extra and PyTorch's CPU build:
``pip install torch --index-url https://download.pytorch.org/whl/cpu && pip install 'jaxcart[sb3]'``.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from jaxcart import cli

cli.import_jax()  # before run.sb3, which imports JAX: JAX reads JAX_* then

from jaxcart.core.solved import is_solved  # noqa: E402
from jaxcart.run import sb3  # noqa: E402
from jaxcart.run.loggers import check_available as check_loggers  # noqa: E402
from jaxcart.rundir import layout  # noqa: E402


@dataclasses.dataclass(frozen=True)
class SB3Options:
    """The command's options, each declared once (:func:`jaxcart.cli.option`): its type and
    default here, its help the docstring below it."""

    num_seeds: int = cli.option(1, type=cli.bounded_count(sb3.PLAN_BOUNDS["num_seeds"]))
    """seeds to train"""
    first_seed: int = cli.option(0, type=cli.seed)
    """seeds are first-seed ... first-seed+num-seeds-1"""
    total_timesteps: int = cli.option(
        sb3.DEFAULT_TIMESTEPS, type=cli.bounded_count(sb3.PLAN_BOUNDS["total_timesteps"])
    )
    """PPO.learn(total_timesteps); SB3 finishes the 2048-step rollout it is in"""
    jobs: int = cli.option(1, type=cli.count)
    """seeds trained at once, one process each"""
    threads: int = cli.option(1, type=cli.count)
    """PyTorch threads per process"""
    out: Path | None = cli.option(type=cli.out_dir)
    """run directory (default: runs/sb3-torch-<time>)"""
    resume: Path | None = cli.option(type=Path, metavar="RUN_DIR")
    """continue an interrupted run: train the seeds it has not kept yet (each seed is kept as
    it finishes; --jobs, --threads and the loggers may change, nothing else)"""


def build_parser() -> argparse.ArgumentParser:
    """The ``python -m jaxcart.sb3`` command line."""
    parser = cli.Parser(
        prog="python -m jaxcart.sb3",
        description="Train Stable-Baselines3's PPO('MlpPolicy', 'CartPole-v1', seed=s) with its "
        "defaults for each seed s and save the seeds as a jaxcart run directory (SB3's logged "
        "metrics, its networks under jaxcart's parameter names, 20 greedy episodes per seed in "
        f"Gymnasium). Needs PyTorch and SB3: {sb3.INSTALL_HINT}",
    )
    run = cli.add_options(parser, SB3Options, "run")["run"]
    cli.add_options(run, cli.SharedOptions, "", ("logger", "logger_dir"))
    return parser


@cli.command(sb3.SB3Unavailable)
def main(argv: list[str] | None = None) -> int:
    """Runs the command; returns the exit code (2 with one line for a user's mistake)."""
    args = build_parser().parse_args(argv)
    typed = {a.split("=")[0] for a in (sys.argv[1:] if argv is None else argv)}
    fixed = [o for o in ("--num-seeds", "--first-seed", "--total-timesteps", "--out") if o in typed]
    if args.resume is not None and fixed:
        raise cli.UsageError(f"--resume continues the run as it was asked for; drop {fixed[0]}")
    out = args.resume or args.out or layout.default_run_dir("sb3-torch")
    if args.resume is None and out.exists():
        raise cli.UsageError(f"--out {out} exists; choose a new run directory")
    check_loggers(args.logger)  # SB3 and PyTorch: train_run checks them

    def on_start(plan: dict, kept: int) -> None:
        resumed = f" | {kept} already kept" if kept else ""
        print(
            f"Stable-Baselines3 PPO | {plan['num_seeds']} seed(s) x "
            f"learn({plan['total_timesteps']:,}){resumed} | {args.jobs} process(es) | out {out}",
            flush=True,
        )

    def on_seed(seed: int, result: sb3.SeedResult) -> None:
        solved = " (solved)" if is_solved(result.returns) else ""
        mean = result.returns.mean()
        print(f"seed {seed}: {result.seconds:.1f} s, greedy mean {mean:.1f}{solved}", flush=True)

    plan = {name: getattr(args, name) for name in sb3.PLAN_BOUNDS}
    try:
        results = sb3.train_run(
            out,
            None if args.resume else plan,
            on_start,
            on_seed,
            jobs=args.jobs,
            threads=args.threads,
            loggers=tuple(args.logger),
            logger_dir=args.logger_dir,
        )
    except KeyboardInterrupt:
        kept = sum(1 for _ in (out / layout.SB3_SEEDS_DIR).glob("seed-*.npz"))
        print(
            f"\ninterrupted: {kept} finished seed(s) kept in {out}; continue with\n"
            f"  python -m jaxcart.sb3 --resume {out}",
            file=sys.stderr,
            flush=True,
        )
        return 130
    solved = sum(int(is_solved(r.returns)) for r in results)
    print(f"solved {solved}/{len(results)} seed(s) | run directory: {out}")
    return 0


if __name__ == "__main__":
    cli.command_main(main)

"""``python -m jaxcart.train``: train PPO on CartPole-v1, evaluate in Gymnasium, save the run.

Every :class:`~jaxcart.config.PPOConfig` field is an option (its docstring is the help);
``--preset`` picks the starting values and explicit options override them.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

from jaxcart import devices
from jaxcart.config import PRESETS, ConfigError, PPOConfig, config_fields, field_docs, preset


class UsageError(Exception):
    """A mistake in the command line; printed as one line, exit code 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # one line, no usage dump
        raise UsageError(f"{message} (see python -m jaxcart.train --help)")


def _tuple_of_ints(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(v) for v in text.replace(" ", "").split(",") if v)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated integers like 64,64, got {text!r}"
        ) from None


def build_parser() -> argparse.ArgumentParser:
    """The CLI: run options, then one option per config field (help from its docstring)."""
    parser = _Parser(
        prog="python -m jaxcart.train",
        description="Train PPO on CartPole-v1 with JAX; every seed is evaluated for 20 greedy "
        "episodes in Gymnasium's own CartPole-v1 (solved = all 20 score 500).",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    run = parser.add_argument_group("run")
    run.add_argument("--preset", default="sb3", help=f"starting config: {', '.join(PRESETS)}")
    run.add_argument("--num-seeds", type=int, default=1, help="independent agents trained together")
    run.add_argument(
        "--seed", type=int, default=0, help="base seed (seed index i uses fold_in(seed, i))"
    )
    run.add_argument(
        "--out", type=Path, default=None, help="run directory (default: runs/<preset>-<time>)"
    )
    run.add_argument(
        "--eval-episodes", type=int, default=20, help="greedy evaluation episodes per seed"
    )
    run.add_argument(
        "--no-compile-cache",
        action="store_true",
        help="do not use JAX's persistent compilation cache (~/.cache/jaxcart/jax)",
    )
    run.add_argument("--quiet", action="store_true", help="no progress bar")

    docs = field_docs()
    group = parser.add_argument_group("PPO config (defaults shown are the sb3 preset's)")
    for f in config_fields():
        flag = "--" + f.name.replace("_", "-")
        help_text = docs.get(f.name, "")
        if f.type in ("bool", bool):
            group.add_argument(
                flag,
                dest=f.name,
                action=argparse.BooleanOptionalAction,
                default=argparse.SUPPRESS,
                help=help_text,
            )
        elif f.name == "hidden_sizes":
            group.add_argument(
                flag,
                dest=f.name,
                type=_tuple_of_ints,
                default=argparse.SUPPRESS,
                metavar="N,N",
                help=help_text,
            )
        else:
            kind = {"int": int, "float": float, "str": str}[str(f.type)]
            group.add_argument(
                flag, dest=f.name, type=kind, default=argparse.SUPPRESS, help=help_text
            )
    return parser


def config_from_args(args: argparse.Namespace) -> PPOConfig:
    """The preset's config with every option the user gave applied on top."""
    names = {f.name for f in dataclasses.fields(PPOConfig)}
    overrides = {k: v for k, v in vars(args).items() if k in names}
    return preset(args.preset, **overrides)


def default_out_dir(preset_name: str) -> Path:
    """``runs/<preset>-<YYYYmmdd-HHMMSS>``, suffixed when that exists already."""
    base = Path("runs") / f"{preset_name}-{time.strftime('%Y%m%d-%H%M%S')}"
    out, n = base, 1
    while out.exists():
        n += 1
        out = base.with_name(f"{base.name}-{n}")
    return out


def prepare_out_dir(out: Path) -> Path:
    """Creates ``out``; refuses a non-empty or unwritable one with a clear message."""
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out} exists and is not a directory; choose another path")
    if out.is_dir() and any(out.iterdir()):
        raise UsageError(
            f"--out {out} is not empty; choose a new directory so no earlier run is overwritten"
        )
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".write-test"
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        raise UsageError(f"cannot write to --out {out}: {exc.strerror or exc}") from None
    return out


def format_table(rows: list[list[str]], header: list[str]) -> str:
    """Right-aligned plain-text table."""
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows)]
    lines = ["  ".join(str(h).rjust(w) for h, w in zip(header, widths))]
    lines.append("  ".join("-" * w for w in widths))
    lines += ["  ".join(str(c).rjust(w) for c, w in zip(r, widths)) for r in rows]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Trains, evaluates, writes the run directory and prints the summary."""
    wall_start = time.perf_counter()
    config = config_from_args(args)
    if args.num_seeds <= 0:
        raise UsageError(f"--num-seeds must be a positive integer, got {args.num_seeds}")
    if args.eval_episodes <= 0:
        raise UsageError(f"--eval-episodes must be a positive integer, got {args.eval_episodes}")
    if not 0 <= args.seed < 2**32:
        raise UsageError(f"--seed must be in [0, 2**32), got {args.seed}")
    out = prepare_out_dir(args.out or default_out_dir(args.preset))

    if not args.no_compile_cache:
        devices.enable_compilation_cache()

    import jax
    import numpy as np
    from tqdm import tqdm

    from jaxcart import rundir
    from jaxcart.evaluate import evaluate_gymnasium, greedy_returns, numpy_policy, summarize
    from jaxcart.trainer import seed_keys, train

    log = sys.stdout
    print(
        f"jaxcart PPO | preset {args.preset} | {args.num_seeds} seed(s) x "
        f"{config.env_steps_per_seed:,} env steps ({config.num_iterations} iterations of "
        f"{config.num_envs} env(s) x {config.num_steps} steps) "
        f"| {jax.device_count()} {jax.default_backend()} device(s) | out {out}",
        file=log,
        flush=True,
    )
    rundir.write_json(
        out / rundir.CONFIG_FILE,
        {
            "format_version": rundir.FORMAT_VERSION,
            "preset": args.preset,
            "num_seeds": args.num_seeds,
            "seed": args.seed,
            "config": config.to_dict(),
            "versions": rundir.package_versions(),
            "backend": jax.default_backend(),
            "device_count": jax.device_count(),
        },
    )

    bar = None

    def on_compiled(seconds: float) -> None:
        nonlocal bar
        print(f"compiled the fused training step in {seconds:.2f} s", file=log, flush=True)
        if not args.quiet:
            bar = tqdm(
                total=config.num_iterations,
                unit="it",
                desc="training",
                dynamic_ncols=True,
                file=sys.stderr,
            )

    def on_chunk(progress) -> None:
        if bar is None:
            return
        ret = progress.metrics["rollout/ep_rew_mean"][-1]
        mean_ret = float(np.nanmean(ret)) if np.isfinite(ret).any() else float("nan")
        bar.set_postfix_str(
            f"env steps/seed {progress.env_steps:,} | ep_rew_mean {mean_ret:.1f}", refresh=False
        )
        bar.update(progress.iteration - bar.n)

    result = train(config, args.num_seeds, args.seed, on_compiled=on_compiled, on_chunk=on_chunk)
    if bar is not None:
        bar.close()

    rundir.write_metrics_csv(out / rundir.METRICS_FILE, result.metrics, config.batch_size)
    params = jax.device_get(result.params)
    rundir.save_params(out / rundir.PARAMS_FILE, params)

    eval_start = time.perf_counter()
    gym_returns = evaluate_gymnasium(
        numpy_policy(params, config.activation, stacked=True), args.num_seeds, args.eval_episodes
    )
    eval_keys = jax.vmap(lambda k: jax.random.fold_in(k, 1))(seed_keys(args.seed, args.num_seeds))
    jax_returns = np.asarray(
        jax.jit(
            jax.vmap(
                lambda p, k: greedy_returns(
                    p, k, config.activation, config.hidden_sizes, args.eval_episodes
                )
            )
        )(params, eval_keys)
    )
    eval_seconds = time.perf_counter() - eval_start
    gym_summary, jax_summary = summarize(gym_returns), summarize(jax_returns)
    final_rew = result.metrics["rollout/ep_rew_mean"][-1]
    rundir.write_json(
        out / rundir.EVALUATION_FILE,
        {
            "episodes": args.eval_episodes,
            "solved_definition": f"all {args.eval_episodes} greedy episodes score 500",
            "seeds": [
                {
                    "seed_index": s,
                    "gymnasium_returns": gym_returns[s].tolist(),
                    "gymnasium_mean": float(gym_summary["mean"][s]),
                    "gymnasium_min": float(gym_summary["min"][s]),
                    "solved": bool(gym_summary["solved"][s]),
                    "jaxcart_returns": jax_returns[s].tolist(),
                    "jaxcart_mean": float(jax_summary["mean"][s]),
                    "final_ep_rew_mean": float(final_rew[s]),
                }
                for s in range(args.num_seeds)
            ],
            "solved_seeds": int(gym_summary["solved"].sum()),
            "compile_seconds": result.compile_seconds,
            "train_seconds": result.run_seconds,
            "eval_seconds": eval_seconds,
            "env_steps": result.env_steps,
            "devices": result.num_devices,
        },
    )

    rows = [
        [
            s,
            f"{gym_summary['mean'][s]:.1f}",
            f"{gym_summary['min'][s]:.0f}",
            "yes" if gym_summary["solved"][s] else "no",
            f"{jax_summary['mean'][s]:.1f}",
            f"{final_rew[s]:.1f}",
        ]
        for s in range(args.num_seeds)
    ]
    print(
        "\nGreedy evaluation, "
        f"{args.eval_episodes} episodes per seed in gymnasium.make('CartPole-v1'):",
        file=log,
    )
    print(
        format_table(
            rows, ["seed", "gym mean", "gym min", "solved", "jaxcart mean", "train ep_rew_mean"]
        ),
        file=log,
    )
    wall = time.perf_counter() - wall_start
    solved = int(gym_summary["solved"].sum())
    print(
        f"\nsolved {solved}/{args.num_seeds} seed(s) | wall {wall:.1f} s "
        f"(compile {result.compile_seconds:.1f} s, train {result.run_seconds:.1f} s, "
        f"eval {eval_seconds:.1f} s) | "
        f"{result.env_steps:,} env steps at {result.env_steps / result.run_seconds:,.0f} steps/s "
        f"({result.env_steps / (result.run_seconds + result.compile_seconds):,.0f} incl. compile) "
        f"on {result.num_devices} device(s)",
        file=log,
    )
    print(
        f"run directory: {out}  (policy: jaxcart.load_policy({str(out)!r}))", file=log, flush=True
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 2 bad input)."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        return run(args)
    except (UsageError, ConfigError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    devices.use_all_host_cores()
    raise SystemExit(main())

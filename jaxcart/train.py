"""``python -m jaxcart.train``: train PPO on CartPole-v1, evaluate in Gymnasium, save the run.

Every :class:`~jaxcart.config.PPOConfig` field is an option (its docstring is the help);
``--preset`` picks the starting values and explicit options override them. ``--sweep``
trains every combination of float hyperparameters x every seed in one compiled program;
``--resume RUN_DIR`` continues an interrupted run from its last checkpoint.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import os
import re
import signal
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from jaxcart import devices
from jaxcart.config import PRESETS, ConfigError, PPOConfig, config_fields, field_docs, preset

RESUME_HINT = "python -m jaxcart.train --resume {out}"


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
    run.add_argument(
        "--preset", default=None, help=f"starting config: {', '.join(PRESETS)} (default sb3)"
    )
    run.add_argument(
        "--num-seeds",
        type=int,
        default=None,
        help="independent agents trained together (default 1)",
    )
    run.add_argument(
        "--seed",
        type=int,
        default=None,
        help="base seed; seed index i uses fold_in(seed, i) (default 0)",
    )
    run.add_argument(
        "--out", type=Path, default=None, help="run directory (default: runs/<preset>-<time>)"
    )
    run.add_argument(
        "--sweep",
        action="append",
        default=[],
        metavar="NAME=V1,V2",
        help="sweep a float hyperparameter (repeatable); every combination x seed trains in one program",
    )
    run.add_argument(
        "--resume", type=Path, default=None, metavar="RUN_DIR", help="continue an interrupted run"
    )
    run.add_argument(
        "--checkpoint-every",
        type=float,
        default=30.0,
        metavar="SECONDS",
        help="checkpoint interval",
    )
    run.add_argument(
        "--eval-episodes", type=int, default=20, help="greedy evaluation episodes per seed"
    )
    run.add_argument(
        "--logger",
        action="append",
        default=[],
        choices=["tensorboard", "swanlab"],
        help="also log metrics to TensorBoard event files or SwanLab (offline); repeatable",
    )
    run.add_argument(
        "--no-compile-cache",
        action="store_true",
        help="do not use JAX's persistent compilation cache (~/.cache/jaxcart/jax)",
    )
    run.add_argument("--quiet", action="store_true", help="no progress bar")
    dist = parser.add_argument_group(
        "distributed (one process per host; process 0 writes the run directory)"
    )
    dist.add_argument(
        "--distributed",
        action="store_true",
        help="join a jax.distributed run; unset options come from JAX_COORDINATOR_ADDRESS, "
        "JAX_NUM_PROCESSES, JAX_PROCESS_ID or the cluster (SLURM, ...)",
    )
    dist.add_argument("--coordinator-address", default=None, metavar="HOST:PORT")
    dist.add_argument("--num-processes", type=int, default=None)
    dist.add_argument("--process-id", type=int, default=None)

    docs = field_docs()
    group = parser.add_argument_group("PPO config (defaults shown are the sb3 preset's)")
    for f in config_fields():
        flag = "--" + f.name.replace("_", "-")
        help_text = docs.get(f.name, "")
        kwargs = dict(dest=f.name, default=argparse.SUPPRESS, help=help_text)
        if f.type in ("bool", bool):
            group.add_argument(flag, action=argparse.BooleanOptionalAction, **kwargs)
        elif f.name == "hidden_sizes":
            group.add_argument(flag, type=_tuple_of_ints, metavar="N,N", **kwargs)
        else:
            group.add_argument(
                flag, type={"int": int, "float": float, "str": str}[str(f.type)], **kwargs
            )
    return parser


def config_overrides(args: argparse.Namespace) -> dict:
    """The config fields the user gave explicitly."""
    names = {f.name for f in dataclasses.fields(PPOConfig)}
    return {k: v for k, v in vars(args).items() if k in names}


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
    # leftovers of a run killed while writing its first file do not count
    if out.is_dir() and any(
        not (p.name.startswith(".") and p.name.endswith(".tmp")) for p in out.iterdir()
    ):
        raise UsageError(
            f"--out {out} is not empty; choose a new directory so no earlier run is "
            f"overwritten (or continue it with --resume {out})"
        )
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".write-test"
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        raise UsageError(f"cannot write to --out {out}: {exc.strerror or exc}") from None
    return out


def format_table(rows: list[list], header: list[str]) -> str:
    """Right-aligned plain-text table."""
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows)]
    lines = ["  ".join(str(h).rjust(w) for h, w in zip(header, widths))]
    lines.append("  ".join("-" * w for w in widths))
    lines += ["  ".join(str(c).rjust(w) for c, w in zip(r, widths)) for r in rows]
    return "\n".join(lines)


@dataclass
class Plan:
    """Everything decided before compiling: what to train and where to write it."""

    out: Path
    preset: str
    config: PPOConfig
    num_seeds: int  # per combination
    seed: int
    sweep: dict[str, list[float]]
    combos: list[dict[str, float]]
    resume_state: object = None  # TrainState when resuming
    resumed_from_iteration: int = 0
    has_checkpoint: bool = False
    info: dict = field(default_factory=dict)  # what config.json holds

    @property
    def num_runs(self) -> int:
        return self.num_seeds * max(1, len(self.combos))


def _check_positive(name: str, value: int) -> None:
    if value <= 0:
        raise UsageError(f"{name} must be a positive integer, got {value}")


def plan_new(args: argparse.Namespace, create_out: bool = True) -> Plan:
    """Validates a new run's options (no JAX work yet)."""
    from jaxcart import sweep as sweeps

    preset_name = args.preset or "sb3"
    config = preset(preset_name, **config_overrides(args))
    num_seeds = 1 if args.num_seeds is None else args.num_seeds
    seed = 0 if args.seed is None else args.seed
    _check_positive("--num-seeds", num_seeds)
    if not 0 <= seed < 2**32:
        raise UsageError(f"--seed must be in [0, 2**32), got {seed}")
    sweep = sweeps.parse_sweep(args.sweep)
    combos = sweeps.combinations(sweep) if sweep else []
    sweeps.validate_combinations(config, combos)
    for name in sweep:
        if name in config_overrides(args):
            raise UsageError(f"--{name.replace('_', '-')} and --sweep {name} both given; keep one")
    out = args.out or default_out_dir(preset_name)
    if create_out:
        out = prepare_out_dir(out)
    return Plan(out, preset_name, config, num_seeds, seed, sweep, combos)


def plan_resume(args: argparse.Namespace) -> Plan:
    """Validates ``--resume RUN_DIR``: a readable run with a compatible checkpoint."""
    from jaxcart import checkpoint, rundir

    given = [f"--{k.replace('_', '-')}" for k in config_overrides(args)]
    given += [
        flag
        for flag, v in (
            ("--preset", args.preset),
            ("--num-seeds", args.num_seeds),
            ("--seed", args.seed),
            ("--out", args.out),
        )
        if v is not None
    ]
    given += ["--sweep"] if args.sweep else []
    if given:
        raise UsageError(
            f"--resume continues a run with its saved settings; drop {', '.join(given)}"
        )
    out = args.resume
    path = out / checkpoint.CHECKPOINT_FILE
    try:
        info = rundir.read_run_config(out)
        # No checkpoint yet (stopped while starting up): nothing was trained, start at 0.
        meta = checkpoint.read_checkpoint_meta(path) if path.exists() else None
    except rundir.RunDirError as exc:
        raise UsageError(f"cannot resume: {exc}") from None
    versions = rundir.package_versions()
    for name in ("jaxcart", "jax", "jaxlib"):
        saved = (meta or info).get("versions", {}).get(name)
        if saved != versions[name]:
            raise UsageError(
                f"cannot resume: {out} was trained with {name} {saved}, this is {versions[name]}; "
                f"reinstall {name}=={saved} to continue it bit-identically"
            )
    config = info["config"]
    if (
        meta is not None
        and meta.get("iteration", 0) >= config.num_iterations
        and (out / rundir.EVALUATION_FILE).exists()
    ):
        raise UsageError(
            f"{out} already finished all {config.num_iterations} iterations; nothing to resume"
        )
    sweep = {k: list(v) for k, v in info.get("sweep", {}).items()}
    from jaxcart import sweep as sweeps

    combos = sweeps.combinations(sweep) if sweep else []
    plan = Plan(
        out, info["preset"], config, int(info["num_seeds"]), int(info["seed"]), sweep, combos
    )
    plan.info = {k: v for k, v in info.items() if k != "config"}
    plan.resumed_from_iteration = int(meta["iteration"]) if meta else 0
    plan.has_checkpoint = meta is not None
    return plan


def _load_resume_state(plan: Plan, hps, seed_indices):
    from jaxcart import checkpoint, rundir
    from jaxcart.env import EnvParams
    from jaxcart.trainer import TrainState, init_runners

    template = {
        "runners": init_runners(plan.config, plan.num_runs, plan.seed, EnvParams(), seed_indices),
        "hyperparams": hps,
    }
    path = plan.out / checkpoint.CHECKPOINT_FILE
    try:
        (state, meta), metrics = (
            checkpoint.load_checkpoint(path, template),
            checkpoint.load_extras(path),
        )
    except rundir.RunDirError as exc:
        raise UsageError(f"cannot resume: {exc}") from None
    return TrainState(
        runners=state["runners"],
        hyperparams=state["hyperparams"],
        iteration=int(meta["iteration"]),
        elapsed=float(meta["elapsed"]),
        metrics=metrics,
        chunk_size=int(meta["chunk_size"]),
    )


class _NullLogger:
    def log(self, *args) -> None:
        pass

    def close(self) -> None:
        pass


class StopFlag:
    """Set by SIGINT/SIGTERM: training stops after the current chunk and checkpoints. A second
    Ctrl-C stops at once (the last periodic checkpoint is kept)."""

    def __init__(self) -> None:
        self.signum: int | None = None

    def __call__(self) -> bool:
        return self.signum is not None

    def handle(self, signum, frame) -> None:
        if self.signum is not None and signum == signal.SIGINT:
            raise KeyboardInterrupt
        self.signum = signum
        name = signal.Signals(signum).name
        print(
            f"\n{name} received: finishing the current chunk and saving a checkpoint...",
            file=sys.stderr,
            flush=True,
        )

    @contextlib.contextmanager
    def installed(self):
        previous = {}
        try:
            for sig in (signal.SIGINT, signal.SIGTERM):
                previous[sig] = signal.signal(sig, self.handle)
        except ValueError:  # not the main thread (e.g. called from a worker): no handlers
            pass
        try:
            yield self
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)


def run(args: argparse.Namespace) -> int:
    """Trains, checkpoints, evaluates, writes the run directory and prints the summary."""
    wall_start = time.perf_counter()
    from jaxcart import distributed

    if args.distributed:
        if args.out is None and args.resume is None:
            raise UsageError("--distributed needs --out DIR (the same path on every process)")
        try:
            distributed.initialize(args.coordinator_address, args.num_processes, args.process_id)
        except (ValueError, TypeError, RuntimeError) as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise UsageError(f"cannot start jax.distributed: {first}") from None
    elif any(
        v is not None for v in (args.coordinator_address, args.num_processes, args.process_id)
    ):
        raise UsageError("--coordinator-address/--num-processes/--process-id need --distributed")
    main_process = not args.distributed or distributed.is_main_process()
    if args.logger:
        from jaxcart.loggers import LoggerUnavailable, check_available

        try:
            check_available(args.logger)
        except LoggerUnavailable as exc:
            raise UsageError(str(exc)) from None
    plan = plan_resume(args) if args.resume else plan_new(args, create_out=main_process)
    _check_positive("--eval-episodes", args.eval_episodes)
    if args.checkpoint_every <= 0:
        raise UsageError(f"--checkpoint-every must be > 0 seconds, got {args.checkpoint_every}")
    if not args.no_compile_cache:
        devices.enable_compilation_cache()

    import jax
    import numpy as np
    from tqdm import tqdm

    from jaxcart import checkpoint, rundir
    from jaxcart import sweep as sweeps
    from jaxcart.trainer import broadcast_hyperparams, initial_state, train

    config, out = plan.config, plan.out
    if args.distributed and plan.num_runs % jax.device_count():
        raise UsageError(
            f"{plan.num_runs} runs cannot be split evenly over {jax.device_count()} devices in "
            f"{jax.process_count()} processes; use a multiple of {jax.device_count()} seeds"
        )
    if plan.combos:
        hps, seed_indices = sweeps.sweep_hyperparams(
            sweeps.validate_combinations(config, plan.combos), plan.num_seeds
        )
    else:
        hps, seed_indices = broadcast_hyperparams(config, plan.num_seeds), None
    if args.resume:
        if plan.has_checkpoint:
            plan.resume_state = _load_resume_state(plan, hps, seed_indices)
    else:
        plan.info = {
            "format_version": rundir.FORMAT_VERSION,
            "preset": plan.preset,
            "num_seeds": plan.num_seeds,
            "seed": plan.seed,
            "sweep": plan.sweep,
            "combinations": plan.combos,
            "versions": rundir.package_versions(),
            "backend": jax.default_backend(),
            "device_count": jax.device_count(),
        }
        if main_process:
            rundir.write_json(out / rundir.CONFIG_FILE, {**plan.info, "config": config.to_dict()})
    run_names = [
        f"combo{r // plan.num_seeds:03d}-seed{r % plan.num_seeds}" if plan.combos else f"seed{r}"
        for r in range(plan.num_runs)
    ]
    logger = _NullLogger()
    if args.logger and main_process:
        from jaxcart.loggers import make_logger  # availability was checked before anything ran

        logger = make_logger(args.logger, out, run_names, {**plan.info, "config": config.to_dict()})

    log = sys.stdout if main_process else open(os.devnull, "w")
    what = (
        f"{len(plan.combos)} combinations x {plan.num_seeds} seed(s)"
        if plan.combos
        else f"{plan.num_seeds} seed(s)"
    )
    print(
        f"jaxcart PPO | preset {plan.preset} | {what} x {config.env_steps_per_seed:,} env steps "
        f"({config.num_iterations} iterations of {config.num_envs} env(s) x {config.num_steps} steps) "
        f"| {jax.device_count()} {jax.default_backend()} device(s) | out {out}",
        file=log,
        flush=True,
    )
    if args.resume:
        print(
            f"resuming from iteration {plan.resumed_from_iteration}/{config.num_iterations}",
            file=log,
            flush=True,
        )

    bar = None
    last_save = time.monotonic()

    versions = rundir.package_versions()  # looked up once, recorded in every checkpoint

    def save(state) -> None:
        # every process takes part in gathering the shards; process 0 writes
        arrays = distributed.gather({"runners": state.runners, "hyperparams": state.hyperparams})
        if not main_process:
            return
        checkpoint.save_checkpoint(
            out / checkpoint.CHECKPOINT_FILE,
            arrays,
            {
                "iteration": state.iteration,
                "elapsed": state.elapsed,
                "chunk_size": state.chunk_size,
                "num_runs": plan.num_runs,
                "config": config.to_dict(),
                "versions": versions,
            },
            extras=state.metrics,
        )

    if plan.resume_state is None:
        # An iteration-0 checkpoint first: a run killed at any moment can be resumed.
        plan.resume_state = initial_state(
            config, plan.num_runs, plan.seed, hps, seed_indices=seed_indices
        )
        save(plan.resume_state)

    def on_compiled(seconds: float) -> None:
        nonlocal bar
        print(f"compiled the fused training step in {seconds:.2f} s", file=log, flush=True)
        if not args.quiet and main_process:
            bar = tqdm(
                total=config.num_iterations,
                initial=plan.resumed_from_iteration,
                unit="it",
                desc="training",
                dynamic_ncols=True,
                file=sys.stderr,
            )

    reported: set[int] = set()

    def on_chunk(progress) -> None:
        nonlocal last_save
        for r in np.flatnonzero(progress.diverged_at >= 0):
            if int(r) not in reported and main_process:
                reported.add(int(r))
                message = (
                    f"{run_names[r]} diverged at iteration {progress.diverged_at[r]} (non-finite loss or "
                    f"parameters): it stops there with its last finite parameters; other runs continue"
                )
                (bar.write if bar is not None else print)(message, file=sys.stderr)
        first = progress.iteration - len(progress.metrics["time/fps"])
        logger.log(
            first,
            (first + 1 + np.arange(len(progress.metrics["time/fps"]))) * config.batch_size,
            progress.metrics,
        )
        due = time.monotonic() - last_save >= args.checkpoint_every
        if args.distributed:  # every process must agree on when to gather the state
            due = distributed.any_process(due)
        if due and progress.iteration < config.num_iterations:
            save(progress.state())
            last_save = time.monotonic()
        if bar is not None:
            ret = progress.metrics["rollout/ep_rew_mean"][-1]
            mean_ret = float(np.nanmean(ret)) if np.isfinite(ret).any() else float("nan")
            bar.set_postfix_str(
                f"env steps/seed {progress.env_steps:,} | ep_rew_mean {mean_ret:.1f}", refresh=False
            )
            bar.update(progress.iteration - bar.n)

    stop = StopFlag()
    try:
        with stop.installed():
            result = train(
                config,
                plan.num_runs,
                plan.seed,
                hyperparams=hps,
                resume=plan.resume_state,
                seed_indices=seed_indices,
                on_compiled=on_compiled,
                on_chunk=on_chunk,
                should_stop=stop,
            )
    finally:
        if bar is not None:
            bar.close()
        logger.close()
    save(result.state)
    if result.stopped:
        if main_process:
            rundir.write_metrics_csv(out / rundir.METRICS_FILE, result.metrics, config.batch_size)
        print(
            f"stopped at iteration {result.state.iteration}/{config.num_iterations}; checkpoint saved in {out}\n"
            f"resume with: {RESUME_HINT.format(out=out)}",
            file=log,
            flush=True,
        )
        return 128 + (stop.signum or signal.SIGTERM)  # another process may have been signalled

    params = distributed.gather(result.params)
    diverged_at = np.asarray(distributed.gather(result.state.runners.diverged_at))
    if not main_process:
        return 0
    eval_start = time.perf_counter()
    gym_returns, jax_returns = evaluate_runs(params, config, plan, args.eval_episodes, seed_indices)
    eval_seconds = time.perf_counter() - eval_start
    groups = (
        [(out, slice(0, plan.num_runs), {})]
        if not plan.combos
        else [
            (out / f"combo-{c:03d}", slice(c * plan.num_seeds, (c + 1) * plan.num_seeds), combo)
            for c, combo in enumerate(plan.combos)
        ]
    )
    timing = {
        "diverged_at": diverged_at,
        "compile_seconds": result.compile_seconds,
        "train_seconds": result.state.elapsed,
        "eval_seconds": eval_seconds,
        "devices": result.num_devices,
    }
    for directory, runs, combo in groups:
        write_outputs(
            directory,
            plan,
            combo,
            runs,
            result.metrics,
            params,
            gym_returns,
            jax_returns,
            args.eval_episodes,
            timing,
        )

    solved = (gym_returns >= 500).all(axis=1)
    diverged = diverged_at
    final_rew = result.metrics["rollout/ep_rew_mean"][-1]
    if plan.combos:
        steps = np.arange(1, config.num_iterations + 1) * config.batch_size
        ranking = sweeps.rank(
            plan.combos,
            solved,
            final_rew,
            sweeps.first_reach(result.metrics["rollout/ep_rew_max"], steps),
            plan.num_seeds,
            diverged,
        )
        rundir.write_json(
            out / "sweep.json",
            {"sweep": plan.sweep, "num_seeds": plan.num_seeds, "ranking": ranking},
        )
        names = list(plan.sweep)
        rows = [
            [
                r["combination"],
                *[f"{r[n]:g}" for n in names],
                f"{r['solve_rate']:.0%}",
                f"{r['final_return']:.1f}",
                "never"
                if not np.isfinite(r["median_steps_to_500"])
                else f"{r['median_steps_to_500']:,.0f}",
                f"{r['seeds_reaching_500']}/{plan.num_seeds}",
                f"{r['seeds_diverged']}/{plan.num_seeds}",
            ]
            for r in ranking
        ]
        print(
            f"\nSweep ranking ({plan.num_seeds} seed(s) each; solved = all {args.eval_episodes} greedy Gymnasium episodes score 500):",
            file=log,
        )
        print(
            format_table(
                rows,
                [
                    "combo",
                    *names,
                    "solved",
                    "final ep_rew_mean",
                    "median steps to a 500 episode",
                    "reached 500",
                    "diverged",
                ],
            ),
            file=log,
        )
        print(f"per-combination results: {out}/combo-NNN/ (sweep.json ranks them)", file=log)
    else:
        rows = [
            [
                s,
                f"{gym_returns[s].mean():.1f}",
                f"{gym_returns[s].min():.0f}",
                ("yes" if solved[s] else "no")
                + (f" (diverged@{diverged[s]})" if diverged[s] >= 0 else ""),
                f"{jax_returns[s].mean():.1f}",
                f"{final_rew[s]:.1f}",
            ]
            for s in range(plan.num_runs)
        ]
        print(
            f"\nGreedy evaluation, {args.eval_episodes} episodes per seed in gymnasium.make('CartPole-v1'):",
            file=log,
        )
        print(
            format_table(
                rows, ["seed", "gym mean", "gym min", "solved", "jaxcart mean", "train ep_rew_mean"]
            ),
            file=log,
        )
    wall = time.perf_counter() - wall_start
    print(
        f"\nsolved {int(solved.sum())}/{plan.num_runs} run(s) | wall {wall:.1f} s "
        f"(compile {result.compile_seconds:.1f} s, train {result.run_seconds:.1f} s, "
        f"eval {eval_seconds:.1f} s) | {result.env_steps:,} env steps at "
        f"{result.env_steps / result.run_seconds:,.0f} steps/s "
        f"({result.env_steps / (result.run_seconds + result.compile_seconds):,.0f} incl. compile) "
        f"on {result.num_devices} device(s)",
        file=log,
    )
    print(f"run directory: {out}", file=log, flush=True)
    return 0


def evaluate_runs(params, config: PPOConfig, plan: Plan, episodes: int, seed_indices):
    """Greedy returns of every run in Gymnasium's CartPole-v1 and in jaxcart, ``[R, episodes]``."""
    import jax
    import numpy as np

    from jaxcart.evaluate import evaluate_gymnasium, greedy_returns, numpy_policy
    from jaxcart.trainer import seed_keys

    gym_returns = evaluate_gymnasium(
        numpy_policy(params, config.activation, stacked=True), plan.num_runs, episodes
    )
    indices = np.arange(plan.num_runs) if seed_indices is None else np.asarray(seed_indices)
    keys = jax.vmap(lambda k: jax.random.fold_in(k, 1))(
        seed_keys(plan.seed, int(indices.max()) + 1)[indices]
    )
    evaluate = jax.jit(
        jax.vmap(
            lambda p, k: greedy_returns(p, k, config.activation, config.hidden_sizes, episodes)
        )
    )
    return gym_returns, np.asarray(evaluate(params, keys))


def write_outputs(
    directory: Path,
    plan: Plan,
    combo: dict,
    runs: slice,
    metrics,
    params,
    gym_returns,
    jax_returns,
    episodes: int,
    timing: dict,
) -> None:
    """config.json (per combination for sweeps), metrics.csv, params.npz, evaluation.json."""
    import jax

    from jaxcart import rundir

    directory.mkdir(parents=True, exist_ok=True)
    if combo:
        config = PPOConfig(**{**plan.config.to_dict(), **combo})
        rundir.write_json(
            directory / rundir.CONFIG_FILE,
            {
                **plan.info,
                "combination": combo,
                "sweep": {},
                "combinations": [],
                "config": config.to_dict(),
            },
        )
    rundir.write_metrics_csv(
        directory / rundir.METRICS_FILE,
        {k: v[:, runs] for k, v in metrics.items()},
        plan.config.batch_size,
    )
    rundir.save_params(directory / rundir.PARAMS_FILE, jax.tree.map(lambda x: x[runs], params))
    g, j = gym_returns[runs], jax_returns[runs]
    final = metrics["rollout/ep_rew_mean"][-1, runs]
    timing = dict(timing)
    diverged = timing.pop("diverged_at")[runs]
    rundir.write_json(
        directory / rundir.EVALUATION_FILE,
        {
            "episodes": episodes,
            "solved_definition": f"all {episodes} greedy episodes score 500 in gymnasium.make('CartPole-v1')",
            "seeds": [
                {
                    "seed_index": s,
                    "gymnasium_returns": g[s].tolist(),
                    "gymnasium_mean": float(g[s].mean()),
                    "gymnasium_min": float(g[s].min()),
                    "solved": bool((g[s] >= 500).all()),
                    "jaxcart_returns": j[s].tolist(),
                    "jaxcart_mean": float(j[s].mean()),
                    "final_ep_rew_mean": float(final[s]),
                    "diverged_at_iteration": int(diverged[s]) if diverged[s] >= 0 else None,
                }
                for s in range(len(g))
            ],
            "solved_seeds": int((g >= 500).all(axis=1).sum()),
            **timing,
        },
    )


def join_negative_values(argv: list[str]) -> list[str]:
    """``["--learning-rate", "-3e-4"]`` -> ``["--learning-rate=-3e-4"]``: argparse reads a
    value like ``-3e-4`` as an unknown option, which would hide the real problem (a negative
    value) behind "expected one argument"."""
    out: list[str] = []
    for token in argv:
        if (
            out
            and out[-1].startswith("--")
            and "=" not in out[-1]
            and re.fullmatch(r"-(\d|\.\d|inf|nan).*", token)
        ):
            out[-1] = f"{out[-1]}={token}"
        else:
            out.append(token)
    return out


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 2 bad input, 128+signal when interrupted)."""
    parser = build_parser()
    try:
        args = parser.parse_args(join_negative_values(sys.argv[1:] if argv is None else list(argv)))
        return run(args)
    except (UsageError, ConfigError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    devices.use_all_host_cores()
    raise SystemExit(main())

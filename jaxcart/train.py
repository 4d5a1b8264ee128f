"""``python -m jaxcart.train``: train PPO on CartPole-v1, evaluate in Gymnasium, save the run.

Only the command line and its printing live here: the options become a frozen
:class:`TrainOptions`, then :mod:`jaxcart.run.lifecycle` carries the run out and
:mod:`jaxcart.report` prints it. Every :class:`~jaxcart.core.config.PPOConfig` field is an option
(its docstring is the help); ``--preset`` picks the starting values and explicit options
override them. ``--sweep`` trains every combination of float hyperparameters x every seed in
one compiled program; ``--resume RUN_DIR`` continues an interrupted run from its last
checkpoint.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

from jaxcart import cli, configfile

cli.import_jax()  # before core.config, a JAX pytree: JAX reads JAX_* on import

from jaxcart.core.config import PRESETS, PPOConfig, config_fields, preset  # noqa: E402
from jaxcart.engine.signals import StopRequest  # noqa: E402

if TYPE_CHECKING:  # the modules that import JAX load in main(), after the options are read
    from jaxcart import report
    from jaxcart.analysis.summary import Score
    from jaxcart.run import lifecycle, structural


def _tuple_of_ints(text: str) -> tuple[int, ...]:
    parts = text.replace(" ", "").split(",")
    try:
        values = tuple(int(v) for v in parts if v)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated integers like 64,64, got {text!r}"
        ) from None
    if "" in parts[:-1] or not parts[0]:  # "64,,64" is a mistake, not (64, 64); "64," is fine
        raise argparse.ArgumentTypeError(f"has an empty element: {text!r}")
    return values


def _float_or_none(text: str) -> float | None:
    """A float, or ``none``/``off`` for None (an argparse ``type``)."""
    if text.strip().lower() in ("none", "off"):
        return None
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number or none, got {text!r}") from None


def build_parser() -> argparse.ArgumentParser:
    """The CLI: :class:`TrainOptions`' options, then one option per config field (help from
    its docstring)."""
    parser = cli.Parser(
        prog="python -m jaxcart.train",
        description="Train PPO on CartPole-v1 (or --env Acrobot-v1, MountainCar-v0) with JAX; "
        "every seed is evaluated for 20 greedy episodes in Gymnasium's own env of that id "
        "(CartPole solved = all 20 score 500; the others: the mean reaches the env's "
        "reward_threshold).",
    )
    run = cli.add_options(parser, TrainOptions, "run")["run"]
    cli.add_options(run, cli.SharedOptions, "")  # --logger, --logger-dir, --trust-code
    _add_config_options(
        parser.add_argument_group(
            "PPO config (defaults shown are the sb3 preset's; --preset changes them)"
        )
    )
    return parser


def _add_config_options(group: argparse._ArgumentGroup) -> None:
    """One option per PPOConfig field, its docstring as the help, the sb3 preset's value as
    the default shown (the option itself defaults to "not given", so presets apply)."""
    docs, defaults = cli.field_docs(PPOConfig), preset("sb3")
    for f in config_fields():
        flag = "--" + f.name.replace("_", "-")
        shown = cli.spelled(getattr(defaults, f.name)).replace("%", "%%")
        help_text = f"{docs.get(f.name, '').replace('%', '%%')} (default: {shown})"
        kwargs = dict(dest=f.name, default=argparse.SUPPRESS, help=help_text)
        if f.type == "bool":
            kwargs["action"] = argparse.BooleanOptionalAction
        else:
            kwargs["type"], kwargs["metavar"] = CONFIG_TYPES[f.type]
        if f.type == "int" and f.metadata.get("minimum") == 0:  # 0 turns it off
            kwargs["type"] = cli.bounded_count(minimum=0)
        group.add_argument(flag, **kwargs)


CONFIG_TYPES = {
    "int": (cli.count, None),  # every integer field is a count: 1e5 and 100_000 read as 100000
    "float": (float, None),
    "str": (str, None),
    "tuple[int, ...]": (_tuple_of_ints, "N,N"),
    "float | None": (_float_or_none, "KL"),
}
"""The argparse ``type`` and metavar of a config field, by its annotation (bools are
``--name/--no-name`` switches)."""


PRESET_NAMES = ", ".join(
    f"{n} (annealed lr)" if p.get("anneal_lr") else n for n, p in PRESETS.items()
)
DISTRIBUTED = "distributed (one process per host; process 0 writes the run directory)"


@dataclass(frozen=True)
class TrainOptions:
    """Everything the command line said, checked: nothing past :func:`main` sees argparse.
    Each :func:`~jaxcart.cli.option` field is the option ``--name``, its docstring the help."""

    preset: str | None = cli.option(help=f"starting config: {PRESET_NAMES} (default: sb3)")
    config: Path | None = cli.option(type=Path, metavar="FILE")
    """options from a TOML/YAML/JSON file (keys named as the options), rl-zoo3's ppo.yml (the
    entry of the env it trains: --env, default CartPole-v1) or a run's config.json (trains it
    again); options on the command line override the file's"""
    num_seeds: int | None = cli.option(type=cli.count)
    """independent agents trained together (default: 1)"""
    seed: int | None = cli.option(type=int)
    """base seed; seed index i uses fold_in(seed, i) (default: 0)"""
    out: Path | None = cli.option(type=cli.out_dir)
    """run directory (default: runs/<preset>-<time>)"""
    sweep: tuple[str, ...] = cli.option((), action="append", metavar="NAME=V1,V2")
    """sweep a float hyperparameter, or a continuous physics field as env.NAME (e.g.
    env.length=0.5,1.0,2.0) (repeatable); every combination x seed trains in one program"""
    score: Score | None = cli.option(type=cli.score, metavar="SCORE")
    """what ranks a --sweep's combinations, each seed scored as compare --score does: eval
    (mean greedy Gymnasium return), auc (mean of rollout/ep_rew_mean over the run) or
    return-at:STEPS (default: eval)"""
    env_param: tuple[str, ...] = cli.option((), action="append", metavar="NAME=VALUE")
    """set a field of CartPole's physics for every run, e.g. length=1.0 (half the pole's
    length, as in Gymnasium); repeatable; recorded in config.json and used by the Gymnasium
    evaluation, evaluate, load_policy and the GIF (python -m jaxcart.env lists the fields)"""
    randomize: tuple[str, ...] = cli.option((), action="append", metavar="env.NAME=LOW:HIGH")
    """draw a continuous physics field uniformly in [LOW, HIGH] once per seed (from the seed,
    recorded per seed in config.json); repeatable; the runs are evaluated on the nominal
    physics (--env-param or CartPole-v1's)"""
    eval_episodes: int | None = cli.option(type=cli.bounded_count(cli.MAX_EPISODES))
    """greedy evaluation episodes per seed (default 20; a resumed run keeps its own)"""
    no_compile_cache: bool = cli.option(False, action="store_true")
    """do not use JAX's persistent compilation cache ($JAXCART_CACHE_DIR, else
    $XDG_CACHE_HOME/jaxcart/jax, else ~/.cache/jaxcart/jax)"""
    wave_size: int | None = cli.option(type=cli.count, metavar="N")
    """train N runs at a time (default: the fewest that fill the devices, fewer when memory
    is short); the wave width is part of what makes a run reproducible"""
    dry_run: bool = cli.option(False, action="store_true")
    """print the plan (waves, memory, estimated time) and exit without training"""
    quiet: bool = cli.option(False, action="store_true")
    """no progress bar"""
    resume: Path | None = cli.option(type=Path, metavar="RUN_DIR")
    """continue an interrupted run; with --total-timesteps N, train an interrupted or
    finished run on to N env steps per seed (an annealed learning rate then anneals over N
    from the resume on, as SB3's learn(reset_num_timesteps=False): recorded as lr_schedule
    in config.json)"""
    allow_device_change: bool = cli.option(False, action="store_true")
    """with --resume: continue on another device count than the run trained on (the numbers
    then differ from an uninterrupted run; config.json records it)"""
    checkpoint_every: float = cli.option(30.0, type=float, metavar="SECONDS")
    """checkpoint interval"""
    distributed: bool = cli.option(False, action="store_true", group=DISTRIBUTED)
    """join a jax.distributed run; unset options come from JAX_COORDINATOR_ADDRESS,
    JAX_NUM_PROCESSES, JAX_PROCESS_ID or the cluster (SLURM, ...)"""
    coordinator_address: str | None = cli.option(metavar="HOST:PORT", group=DISTRIBUTED)
    num_processes: int | None = cli.option(type=cli.count, group=DISTRIBUTED)
    process_id: int | None = cli.option(type=int, group=DISTRIBUTED)
    trust_code: bool = False  # --trust-code, --logger and --logger-dir: shared with other commands
    logger: tuple[str, ...] = ()
    logger_dir: Path | None = None
    overrides: dict = field(default_factory=dict)  # config fields given explicitly
    argv: tuple[str, ...] = ()  # as typed, recorded in config.json

    @classmethod
    def from_args(cls, args: argparse.Namespace, argv: list[str] = ()) -> TrainOptions:
        """The options of ``args`` that are fields here, the config fields given explicitly
        as ``overrides`` (the options default to "not given"), and ``argv`` as typed."""
        names = {f.name for f in config_fields()}
        overrides = {k: v for k, v in vars(args).items() if k in names}
        return cli.options_from(cls, args, overrides=overrides, argv=tuple(argv))

    def run_spec(self) -> lifecycle.RunSpec:
        """The new run these options describe."""
        from jaxcart.core import physics
        from jaxcart.run import spec

        sweep, shapes = spec.parse_sweep(self.sweep)
        env_values = spec.parse_env_params(self.env_param)
        given = {name: "--" + name.replace("_", "-") for name in self.overrides}
        given.update({physics.PREFIX + name: f"--env-param {name}" for name in env_values})
        for name in (*sweep, *shapes):
            if name in given:
                raise cli.UsageError(f"{given[name]} and --sweep {name} both given; keep one")
        name = self.preset or "sb3"
        return spec.RunSpec(
            config=preset(name, **self.overrides),
            preset=name,
            num_seeds=1 if self.num_seeds is None else self.num_seeds,
            seed=0 if self.seed is None else self.seed,
            sweep=sweep,
            env_params=physics.make_env_params(env_values),
            randomize=spec.parse_randomize(self.randomize),
        )

    def run_options(self) -> lifecycle.RunOptions:
        """How to carry the run out."""
        from jaxcart.run import lifecycle

        same = ("checkpoint_every", "eval_episodes", "logger_dir", "wave_size", "score")
        return lifecycle.RunOptions(
            loggers=self.logger,
            compile_cache=not self.no_compile_cache,
            **{name: getattr(self, name) for name in same},
        )

    def check(self) -> None:
        """Refuses options that do not go together: ``--resume`` continues with the run's
        saved settings (but ``--total-timesteps``, which extends the run), and the options of
        a distributed run need ``--distributed``."""
        if self.resume is None and self.allow_device_change:
            raise cli.UsageError("--allow-device-change goes with --resume RUN_DIR")
        if self.resume is None and self.trust_code:
            raise cli.UsageError(
                "--trust-code goes with --resume RUN_DIR (a new run names its code)"
            )
        kept = ("preset", "num_seeds", "seed", "out", "wave_size", "dry_run", "sweep", "env_param")
        given = [k for k in self.overrides if k != "total_timesteps"] + [
            k for k in (*kept, "randomize") if getattr(self, k) not in (None, False, ())
        ]
        if self.resume is not None and given:
            raise cli.UsageError(
                "--resume continues a run with its saved settings; drop "
                + ", ".join("--" + k.replace("_", "-") for k in given)
            )
        where = (self.coordinator_address, self.num_processes, self.process_id)
        if not self.distributed and any(v is not None for v in where):
            raise cli.UsageError(
                "--coordinator-address/--num-processes/--process-id need --distributed"
            )
        if self.distributed and self.out is None and self.resume is None:
            raise cli.UsageError("--distributed needs --out DIR (the same path on every process)")


def _train(opts: TrainOptions, console: report.ConsoleReport) -> int:
    """Plans, trains, evaluates and reports a run, or a structural sweep (one program and run
    directory per shape group, ranked together); returns the exit code."""
    from jaxcart import report
    from jaxcart.engine import distributed
    from jaxcart.engine.signals import Stopped
    from jaxcart.run import lifecycle, structural
    from jaxcart.run.spec import parse_sweep
    from jaxcart.rundir import layout, reader
    from jaxcart.rundir.files import RunDirError
    from jaxcart.rundir.reader import group_label

    wall_start = time.perf_counter()
    opts.check()
    spec = None if opts.resume is not None else opts.run_spec()  # bad options fail here
    shapes = parse_sweep(opts.sweep)[1]  # a structural sweep's axes, if any
    groups = reader.sweep_combinations(shapes) if spec is not None else []
    specs = [structural.group_spec(spec, g) for g in groups] if groups else [spec]  # each checked
    if spec is not None and opts.score is not None:
        _check_score(opts.score, spec, groups, specs)
    run_options = opts.run_options()
    if opts.distributed and (groups or (opts.resume and reader.is_groups(opts.resume))):
        raise cli.UsageError("a structural sweep (--sweep of a shape) runs in one process")
    if opts.distributed:
        lifecycle.start_distributed(opts.coordinator_address, opts.num_processes, opts.process_id)
    if not distributed.is_main_process():
        console.out, console.progress_bar = open(os.devnull, "w"), False
    if groups:
        console.print(
            f"structural sweep: {len(groups)} shape groups, so {len(groups)} programs compile "
            f"(one each; the float axes stay vmapped inside each): "
            + "; ".join(group_label(g) for g in groups)
        )
    if opts.dry_run and not groups:
        import jax

        # the header a run would print, without a directory: what would train, in env steps
        out = opts.out or "(none: --dry-run creates nothing)"
        console.print(report.header_line(spec, jax.device_count(), jax.default_backend(), out))
    if opts.dry_run:  # the plan of the run, or of each shape group
        for group, group_spec in zip(groups or [None], specs):
            label = f"{group_label(group)}: " if groups else ""
            plan = lifecycle.plan_run(group_spec, run_options)
            console.print(label + report.plan_text(plan, group_spec))
        return 0

    def on_group(outcome: lifecycle.Outcome) -> None:
        if not outcome.stopped and outcome.evaluation is not None:
            console.print(report.results_text(outcome))

    def start_or_resume() -> lifecycle.Outcome | structural.GroupsOutcome:
        """The run: ``spec`` as a new run (one per shape group of a structural sweep), or
        ``--resume`` (``spec`` None) of a run or of every group of a sweep not yet finished."""
        command = ["python -m jaxcart.train", *opts.argv]
        if groups:
            out = opts.out or layout.default_run_dir(f"{spec.preset}-groups")
            args = (run_options, hooks, stop, command, on_group)
            return structural.run_groups(spec, groups, out, *args)
        if spec is not None:
            return lifecycle.run_new(spec, opts.out, run_options, hooks, stop, command)
        if reader.is_groups(opts.resume):
            return structural.finish_groups(opts.resume, run_options, hooks, stop, on_group)
        extend_to, allow = opts.overrides.get("total_timesteps"), opts.allow_device_change
        try:
            return lifecycle.resume_run(
                opts.resume, run_options, hooks, stop, extend_to, allow, trust_code=opts.trust_code
            )
        except RunDirError as exc:
            raise cli.UsageError(f"cannot resume: {exc}") from None

    stop, hooks = StopRequest(on_signal=console.on_signal), console.hooks()
    try:
        with stop.installed():  # the training's signal handling, from its plan to its outputs
            outcome = start_or_resume()
    except Stopped:
        console.print("stopped before the run started; nothing was written")
        return 128 + (stop.signum or 15)
    except KeyboardInterrupt:
        if stop.signum is None:  # not the second signal: command_main's one line
            raise
        console.close()  # the second signal: stop at once; the checkpoint on disk is valid
        print(report.interrupted_text(console.run, stop.signum), file=sys.stderr, flush=True)
        return 128 + stop.signum
    except OSError as exc:  # a full or read-only disk: earlier checkpoints stay intact
        console.close()
        print(report.write_failed_text(console.run, exc), file=sys.stderr, flush=True)
        return 1
    finally:
        console.close()
    distributed.leave()
    wall = time.perf_counter() - wall_start
    if isinstance(outcome, structural.GroupsOutcome):
        console.print(report.groups_finished_text(outcome, wall))
        return 128 + outcome.signum if outcome.stopped else 0
    if not outcome.stopped and outcome.evaluation is None:  # not process 0: it reports
        return 0
    console.print(report.finished_text(outcome, wall))
    return 128 + outcome.signum if outcome.signum else 0


def _check_score(score: Score, spec: lifecycle.RunSpec, groups: list, specs: list) -> None:
    """Refuses, before anything trains, a ``--score`` without a sweep to rank, and a
    ``return-at:STEPS`` past the end of the run (or of one of its shape groups, ``specs``)."""
    from jaxcart.run.search import check_score

    if not spec.grid.is_sweep and not groups:
        raise cli.UsageError(
            "--score ranks the combinations of a --sweep; without one there is nothing to rank "
            "(python -m jaxcart.compare --score scores any run)"
        )
    check_score(score, [group_spec.config for group_spec in specs])


@cli.command()
def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 2 bad input, 1 a failed write, 128+signal
    when a signal stopped the training). While the run trains (planned, written, trained and
    evaluated), a first SIGINT/SIGTERM stops it at the next safe point with a checkpoint and a
    second one at once, without a traceback; before that, Ctrl-C is Python's
    :class:`KeyboardInterrupt` (one line from :func:`jaxcart.cli.command_main`)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    # the command line, after the --config file's options when it names one (so that the
    # command line's override the file's); the file's ignored keys are printed, a line each
    args = configfile.parse_with_config(build_parser(), argv)
    opts = TrainOptions.from_args(args, argv)
    from jaxcart import report  # the training's modules: not for --help

    console = report.ConsoleReport(sys.stdout)
    console.progress_bar = not opts.quiet
    try:
        return _train(opts, console)
    except RuntimeError as exc:  # JAX's runtime errors are RuntimeErrors
        if "RESOURCE_EXHAUSTED" not in str(exc):
            raise  # anything else is jaxcart's bug: its traceback is the report
        console.close()
        print(
            "error: the device ran out of memory compiling or running the training; "
            "train fewer runs at once (--wave-size N, or fewer --num-seeds)",
            file=sys.stderr,
        )
        return 1


def cli_main(argv: list[str] | None = None) -> NoReturn:
    """The process entry (the ``jaxcart-train`` script, ``python -m jaxcart.train``):
    :func:`main` through :func:`jaxcart.cli.command_main`, on one CPU device per core; exits."""
    cli.command_main(main, argv, all_cores=True)


if __name__ == "__main__":
    cli_main()

"""``python -m jaxcart.tune``: hyperparameter search on Optuna, trials x seeds in one program.

Train's options are every trial's base (``--preset``, ``--total-timesteps``, ...); ``--space``
says what the search draws. Each batch of ``--batch-trials`` trials trains as one program per
shape (:mod:`jaxcart.run.search`) into a run directory under ``--out``; the study lives in
``--storage`` (SQLite by default, any URL Optuna accepts), so the same command run again, or
in another process or on another machine, continues it to ``--trials`` finished trials. It
ends by training the top ``--heldout-top`` trials again on fresh seeds, ranked by those::

    python -m jaxcart.tune --trials 32 --batch-trials 8 --num-seeds 4 \\
        --space learning_rate=log:1e-5:1e-2 --space clip_coef=0.1:0.3
"""

from __future__ import annotations

import argparse
import functools
import shlex
import signal
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

from jaxcart import cli, configfile, train
from jaxcart.analysis import stats
from jaxcart.analysis.summary import Score
from jaxcart.run import search
from jaxcart.run.spec import Hooks

DEFAULT_STORAGE = "sqlite:///runs/study.db"
DEFAULT_STUDY = "jaxcart"


def build_parser() -> argparse.ArgumentParser:
    """The CLI: :class:`TuneOptions`' options (the search's, every trial's), one option per
    config field."""
    parser = cli.Parser(
        prog="python -m jaxcart.tune",
        description="Search PPO's hyperparameters with Optuna (ask-and-tell, TPE by default): "
        "each batch of trials x seeds trains as one compiled program; the study lives in a "
        "database, so the same command continues it after an interruption or in other processes.",
    )
    trial = cli.add_options(parser, TuneOptions, "search")[TRIAL]
    # what every trial passes on to train unchanged: train's own options
    cli.add_options(trial, train.TrainOptions, "", ("preset", "eval_episodes", "no_compile_cache"))
    train._add_config_options(parser.add_argument_group("PPO config, the trials' base"))
    return parser


SPACE_HELP = (
    "a config field to search (repeatable): LOW:HIGH (uniform), log:LOW:HIGH, int:LOW:HIGH, or "
    "choices A,B,C (shape settings such as num_envs=1,4,8 or hidden_sizes=64x64,32x32 group a "
    "batch into one program per shape); one_minus_FIELD draws 1 - FIELD; a named space stands "
    f"for its fields: {', '.join(search.SPACE_PRESETS)}; default: rl-zoo3's PPO float ranges "
    f"since its v2.6, {' '.join(search.DEFAULT_SPACE)}"
)
TRIAL = "every trial (as for jaxcart.train)"


@dataclass(frozen=True)
class TuneOptions:
    """Everything the command line said: nothing past :func:`main` sees argparse. Each
    :func:`~jaxcart.cli.option` field is the option ``--name``, its docstring the help."""

    trials: int = cli.option(32, type=cli.count)
    """finished trials the study should hold"""
    batch_trials: int = cli.option(8, type=cli.count)
    """trials asked and trained together"""
    space: tuple[str, ...] = cli.option((), action="append", metavar="NAME=SPEC", help=SPACE_HELP)
    score: Score = cli.option(Score("auc"), type=cli.score, metavar="SCORE")
    """what a trial is told, the IQM over its seeds of compare's score: auc (default), eval or
    return-at:STEPS"""
    storage: str = cli.option(DEFAULT_STORAGE)
    """Optuna storage URL"""
    study_name: str = cli.option(DEFAULT_STUDY)
    """the study's name in the storage"""
    sampler: str = cli.option("tpe", choices=("tpe", "random"))
    """Optuna's sampler"""
    sampler_seed: int | None = cli.option(type=int)
    """seed of the sampler"""
    pruner: str = cli.option("none", choices=("none", "median", "halving"))
    """Optuna's MedianPruner or SuccessiveHalvingPruner on the partial AUC at 8 rungs; a batch
    group stops when all its trials are pruned"""
    top: int = cli.option(5, type=cli.count)
    """trials in the final table"""
    heldout_top: int = cli.option(3, type=cli.bounded_count(minimum=0), metavar="K")
    """at the end, train the top K trials again on fresh seeds, as one batch, and rank them
    by those held-out scores (0: skip; default: 3)"""
    config: Path | None = cli.option(type=Path, metavar="FILE", group=TRIAL)
    """options from a TOML/YAML/JSON file (keys named as the options, space = [...]
    included); options on the command line override the file's"""
    num_seeds: int = cli.option(4, type=cli.count, group=TRIAL)
    """seeds per trial"""
    seed: int = cli.option(0, type=cli.seed, group=TRIAL)
    """base seed, shared by every trial"""
    out: Path | None = cli.option(type=cli.out_dir, group=TRIAL)
    """folder of the trials' run directories (default: runs/STUDY_NAME)"""
    quiet: bool = cli.option(False, action="store_true", group=TRIAL)
    """no line per batch"""
    base: train.TrainOptions = field(default_factory=train.TrainOptions)
    """Every trial's options, as train reads its own."""

    @classmethod
    def from_args(cls, args: argparse.Namespace, argv: list[str]) -> TuneOptions:
        """The search's options, and the trials' base as train reads its own (its own
        ``--score`` ranks no sweep; ``--out`` defaults to runs/STUDY_NAME)."""
        base = train.TrainOptions.from_args(args, argv)
        out = args.out or Path("runs") / args.study_name
        return cli.options_from(cls, args, base=replace(base, score=None, out=out))


def retrain_command(opts: TuneOptions, params: dict, out: str, seed: int) -> str:
    """The ``python -m jaxcart.train`` command that trains a trial again: the tune command's
    base options, the trial's values, its number of seeds from base seed ``seed``."""
    base, parser = opts.base, train.build_parser()
    words = ["python", "-m", "jaxcart.train", *(["--preset", base.preset] if base.preset else [])]
    static, traced = search.split_params(params)
    for name, value in {**base.overrides, **static, **traced}.items():  # as a file's keys
        words += configfile.option_tokens(configfile.action_of(name, parser, False), value)
    words += ["--num-seeds", str(base.num_seeds), "--seed", str(seed)]
    if base.eval_episodes:
        words += ["--eval-episodes", str(base.eval_episodes)]
    words += ["--out", out]
    return shlex.join(words)


def _iqm_text(scores: Sequence[float]) -> str:
    """``412.3 [380.0, 450.5]``: the IQM of per-seed ``scores`` ``[num_seeds]`` and its
    bootstrap interval (the seeds' range with too few seeds: :func:`stats.interval_label`)."""
    return stats.bootstrap_ci(list(scores), stats.iqm).format()


def _scores(trial: object) -> list[float]:
    """A complete trial's per-seed scores ``[num_seeds]``, as its batch told them."""
    return trial.user_attrs.get("scores", [trial.value])


def _print_batch(out: Path, results: list, started: float) -> None:
    """A batch group's line: its trials, its best trial's IQM, how many were pruned."""
    best = max(results, key=lambda r: float(stats.iqm(r.scores)))
    pruned = sum(r.pruned for r in results)
    print(
        f"trials {', '.join(str(r.number) for r in results)}: best #{best.number} "
        f"{_iqm_text(best.scores)} ({stats.interval_label(len(best.scores))})"
        f"{f' | {pruned} pruned' if pruned else ''} | {out} | "
        f"{time.monotonic() - started:.1f} s so far",
        flush=True,
    )


def _print_summary(opts: TuneOptions, study: object, space: dict) -> list:
    """The study's trials by state and the top trials with their intervals over seeds;
    returns every complete trial, best first."""
    trials = study.get_trials(deepcopy=False)
    states = [t.state.name.lower() for t in trials]
    counted = {s: states.count(s) for s in ("complete", "pruned", "fail", "running")}
    shown = ", ".join(f"{n} {s}" for s, n in counted.items() if n)
    print(f"study {opts.study_name!r} in {opts.storage}: {shown}")
    ranked = sorted((t for t in trials if t.state.name == "COMPLETE"), key=lambda t: -t.value)
    rows = [
        [rank, t.number, _iqm_text(_scores(t))]
        + [f"{v:.4g}" if isinstance(v, float) else v for v in map(t.params.get, space)]
        + [t.user_attrs.get("run_dir", "")]
        for rank, t in enumerate(ranked[: opts.top], 1)
    ]
    if rows:
        n = opts.base.num_seeds
        print(f"\nTop trials by the IQM of --score {opts.score.label} over {n} seed(s):")
        header = ["rank", "trial", f"iqm [{stats.interval_label(n)}]", *space, "run directory"]
        print(cli.format_table(rows, header))
    return ranked


def _heldout(opts: TuneOptions, tuner: search.Tuner, ranked: list) -> None:
    """Trains the top ``--heldout-top`` trials again on fresh seeds, ranks them by those
    scores, records the seed in the study, and prints the winner's retrain command on seeds
    fresher still (without held-out runs: the search's best)."""
    if not ranked:
        return
    n, seed = opts.base.num_seeds, search.heldout_seed(tuner.study, opts.base.seed)
    best, out = ranked[0], f"runs/{opts.study_name}-best"
    run_dirs = [best.user_attrs.get("run_dir", "")]
    if opts.heldout_top:
        top = {t.number: t for t in ranked[: opts.heldout_top]}
        print(
            f"\nheld-out check: the top {len(top)} trained again on {n} fresh seed(s), base "
            f"seed {seed} (the search's: {opts.base.seed}), as one batch",
            flush=True,
        )
        results = tuner.heldout(list(top.values()), seed)
        results.sort(key=lambda r: -float(stats.iqm(r.scores)))
        scores = {str(r.number): [float(x) for x in r.scores] for r in results}
        tuner.study.set_user_attr("heldout", {"seed": seed, "scores": scores})
        rows = [
            [i, r.number, _iqm_text(_scores(top[r.number])), _iqm_text(r.scores)] + [r.run_dir]
            for i, r in enumerate(results, 1)
        ]
        seeds = stats.interval_label(n)
        header = ["rank", "trial", f"search iqm [{seeds}]", f"held-out iqm [{seeds}]"]
        print(cli.format_table(rows, [*header, "held-out run directory"]))
        best, run_dirs = top[results[0].number], [str(r.run_dir) for r in results]
        print(f"\nbest on held-out seeds: trial {best.number}; train it on other fresh seeds with:")
    else:
        print(f"\nbest: trial {best.number}; train it again on fresh seeds with:")
    print(f"  {retrain_command(opts, best.params, out, seed + 1)}")
    print(f"  python -m jaxcart.compare {' '.join(run_dirs)} {out} --score {opts.score.label}")
    print(
        f"  optuna-dashboard {opts.storage}   # the study in a browser (pip install optuna-dashboard)"
    )


def _note(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def _on_wait(running: int) -> None:
    expiry = time.strftime("%H:%M:%S", time.localtime(time.time() + search.STALE_GRACE_SECONDS))
    _note(
        f"note: waiting for {running} trial(s) running elsewhere: another process's finish; "
        f"a killed process's are marked failed by about {expiry} and asked again"
    )


def _on_signal(signum: int) -> None:
    _note(f"\n{signal.Signals(signum).name}: stopping; this batch's trials are marked failed")


def _tune(opts: TuneOptions) -> int:
    spec = opts.base.run_spec()
    space = search.parse_space(list(opts.space), spec.config, opts.score)
    for param in space:
        if search.field_of(param) in opts.base.overrides:
            flag = "--" + search.field_of(param).replace("_", "-")
            raise cli.UsageError(f"{flag} and --space {param} both given; keep one")
    study, storage = search.open_study(
        opts.storage, opts.study_name, opts.sampler, opts.pruner, opts.sampler_seed
    )
    started = time.monotonic()
    on_batch = None if opts.base.quiet else functools.partial(_print_batch, started=started)
    hooks, options = Hooks(on_signal=_on_signal), opts.base.run_options()
    tuner = search.Tuner(
        study, storage, space, spec, opts.base.out, options, opts.score, hooks, on_batch, _on_wait
    )
    print(
        f"jaxcart tune | study {opts.study_name!r} in {opts.storage} | {opts.trials} trials, "
        f"{opts.batch_trials} at a time x {spec.num_seeds} seed(s) | score {opts.score.label} | "
        f"sampler {opts.sampler}, pruner {opts.pruner} | out {opts.base.out}",
        flush=True,
    )
    with search.storage_errors(opts.storage):  # a read-only database, a lost server
        try:
            tuner.run(opts.trials, opts.batch_trials)
            if tuner.pruned_seconds_saved:
                saved = tuner.pruned_seconds_saved
                print(f"pruning stopped groups early: about {saved:.1f} s of training saved")
            _heldout(opts, tuner, _print_summary(opts, study, space))
        except search.BatchStopped as exc:
            name = signal.Signals(exc.signum).name
            _note(f"stopped by {name}; run the same command again to continue the study")
            return 128 + exc.signum
        except KeyboardInterrupt:
            _note("interrupted; run the same command again to continue the study")
            return 130
    return 0


@cli.command()
def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 2 bad input, 128+signal when stopped)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    args = configfile.parse_with_config(build_parser(), argv)  # the command line's win
    return _tune(TuneOptions.from_args(args, argv))


if __name__ == "__main__":
    cli.command_main(main, all_cores=True)  # one CPU device per core, as jaxcart.train

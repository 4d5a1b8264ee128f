"""What the commands print: tables, the run header and summary line, the progress bar.

Nothing here trains or writes files; :class:`ConsoleReport` turns a run's lifecycle events
(:class:`jaxcart.run.spec.Hooks`) into terminal output.
"""

from __future__ import annotations

import shlex
import signal
import sys
from collections.abc import Callable
from typing import IO, TYPE_CHECKING

import numpy as np

from jaxcart.analysis import stats
from jaxcart.analysis.summary import Score
from jaxcart.cli import format_table
from jaxcart.core import physics, solved
from jaxcart.core.config import PRESETS, config_fields, preset
from jaxcart.run import sweep as sweeps
from jaxcart.run.progress import ProgressBar, new_bar
from jaxcart.rundir.layout import CHECKPOINT_FILE, CONFIG_FILE, GROUPS_FILE
from jaxcart.rundir.reader import group_label

if TYPE_CHECKING:  # annotations only: the lifecycle does not import this module
    from pathlib import Path

    from jaxcart.engine.loop import Progress
    from jaxcart.run.spec import Outcome, Run, RunSpec
    from jaxcart.run.structural import GroupsOutcome
    from jaxcart.run.waves import WavePlan


MAX_TABLE_ROWS = 100
"""Seeds listed on the terminal; evaluation.json holds them all."""


def header_line(
    run: Run | RunSpec, device_count: int, backend: str, out: Path | str | None = None
) -> str:
    """``jaxcart PPO | preset sb3 + learning_rate=0.001 | 2 seed(s) x 81,920 env steps (...) |
    2 cpu device(s) | out ...``: of a run, or of the spec a dry run plans (``out``: what it
    says instead of a run directory)."""
    grid, config = run.grid, run.config
    combos = f"{grid.num_combos} combination{'s' if grid.num_combos != 1 else ''}"
    what = f"{combos} x {grid.num_seeds} seed(s)" if grid.is_sweep else f"{grid.num_seeds} seed(s)"
    changed = []  # what the config changes from its preset, spelled as on the command line
    base = preset(run.preset) if run.preset in PRESETS else config
    for f in config_fields():
        value = getattr(config, f.name)
        if value != getattr(base, f.name):
            text = ",".join(map(str, value)) if isinstance(value, tuple) else value
            changed.append(f"{f.name}={text:g}" if isinstance(value, float) else f"{f.name}={text}")
    modified = f" + {', '.join(changed)}" if changed else ""
    return (
        f"jaxcart PPO | preset {run.preset}{modified}{physics_text(run)} | {what} x "
        f"{config.env_steps_per_seed:,} env steps "
        f"({config.num_iterations} iterations of {config.num_envs} env(s) x {config.num_steps} steps) "
        f"| {device_count} {backend} device(s) | out {run.out if out is None else out}"
    )


def physics_text(run: Run) -> str:
    """`` | physics length=1, randomized masspole in [0.05, 0.2] per run``: the run's physics
    where it is not CartPole-v1's (``""`` otherwise)."""
    spec = getattr(run, "spec", run)
    overrides = physics.overrides(spec.env_params) if hasattr(spec, "env_params") else {}
    parts = [physics.describe(overrides)] if overrides else []
    parts += [
        f"randomized {r.name} in [{r.low:g}, {r.high:g}] per {r.per}"
        for r in getattr(spec, "randomize", ())
    ]
    return f" | physics {', '.join(parts)}" if parts else ""


def seed_rows(returns: np.ndarray, env_id: str) -> list[list]:
    """``seed, mean, min, solved`` of each seed's greedy returns ``[num_seeds, episodes]``:
    the table after training and ``python -m jaxcart.evaluate``'s."""
    flags = solved.is_solved(returns, env_id)
    return [
        [s, f"{r.mean():.1f}", f"{r.min():.0f}", "yes" if ok else "no"]
        for s, (r, ok) in enumerate(zip(returns, flags))
    ]


def mean_rule(env_id: str) -> str:
    """`` (solved: mean >= -100)`` for an env solved by its mean return (``""``: CartPole's
    every episode scores 500)."""
    rule, threshold = solved.SOLVED_BY[env_id]
    return f" (solved: mean >= {threshold:g})" if rule == "mean" else ""


def evaluation_rows(outcome: Outcome) -> tuple[list[list], list[str]]:
    """The per-seed table of a run without a sweep."""
    ev, final, diverged = outcome.evaluation, outcome.final_return, outcome.diverged_at
    rows = seed_rows(ev.gym_returns[:MAX_TABLE_ROWS], ev.env)
    for s, row in enumerate(rows):
        row[-1] += f" (diverged@{diverged[s]})" if diverged[s] >= 0 else ""
        row += [f"{ev.jax_returns[s].mean():.1f}", f"{final[s]:.1f}"]
    header = ["seed", "gym mean", "gym min", "solved", "jaxcart mean", "train ep_rew_mean"]
    spec = outcome.run.spec
    # each seed's randomised physics: what it trained on (it is evaluated on the nominal)
    drawn = physics.randomized_values(spec.randomize, spec.seed, np.arange(len(rows)))
    for name, values in drawn.items():
        header.append(f"trained {name}")
        for row, value in zip(rows, values):
            row.append(f"{value:.3g}")
    if len(ev.solved) > MAX_TABLE_ROWS:
        rows.append(["...", f"{len(ev.solved) - MAX_TABLE_ROWS:,} more in evaluation.json"])
        rows[-1] += [""] * (len(header) - 2)
    return rows, header


def _rank(row: dict, ranking: list[dict]) -> str:
    """A row's rank, ``2=`` when other combinations share it (the same IQM)."""
    tied = sum(r["rank"] == row["rank"] for r in ranking) > 1
    return f"{row['rank']}{'=' if tied else ''}"


def _interval(e: dict | None, digits: int = 1) -> str:
    """A ranking's ``{value, ci_low, ci_high}`` as ``412.3 [380.0, 450.5]`` (``-``: none)."""
    return "-" if e is None else stats.Estimate(**e).format(digits)


Column = tuple[str, Callable[[dict], object]]
"""A ranking table's column: its header and its cell of a ranking row."""


def _ranking_columns(ranking: list[dict], names: list[str], num_seeds: int) -> list[Column]:
    """The columns every ranking shows: the swept values and the IQM with its interval."""
    values = [(name, lambda r, name=name: f"{r[name]:g}") for name in names]
    label = ranking[0]["score"] if ranking else "eval"  # IQM gym return [95% CI], IQM auc [...]
    iqm = f"IQM {'gym return' if label == 'eval' else label} [{stats.interval_label(num_seeds)}]"
    return [*values, (iqm, lambda r: _interval(r["iqm"]))]


def _table(ranking: list[dict], columns: list[Column]) -> str:
    """A ranking as a table: one row per ranked combination."""
    header = [h for h, _ in columns]
    return format_table([[cell(r) for _, cell in columns] for r in ranking], header)


def sweep_table(outcome: Outcome) -> str:
    """The ranking table of a sweep: each combination's rank, the IQM of its seeds' scores
    (``--score``, by default the mean greedy Gymnasium return) with its bootstrap interval,
    and the probability of improvement over combination 0."""
    ranking, grid = outcome.ranking, outcome.run.grid
    n, scores = grid.num_seeds, outcome.evaluation.gym_returns.mean(axis=-1)
    steps = "median_steps_to_500"  # the env's solved return (500 on CartPole-v1)
    reached, ci = solved.reached_label([outcome.run.config.env]), stats.interval_label(n)
    columns = [
        ("rank", lambda r: _rank(r, ranking)),
        ("combo", lambda r: r["combination"]),
        *_ranking_columns(ranking, list(outcome.run.sweep), n),
        ("gym mean", lambda r: f"{scores[grid.runs_of(r['combination'])].mean():.1f}"),
        (f"P(> combo 0) [{ci}]", lambda r: _interval(r["probability_of_improvement"], 2)),
        ("solved", lambda r: f"{r['solve_rate']:.0%}"),
        ("final ep_rew_mean", lambda r: f"{r['final_return']:.1f}"),
        (f"median steps to a {reached} episode", lambda r: steps_text(r[steps])),
        (f"reached {reached}", lambda r: f"{r['seeds_reaching_500']}/{n}"),
        ("diverged", lambda r: f"{r['seeds_diverged']}/{n}"),
    ]
    return _table(ranking, columns)


SWEEP_COLUMNS = (
    "IQM: interquartile mean (middle 50%) of the seeds' scores ({score}), which ranks the "
    "combinations (the same IQM, the same rank); gym mean: the plain mean of the seeds' mean "
    "greedy Gymnasium returns (the plot's 'mean return'); final ep_rew_mean: the last 100 "
    "training episodes, mean over seeds"
)
"""The line under the sweep table: the IQM and the plain mean are different statistics (of
the same per-seed scores by default), so they differ whenever the seeds do."""


def steps_text(steps: float) -> str:
    """Env steps as a table cell: ``81,920``, or ``never`` (infinite)."""
    return f"{steps:,.0f}" if np.isfinite(steps) else "never"


def ranking_lines(ranking: list[dict]) -> str:
    """The lines under a ranking table: what it cannot tell (saturation, ties), if any."""
    return "".join(f"\n{line}" for line in sweeps.ranking_notes(ranking))


def results_text(outcome: Outcome) -> str:
    """The evaluation table (or the sweep ranking) after a finished run."""
    episodes, grid = outcome.evaluation.episodes, outcome.run.grid
    env_id = outcome.run.config.env
    if grid.is_sweep:
        rule = solved.solved_definition(env_id).format(episodes=episodes)
        score = Score.parse(outcome.ranking[0]["score"])
        return (
            f"\nSweep ranking ({grid.num_seeds} seed(s) each; solved = {rule}):\n"
            f"{sweep_table(outcome)}{ranking_lines(outcome.ranking)}\n"
            f"{SWEEP_COLUMNS.format(score=score.definition([env_id]))}\n"
            f"per-combination results: {outcome.run.out}/combo-NNN/ (sweep.json ranks them)"
        )
    overrides = physics.overrides(outcome.run.spec.env_params)
    on = f" with {physics.describe(overrides)}" if overrides else ""
    nominal = " (nominal physics)" if outcome.run.spec.randomize else ""
    table = format_table(*evaluation_rows(outcome))
    return (
        f"\nGreedy evaluation, {episodes} episodes per seed in gymnasium.make('{env_id}')"
        f"{on}{nominal}{mean_rule(env_id)}:\n{table}\n{evaluation_columns_text(episodes)}"
    )


def evaluation_columns_text(episodes: int) -> str:
    """The one line under the evaluation table that says what each column is over: the two
    greedy means start from different states, so they differ for a policy that does not
    solve every start (which is not a parity bug)."""
    last = solved.EVAL_SEED + episodes - 1
    return (
        f"gym: {episodes} greedy episodes in Gymnasium (reset seeds {solved.EVAL_SEED}..{last}); "
        f"jaxcart mean: {episodes} greedy episodes in jaxcart's JAX env from other start "
        "states, so it differs unless the policy solves every start; train ep_rew_mean: the "
        "last 100 training episodes (sampled actions)"
    )


def summary_line(outcome: Outcome, wall_seconds: float) -> str:
    """``solved 2/2 run(s) | wall ... | N env steps at M steps/s ... on D device(s)``, with
    ``(best policies 2/2)`` after the count when the runs kept their best; after a resume,
    the times and steps are this session's, and say so, with the training time in all added
    where the run records it."""
    ev = outcome.evaluation
    steps, run_s, compile_s = outcome.env_steps, outcome.train_seconds, outcome.compile_seconds
    train, session = f"train {run_s:.1f} s", ""
    if outcome.run.resumed_from is not None:
        session = " this session"
        train += session
        # the state's elapsed spans every session of a run in one wave; in waves, only the
        # output files record the earlier waves' times
        if outcome.result is not None and outcome.run.plan.num_waves == 1:
            train += f" and {float(outcome.result.state.elapsed):.1f} s in all"
    rate = ""  # none when this session trained nothing (a resume that only evaluated)
    if run_s > 0:
        rate = (
            f" at {steps / run_s:,.0f} steps/s ({steps / (run_s + compile_s):,.0f} incl. compile)"
        )
    kept = ""  # keep_best: the verdict of the policies a user takes away too
    if (best := ev.best_solved) is not None:
        kept = f" (best policies {int(best.sum())}/{len(best)})"
    return (
        f"\nsolved {int(ev.solved.sum())}/{len(ev.solved)} run(s){kept} | wall {wall_seconds:.1f} s "
        f"(compile {compile_s:.1f} s, {train}, eval {ev.seconds:.1f} s) | "
        f"{steps:,} env steps{session}{rate} on {outcome.num_devices} device(s)"
    )


def finished_text(outcome: Outcome, wall_seconds: float) -> str:
    """What a run prints once it is done (its evaluation, the summary line, its directory and
    what to run next), or once it stopped (where, and how to resume)."""
    if outcome.stopped:
        return stopped_text(outcome, resume_command(outcome.run.out))
    lines = [results_text(outcome), summary_line(outcome, wall_seconds)]
    lines += [f"run directory: {outcome.run.out}", next_steps_text(outcome)]
    return "\n".join(lines)


def groups_finished_text(done: GroupsOutcome, wall_seconds: float) -> str:
    """What a structural sweep prints once its groups are done (every combination of every
    shape group ranked together, then where and what next), or once one of them stopped."""
    if done.stopped:
        last = done.outcomes[-1] if done.outcomes and done.outcomes[-1].stopped else None
        hint = resume_command(done.out)
        return stopped_text(last, hint) if last else f"stopped; resume with: {hint}"
    ranking, groups = done.ranking, done.groups
    columns = [
        ("rank", lambda r: _rank(r, ranking)),
        ("group", lambda r: r["group"]),
        ("shapes", lambda r: group_label({k: r[k] for k in groups[r["group"]]})),
        *_ranking_columns(ranking, list(done.sweep), done.num_seeds),
        ("solved", lambda r: f"{r['solve_rate']:.0%}"),
        ("final ep_rew_mean", lambda r: f"{r['final_return']:.1f}"),
    ]
    what = f"{len(groups)} shape group(s) ({done.num_seeds} seed(s) each)"
    return (
        f"\nStructural sweep ranking, {what}:\n{_table(ranking, columns)}{ranking_lines(ranking)}"
        f"\nwall {wall_seconds:.1f} s | structural sweep directory: {done.out} "
        f"({GROUPS_FILE} ranks every combination)\nnext:\n"
        f"  python -m jaxcart.plot {done.out}      # every group's curves, into its curves.png\n"
        f"  python -m jaxcart.compare {done.out}   # statistics of every combination"
    )


def next_steps_text(outcome: Outcome) -> str:
    """The commands a user runs next on a finished run: its learning curves, a GIF of a
    policy (the first solved seed, else seed 0; a sweep's best-ranked combination; each
    seed's best policy when the run kept it) and a
    comparison (with another run; a sweep's combinations with each other). Paths are quoted
    for the shell."""
    out, grid, q, ev = outcome.run.out, outcome.run.grid, shlex.quote, outcome.evaluation
    kept = ev.best_solved is not None  # keep_best: the best policies are what to watch
    run, solved_seeds = q(str(out)), ev.best_solved if kept else ev.solved
    where, pick = out, ""  # the directory of the policy to watch, and how evaluate picks it
    if grid.is_sweep:
        best = outcome.ranking[0]["combination"] if outcome.ranking else 0
        solved_seeds = solved_seeds[grid.runs_of(best)]
        where, pick = out / f"combo-{best:03d}", f" --combination {best}"
    seed = int(np.argmax(solved_seeds))  # the first solved seed (none: seed 0)
    pick += (f" --seed-index {seed}" if seed else "") + (" --policy best" if kept else "")
    watch = f"python -m jaxcart.evaluate {run}{pick} --gif {q(str(where / f'seed{seed}.gif'))}"
    if grid.is_sweep:
        commands = [
            (
                f"python -m jaxcart.plot {run} --out {q(str(out / 'curves.png'))}",
                "learning curves of every combination",
            ),
            (watch, f"watch seed {seed} of the best-ranked combination"),
            (f"python -m jaxcart.compare {run}", "the combinations' statistics"),
        ]
    else:
        kind = "best policy" if kept else "policy"
        commands = [
            (f"python -m jaxcart.plot {run}", "learning curves, into its curves.png"),
            (watch, f"watch seed {seed}'s {kind}"),
            (f"python -m jaxcart.compare {run} OTHER_RUN", "statistics against another run"),
        ]
    if gif_refusal(outcome.run.config.env):  # no renderer for this env here
        commands = [(c, why) for c, why in commands if "--gif" not in c]
    width = max(len(c) for c, _ in commands)
    return "next:\n" + "\n".join(f"  {c.ljust(width)}  # {why}" for c, why in commands)


def gif_refusal(env_id: str) -> str | None:
    """Why ``--gif`` cannot draw ``env_id`` on this machine, or None: Gymnasium's renderer
    (pygame) draws every env, and without it the env's own
    :attr:`~jaxcart.core.envs.Env.draw_frame` (CartPole's, with Pillow)."""
    from jaxcart.core import envs
    from jaxcart.results.gif import pygame_available

    if pygame_available() or envs.make(env_id).draw_frame is not None:
        return None
    return f"--gif of {env_id} needs Gymnasium's renderer: pip install pygame"


def stopped_text(outcome: Outcome, resume_hint: str) -> str:
    """What a stopped run prints: where it stopped and how to resume."""
    run, (wave, iteration) = outcome.run, outcome.stopped_at or (0, 0)
    where = f"at {_at(run, iteration, wave)}"
    if outcome.result is None and wave == 0:
        where = "before training started"
    return f"stopped {where}; checkpoint saved in {run.out}\nresume with: {resume_hint}"


def _at(run: Run, iteration: int, wave: int) -> str:
    """``iteration 12/40``, or in waves ``iteration 3/40 of wave 2/5``."""
    waves = f" of wave {wave + 1}/{run.plan.num_waves}" if run.plan.num_waves > 1 else ""
    return f"iteration {iteration}/{run.config.num_iterations}{waves}"


def plan_text(plan: WavePlan, spec: RunSpec) -> str:
    """The plan: runs, waves, memory and estimated time (and what the time assumes); then
    how the width was chosen."""
    text = plan.describe("runs" if spec.grid.is_sweep else "seeds")
    if plan.wave_seconds:  # a model (jaxcart.run.waves), not a measurement of this machine
        text += (
            "\nthe time assumes an otherwise idle machine (a busy one can be several times "
            "slower); the run measures its own speed from its first chunks"
        )
    return f"{text}\n{plan.why}" if plan.why else text


def resume_command(out: Path) -> str:
    """``python -m jaxcart.train --resume RUN`` with the path quoted for the shell."""
    from jaxcart.run.lifecycle import RESUME_HINT

    return RESUME_HINT.format(out=shlex.quote(str(out)))


def checkpoint_text(run: Run) -> str:
    """Which iteration the checkpoint on disk holds, as the run knows it (``iteration
    12/40``, ``iteration 3/40 of wave 2/5``); "" when none was saved yet."""
    meta = run.directory.checkpoint_meta
    return "" if meta is None else _at(run, int(meta["iteration"]), int(meta.get("wave", 0)))


def write_failed_text(run: Run | None, exc: OSError) -> str:
    """The one line after a write failed (ENOSPC, EROFS, EACCES, ...)."""
    what = f"error: cannot write {exc.filename or 'a file'}: {exc.strerror or exc}"
    if run is None or not (run.out / CHECKPOINT_FILE).exists():
        return what
    at = checkpoint_text(run)
    return (
        f"{what}; the last checkpoint{f' (at {at})' if at else ''} is intact: once the disk "
        f"has room, resume with: {resume_command(run.out)}"
    )


def interrupted_text(run: Run | None, signum: int | None) -> str:
    """The one line after a second signal stopped the process at once: which iteration the
    checkpoint on disk holds, and how to resume."""
    if run is None or not (run.out / CONFIG_FILE).exists():
        return "stopped at once; no run directory was written"
    at = checkpoint_text(run)
    if not at:
        return (
            f"stopped at once before the first checkpoint; resuming {run.out} starts from "
            f"iteration 0: {resume_command(run.out)}"
        )
    return (
        f"stopped at once; the checkpoint in {run.out} (at {at}) is intact: resume with: "
        + resume_command(run.out)
    )


class ConsoleReport(ProgressBar):
    """Lifecycle hooks that print: the header, compile time, the progress bar (a
    :class:`~jaxcart.run.progress.ProgressBar`), the measured pace, divergences and signals.
    ``out`` gets the lines, stderr the bar and warnings; ``progress_bar=False`` (``--quiet``)
    leaves out the bar and the pace line."""

    def __init__(self, out: IO[str], progress_bar: bool = True) -> None:
        super().__init__(enabled=progress_bar)
        self.out = out
        self.init_bar = None
        self.compiled_said = False
        self.pace_start: tuple[float, int] | None = None  # (elapsed, iteration) at first chunk

    def print(self, text: str) -> None:
        print(text, file=self.out, flush=True)

    def on_start(self, run: Run, device_count: int, backend: str) -> None:
        super().on_start(run, device_count, backend)
        self.print(header_line(run, device_count, backend))
        runs = len(run.plan.wave(run.plan.num_waves - 1))  # the others divide over the devices
        if runs < device_count and run.plan.num_waves == 1:
            self.print(f"{runs} run(s) on {runs} of the {device_count} devices (one each)")
        elif runs % device_count:
            padded = -(-runs // device_count) * device_count
            last = " in the last wave" if run.plan.num_waves > 1 else ""
            self.print(
                f"{runs} runs{last} padded to {padded} so that each of the {device_count} "
                f"devices takes {padded // device_count} ({padded - runs} padding run(s) "
                "computed and discarded)"
            )
        if run.plan.num_waves > 1:  # a new run's plan, or a resumed one's with today's memory
            self.print(plan_text(run.plan, run.spec))
        if run.resumed_from is not None:
            self.print(f"resuming from {_at(run, run.resumed_from, run.resume_wave)}")

    def on_compiled(self, seconds: float) -> None:
        if not self.compiled_said:  # a later wave's program is cached
            self.print(f"compiled the fused training step in {seconds:.2f} s")
            self.compiled_said = True
        super().on_compiled(seconds)

    def on_chunk(self, progress: Progress) -> None:
        if self.progress_bar:
            self._measure_pace(progress)
        super().on_chunk(progress)

    def _measure_pace(self, progress: Progress) -> None:
        """Once, after 10 s of training past the first chunk (which includes warm-up): the
        measured time per iteration and what it means for the waves left."""
        if self.pace_start is None:
            self.pace_start = (progress.elapsed, progress.iteration)
            return
        seconds = progress.elapsed - self.pace_start[0]
        iterations = progress.iteration - self.pace_start[1]
        if self.pace_start[1] < 0 or seconds < 10 or iterations <= 0:
            return
        from jaxcart.run.waves import format_duration

        plan, pace = self.run.plan, seconds / iterations
        wave_seconds = pace * self.run.config.num_iterations
        left = pace * (progress.num_iterations - progress.iteration)
        waves_after = plan.num_waves - 1 - self.wave_offset // max(1, progress.num_iterations)
        left += wave_seconds * waves_after
        text = f"measured {pace:.3g} s per iteration: {format_duration(wave_seconds)} per wave"
        if plan.num_waves > 1:
            text += f", about {format_duration(left)} left for {plan.num_waves:,} waves"
        self.write(text)
        self.pace_start = (0.0, -1)  # said once

    def on_diverged(self, run_name: str, iteration: int) -> None:
        self.write(
            f"{run_name} diverged at iteration {iteration} (non-finite loss or parameters): "
            "it stops there with its last finite parameters; other runs continue"
        )

    def on_signal(self, signum: int) -> None:
        what = "stopping at the next safe point and saving a checkpoint (again to stop at once)"
        print(f"\n{signal.Signals(signum).name} received: {what}...", file=sys.stderr, flush=True)

    def on_init(self, done: int, total: int) -> None:
        """A progress bar for initialising large runs (on the host, seconds per 10^4 runs)."""
        if total < 4096 or not self.progress_bar:
            return
        if self.init_bar is None:
            self.init_bar = new_bar(total, "initialising", "run")
        self.init_bar.update(done - self.init_bar.n)
        if done + 1024 >= total:
            self.init_bar.update(total - self.init_bar.n)
            self.init_bar.close()
            self.init_bar = None

    def close(self) -> None:
        super().close()
        if self.init_bar is not None:
            self.init_bar.close()
        self.init_bar = None

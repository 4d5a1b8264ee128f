"""Greedy (argmax) evaluation, in jaxcart's JAX env and in Gymnasium's own CartPole-v1.

"Solved" means every one of the evaluation episodes (20 by default) scores 500.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING

from jaxcart import cli
from jaxcart.core.solved import DEFAULT_ENV, EVAL_SEED, GYMNAX_ENVS, NUM_EVAL_EPISODES
from jaxcart.rundir import layout

if TYPE_CHECKING:  # JAX loads once the command line is read: --help needs none of it
    from jaxcart.rundir.policy import RunParams


def build_parser() -> argparse.ArgumentParser:
    """The ``python -m jaxcart.evaluate`` command line."""
    parser = cli.Parser(
        prog="python -m jaxcart.evaluate",
        description="Evaluate every seed of a jaxcart run greedily in Gymnasium's own "
        "CartPole-v1 (solved = every episode scores 500); optionally render one seed's "
        "policy to an animated GIF. A run that did not finish is evaluated from its last "
        "checkpoint (and says so); a sweep directory, every combination.",
    )
    parser.add_argument(
        "run_dir", type=Path, metavar="RUN_DIR", help="a jaxcart run (or sweep) directory"
    )
    parser.add_argument(
        "--episodes",
        type=cli.bounded_count(cli.MAX_EPISODES),
        default=NUM_EVAL_EPISODES,
        help="greedy episodes per seed",
    )
    parser.add_argument(
        "--combination",
        type=int,
        default=None,
        metavar="C",
        help="only this combination of a sweep (needed with --gif)",
    )
    parser.add_argument(
        "--env-param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="evaluate on other physics: this field of CartPole's params over the run's own "
        "(repeatable; default: the physics the run trained on, a randomised field at its "
        "nominal value)",
    )
    parser.add_argument(
        "--policy",
        choices=list(layout.POLICY_FILES),
        default="final",
        help="final: the parameters at the end of training; best: each seed's best policy "
        "by the evaluation during training (a run trained with --eval-every N --keep-best)",
    )
    cli.add_trust_code_argument(parser)
    parser.add_argument("--gif", type=Path, default=None, help="also render one episode to a GIF")
    parser.add_argument("--seed-index", type=int, default=0, help="the seed --gif renders")
    parser.add_argument(
        "--gif-seed",
        type=cli.seed,
        default=EVAL_SEED,
        help=f"env.reset seed of the GIF's episode (default: {EVAL_SEED}, the first "
        "evaluation episode's)",
    )
    return parser


def _check_gif_options(args: argparse.Namespace, num_seeds: int, sweep: bool) -> None:
    if args.gif.suffix.lower() != ".gif":
        raise cli.UsageError(f"--gif {args.gif} must end in .gif")
    if not args.gif.parent.is_dir():
        raise cli.UsageError(f"--gif {args.gif}: directory {args.gif.parent} does not exist")
    if sweep and args.combination is None:
        raise cli.UsageError("--gif on a sweep needs --combination C (which policy to render)")
    if not 0 <= args.seed_index < num_seeds:
        raise cli.UsageError(
            f"--seed-index must be in [0, {num_seeds}) for this {num_seeds}-seed run, "
            f"got {args.seed_index}"
        )


def _sources(
    run_dir: Path, combination: int | None, policy: str = "final", trust_code: bool = False
) -> list[tuple[str | None, RunParams]]:
    """What to evaluate: the run, one combination, or every combination of a sweep, each
    with its label (``0 learning_rate=0.001``) in a sweep; ``policy`` final or best."""
    from jaxcart.rundir.policy import run_params
    from jaxcart.rundir.reader import read_run_config, recorded_combinations

    combos = recorded_combinations(read_run_config(run_dir))
    if not combos:
        return [(None, run_params(run_dir, combination, policy, trust_code=trust_code))]
    chosen = range(len(combos)) if combination is None else [combination]
    return [
        (_combo_label(c, combos), run_params(run_dir, c, policy, trust_code=trust_code))
        for c in chosen
    ]


def _combo_label(c: int, combos: list) -> str:
    values = combos[c] if 0 <= c < len(combos) else {}
    return f"{c} " + ",".join(f"{k}={v:g}" for k, v in values.items())


def _with_env_params(trained: RunParams, specs: list[str]) -> RunParams:
    """``trained`` evaluated on its own physics with the ``--env-param`` fields over them."""
    if not specs:
        return trained
    from jaxcart.core import physics

    values = {**physics.overrides(trained.env_params), **physics.parse_env_params(specs)}
    return dataclasses.replace(trained, env_params=physics.make_env_params(values))


def _physics_text(sources: list[tuple[str | None, RunParams]], chosen: bool) -> str:
    """`` with length=1`` when every source runs on the same non-default physics; ``""``
    for CartPole-v1's (`` with CartPole-v1's own physics`` when ``--env-param`` chose them);
    `` with each combination's physics`` when they differ."""
    from jaxcart.core import physics

    shown = {physics.describe(physics.overrides(t.env_params)) for _, t in sources}
    if len(shown) > 1:
        return " with each combination's physics"
    text = shown.pop()
    if not text:
        return " with CartPole-v1's own physics" if chosen else ""
    return f" with {text}"


def _evaluate_command(argv: list[str] | None) -> int:
    args = build_parser().parse_args(argv)
    from jaxcart.core import physics
    from jaxcart.run.greedy import evaluate_params, summarize
    from jaxcart.rundir.reader import read_run_config, recorded_combinations

    physics.parse_env_params(args.env_param)  # a bad --env-param before anything is read
    info = read_run_config(args.run_dir)
    num_seeds = int(info.get("num_seeds", 1))
    sweep = bool(recorded_combinations(info))
    env_id = info["config"].env
    if args.env_param and env_id != DEFAULT_ENV:
        raise cli.UsageError(f"--env-param sets CartPole's physics; this run trained {env_id}")
    if args.gif is not None:
        if env_id != DEFAULT_ENV:
            raise cli.UsageError(f"--gif renders CartPole-v1 only; this run trained {env_id}")
        _check_gif_options(args, num_seeds, sweep)
    sources = [
        (label, _with_env_params(trained, args.env_param))
        for label, trained in _sources(args.run_dir, args.combination, args.policy, args.trust_code)
    ]
    note = sources[0][1].note
    if note:
        print(
            f"note: parameters {note} (resume with: python -m jaxcart.train --resume "
            f"{args.run_dir})"
        )
    rows = []
    for label, trained in sources:
        summary = summarize(evaluate_params(args.run_dir, trained, args.episodes), env_id)
        rows += [
            ([label] if sweep else [])
            + [s, f"{summary['mean'][s]:.1f}", f"{summary['min'][s]:.0f}"]
            + ["yes" if summary["solved"][s] else "no"]
            for s in range(num_seeds)
        ]
    print(
        f"Greedy evaluation of {args.run_dir}"
        + (" (each seed's best policy)" if args.policy == "best" else "")
        + f", {args.episodes} episodes per seed in gymnasium.make('{env_id}')"
        f"{_physics_text(sources, bool(args.env_param))} (reset seeds {EVAL_SEED}..."
        f"{EVAL_SEED + args.episodes - 1}):"
    )
    print(cli.format_table(rows, ["combination"] * sweep + ["seed", "mean", "min", "solved"]))
    solved = sum(r[-1] == "yes" for r in rows)
    rule = "" if env_id == DEFAULT_ENV else f" (solved: mean >= {GYMNAX_ENVS[env_id]:g})"
    print(f"solved {solved}/{len(rows)} seed(s){rule}", flush=True)
    if args.gif is not None:
        _write_gif(args, sources[0][1])
    return 0


def _write_gif(args: argparse.Namespace, trained: RunParams) -> None:
    import jax

    from jaxcart.results.gif import render_gif
    from jaxcart.rundir.policy import make_policy

    one = jax.tree.map(lambda x: x[args.seed_index], trained.params)
    policy = make_policy(one, trained.config)
    gif = render_gif(policy, args.gif, seed=args.gif_seed, env_params=trained.env_params)
    print(
        f"wrote {gif.path}: seed {args.seed_index}, {gif.steps} steps, return "
        f"{gif.episode_return:.0f}, {gif.frames} frames ({gif.backend} renderer)"
    )


def main(argv: list[str] | None = None) -> int:
    """``python -m jaxcart.evaluate RUN_DIR``: prints the per-seed Gymnasium evaluation table
    and, with ``--gif``, renders seed ``--seed-index``. Returns 0, or 2 for bad input."""
    return cli.run_command(lambda: _evaluate_command(argv), also=(ValueError, ImportError))


if __name__ == "__main__":
    cli.command_main(main)

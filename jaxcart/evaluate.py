"""Greedy (argmax) evaluation, in jaxcart's JAX env and in Gymnasium's own CartPole-v1.

"Solved" means every one of the evaluation episodes (20 by default) scores 500.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxcart import cli, rundir
from jaxcart import env as cartpole
from jaxcart.config import PPOConfig
from jaxcart.networks import ActorCritic
from jaxcart.policy import RunParams, combinations, numpy_policy, run_params
from jaxcart.signals import Stopped
from jaxcart.trainer import seed_keys

NUM_EVAL_EPISODES = 20
EVAL_SEED = 1_000_000
"""Episode i of a Gymnasium evaluation is reset with seed ``EVAL_SEED + i`` (all runs alike)."""


SOLVED_RETURN = 500.0
"""CartPole-v1's maximum return: an episode that lasts until the 500-step time limit."""
SOLVED_DEFINITION = "all {episodes} greedy episodes score 500 in gymnasium.make('CartPole-v1')"


def is_solved(returns: np.ndarray) -> np.ndarray:
    """The one definition of solved: every evaluation episode scored 500.

    Args:
        returns: ``[..., episodes]``.

    Returns:
        ``[...]`` bool.
    """
    return (np.asarray(returns) >= SOLVED_RETURN).all(axis=-1)


def evaluate_gymnasium(
    policy: Callable[[np.ndarray], np.ndarray],
    num_policies: int,
    num_episodes: int = NUM_EVAL_EPISODES,
    seed: int = EVAL_SEED,
    env_id: str = "CartPole-v1",
    should_stop: Callable[[], bool] | None = None,
) -> np.ndarray:
    """Runs ``num_episodes`` greedy episodes per policy in ``gymnasium.make(env_id)``.

    Args:
        policy: maps observations ``[num_policies, num_episodes, 4]`` to actions of shape
            ``[num_policies, num_episodes]`` (a stacked :class:`NumpyPolicy`), so all policies
            and episodes advance in lockstep with one batched forward pass per step.

    Returns:
        Episode returns, ``[num_policies, num_episodes]`` float64.
    """
    import gymnasium as gym

    envs = [[gym.make(env_id) for _ in range(num_episodes)] for _ in range(num_policies)]
    obs = np.zeros((num_policies, num_episodes, 4), np.float32)
    for p, row in enumerate(envs):
        for e, env_ in enumerate(row):
            obs[p, e], _ = env_.reset(seed=seed + e)
    returns = np.zeros((num_policies, num_episodes))
    alive = np.ones((num_policies, num_episodes), bool)
    while alive.any():
        if should_stop is not None and should_stop():
            raise Stopped("evaluation interrupted")
        actions = np.asarray(policy(obs))
        for p, e in zip(*np.nonzero(alive)):
            o, r, terminated, truncated, _ = envs[p][e].step(int(actions[p, e]))
            obs[p, e] = o
            returns[p, e] += r
            if terminated or truncated:
                alive[p, e] = False
    for row in envs:
        for env_ in row:
            env_.close()
    return returns


def greedy_returns(
    params: dict,
    key: jax.Array,
    activation: str = "tanh",
    hidden_sizes: tuple[int, ...] = (64, 64),
    num_episodes: int = NUM_EVAL_EPISODES,
    env_params: cartpole.EnvParams | None = None,
) -> jax.Array:
    """Greedy returns of ``num_episodes`` jaxcart episodes, ``[num_episodes]``; jit/vmap-able."""
    env_params = env_params or cartpole.EnvParams()
    network = ActorCritic(hidden_sizes=tuple(hidden_sizes), activation=activation)
    obs, state = jax.vmap(cartpole.reset, in_axes=(0, None))(
        jax.random.split(key, num_episodes), env_params
    )

    def one_step(carry, _):
        obs, state, alive, total = carry
        action = jnp.argmax(network.logits(params, obs), axis=-1)
        obs, state, reward, terminated, truncated = jax.vmap(
            cartpole.step_env, in_axes=(0, 0, None)
        )(state, action, env_params)
        total = total + jnp.where(alive, reward, 0.0)
        alive = alive & ~(terminated | truncated)
        return (obs, state, alive, total), None

    init = (obs, state, jnp.ones((num_episodes,), bool), jnp.zeros((num_episodes,), obs.dtype))
    (_, _, _, total), _ = jax.lax.scan(one_step, init, None, length=env_params.max_episode_steps)
    return total


def summarize(returns: np.ndarray) -> dict[str, np.ndarray]:
    """Per-policy mean, min and solved flag from returns ``[P, episodes]``."""
    returns = np.asarray(returns)
    return {
        "mean": returns.mean(axis=-1),
        "min": returns.min(axis=-1),
        "solved": is_solved(returns),
    }


def evaluate_runs(
    params: dict,
    config: PPOConfig,
    seed: int,
    seed_indices: np.ndarray,
    episodes: int,
    should_stop: Callable[[], bool] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Greedy returns of every run of a training, ``([R, episodes], [R, episodes])``: in
    Gymnasium's CartPole-v1 (the same reset seeds for all) and in jaxcart's env (run r's
    episodes from ``fold_in(seed key of seed_indices[r], 1)``).

    Args:
        params: network parameters, leaves ``[R, ...]`` (NumPy).
    """
    num_runs = len(seed_indices)
    policy = numpy_policy(params, config.activation, stacked=True)
    gym_returns = evaluate_gymnasium(policy, num_runs, episodes, should_stop=should_stop)
    indices = np.asarray(seed_indices)
    keys = jax.vmap(lambda k: jax.random.fold_in(k, 1))(
        seed_keys(seed, int(indices.max()) + 1)[indices]
    )
    evaluate = jax.jit(
        jax.vmap(
            lambda p, k: greedy_returns(p, k, config.activation, config.hidden_sizes, episodes)
        )
    )
    return gym_returns, np.asarray(evaluate(params, keys))


def evaluate_run_dir(
    run_dir: str | Path, episodes: int = NUM_EVAL_EPISODES, combination: int | None = None
) -> tuple[np.ndarray, dict]:
    """Evaluates every seed of a run directory in Gymnasium's CartPole-v1: a finished run's
    ``params.npz``, or the last checkpoint of one that did not finish.

    Args:
        combination: for a sweep directory, which combination.

    Returns:
        ``(returns [num_seeds, episodes], info)`` with ``info`` the run's ``config.json``
        and ``info["note"]``: None, or where the parameters came from when the run did not
        finish (``from the checkpoint at iteration 12/40: the run did not finish``).

    Raises:
        rundir.RunDirError: not a usable run (or a sweep without ``combination``).
    """
    info = rundir.read_run_config(run_dir)
    trained = run_params(run_dir, combination)
    return _evaluate_params(run_dir, trained, episodes), {**info, "note": trained.note}


def _evaluate_params(run_dir: str | Path, trained: RunParams, episodes: int) -> np.ndarray:
    try:
        policy = numpy_policy(trained.params, trained.config.activation, stacked=True)
    except (KeyError, TypeError, ValueError) as exc:
        raise rundir.RunDirError(f"{run_dir} does not hold an actor: {exc}") from None
    return evaluate_gymnasium(policy, trained.num_seeds, episodes)


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
        "--episodes", type=int, default=NUM_EVAL_EPISODES, help="greedy episodes per seed"
    )
    parser.add_argument(
        "--combination",
        type=int,
        default=None,
        metavar="C",
        help="only this combination of a sweep (needed with --gif)",
    )
    parser.add_argument("--gif", type=Path, default=None, help="also render one episode to a GIF")
    parser.add_argument("--seed-index", type=int, default=0, help="the seed --gif renders")
    parser.add_argument(
        "--gif-seed",
        type=int,
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


def _sources(run_dir: Path, combination: int | None) -> list[tuple[str | None, RunParams]]:
    """What to evaluate: the run, one combination, or every combination of a sweep, each
    with its label (``0 learning_rate=0.001``) in a sweep."""
    combos = combinations(rundir.read_run_config(run_dir))
    if not combos:
        return [(None, run_params(run_dir, combination))]
    chosen = range(len(combos)) if combination is None else [combination]
    return [(_combo_label(c, combos), run_params(run_dir, c)) for c in chosen]


def _combo_label(c: int, combos: list) -> str:
    values = combos[c] if 0 <= c < len(combos) else {}
    return f"{c} " + ",".join(f"{k}={v:g}" for k, v in values.items())


def _evaluate_command(argv: list[str] | None) -> int:
    args = build_parser().parse_args(argv)
    if args.episodes <= 0:
        raise cli.UsageError(f"--episodes must be a positive integer, got {args.episodes}")
    info = rundir.read_run_config(args.run_dir)
    num_seeds = int(info.get("num_seeds", 1))
    sweep = bool(combinations(info))
    if args.gif is not None:
        _check_gif_options(args, num_seeds, sweep)
    sources = _sources(args.run_dir, args.combination)
    note = sources[0][1].note
    if note:
        print(
            f"note: parameters {note} (resume with: python -m jaxcart.train --resume "
            f"{args.run_dir})"
        )
    rows = []
    for label, trained in sources:
        summary = summarize(_evaluate_params(args.run_dir, trained, args.episodes))
        rows += [
            ([label] if sweep else [])
            + [s, f"{summary['mean'][s]:.1f}", f"{summary['min'][s]:.0f}"]
            + ["yes" if summary["solved"][s] else "no"]
            for s in range(num_seeds)
        ]
    print(
        f"Greedy evaluation of {args.run_dir}, {args.episodes} episodes per seed in "
        f"gymnasium.make('CartPole-v1') (reset seeds {EVAL_SEED}..."
        f"{EVAL_SEED + args.episodes - 1}):"
    )
    print(cli.format_table(rows, ["combination"] * sweep + ["seed", "mean", "min", "solved"]))
    solved = sum(r[-1] == "yes" for r in rows)
    print(f"solved {solved}/{len(rows)} seed(s)", flush=True)
    if args.gif is not None:
        _write_gif(args, sources[0][1])
    return 0


def _write_gif(args: argparse.Namespace, trained: RunParams) -> None:
    from jaxcart.render import render_gif

    one = jax.tree.map(lambda x: x[args.seed_index], trained.params)
    policy = numpy_policy(one, trained.config.activation)
    gif = render_gif(policy, args.gif, seed=args.gif_seed)
    print(
        f"wrote {gif.path}: seed {args.seed_index}, {gif.steps} steps, return "
        f"{gif.episode_return:.0f}, {gif.frames} frames ({gif.backend} renderer)"
    )


def main(argv: list[str] | None = None) -> int:
    """``python -m jaxcart.evaluate RUN_DIR``: prints the per-seed Gymnasium evaluation table
    and, with ``--gif``, renders seed ``--seed-index``. Returns 0, or 2 for bad input."""
    return cli.run_command(lambda: _evaluate_command(argv), also=(ValueError, ImportError))


if __name__ == "__main__":
    raise SystemExit(main())

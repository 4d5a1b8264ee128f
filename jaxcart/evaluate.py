"""Greedy (argmax) evaluation, in jaxcart's JAX env and in Gymnasium's own CartPole-v1.

"Solved" means every one of the evaluation episodes (20 by default) scores 500.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from jaxcart import env as cartpole

NUM_EVAL_EPISODES = 20
EVAL_SEED = 1_000_000
"""Episode i of a Gymnasium evaluation is reset with seed ``EVAL_SEED + i`` (all runs alike)."""


class NumpyPolicy:
    """Greedy actor in plain NumPy, for one or a stack of seeds.

    ``kernels[i]``/``biases[i]`` are the actor's layers; with a leading seed axis ``[S, ...]``
    when ``stacked``. Calling it on float32 observations returns argmax actions:
    ``(4,) -> int``, ``(N, 4) -> (N,)``, and when stacked ``(S, N, 4) -> (S, N)``.
    """

    def __init__(
        self,
        kernels: list[np.ndarray],
        biases: list[np.ndarray],
        activation: str,
        stacked: bool = False,
    ):
        self.kernels = [np.asarray(k, np.float32) for k in kernels]
        self.biases = [np.asarray(b, np.float32) for b in biases]
        self.activation = {"tanh": np.tanh, "relu": lambda x: np.maximum(x, 0.0)}[activation]
        self.stacked = stacked

    def logits(self, obs: np.ndarray) -> np.ndarray:
        """Policy logits for ``obs`` (any leading shape matching the stacking)."""
        x = np.asarray(obs, np.float32)
        if x.shape[-1] != 4:
            raise ValueError(
                f"expected observations with 4 values in the last axis, got shape {x.shape}"
            )
        last = len(self.kernels) - 1
        for i, (k, b) in enumerate(zip(self.kernels, self.biases)):
            if self.stacked:
                x = np.matmul(x, k) + b[:, None, :]
            else:
                x = x @ k + b
            if i < last:
                x = self.activation(x)
        return x

    def __call__(self, obs: np.ndarray):
        actions = np.argmax(self.logits(obs), axis=-1)
        return int(actions) if actions.ndim == 0 else actions


def actor_layers(params: dict) -> tuple[list, list]:
    """The actor's kernels and biases in order, from ``{"params": {"actor": ...}}``."""
    actor = params["params"]["actor"]
    names = sorted(
        (n for n in actor if n.startswith("hidden_")), key=lambda n: int(n.split("_")[1])
    )
    names.append("out")
    return [actor[n]["kernel"] for n in names], [actor[n]["bias"] for n in names]


def numpy_policy(params: dict, activation: str, stacked: bool = False) -> NumpyPolicy:
    """A :class:`NumpyPolicy` from flax params (with a leading seed axis when ``stacked``)."""
    kernels, biases = actor_layers(jax.device_get(params))
    return NumpyPolicy(kernels, biases, activation, stacked)


def evaluate_gymnasium(
    policy: Callable[[np.ndarray], np.ndarray],
    num_policies: int,
    num_episodes: int = NUM_EVAL_EPISODES,
    seed: int = EVAL_SEED,
    env_id: str = "CartPole-v1",
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
    from jaxcart.networks import ActorCritic

    env_params = env_params or cartpole.EnvParams()
    network = ActorCritic(hidden_sizes=tuple(hidden_sizes), activation=activation)
    obs, state = jax.vmap(cartpole.reset, in_axes=(0, None))(
        jax.random.split(key, num_episodes), env_params
    )

    def one_step(carry, _):
        obs, state, alive, total = carry
        action = jnp.argmax(network.apply(params, obs, method=ActorCritic.logits), axis=-1)
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
        "solved": (returns >= 500).all(axis=-1),
    }


class EvaluateUsageError(Exception):
    """A mistake on the ``python -m jaxcart.evaluate`` command line; one line, exit code 2."""


def _evaluate_parser():
    """The ``python -m jaxcart.evaluate`` argument parser (errors raise, never exit)."""
    import argparse
    from pathlib import Path

    class Parser(argparse.ArgumentParser):
        def error(self, message: str):  # one line, no usage dump
            raise EvaluateUsageError(f"{message} (see python -m jaxcart.evaluate --help)")

    parser = Parser(
        prog="python -m jaxcart.evaluate",
        description="Evaluate every seed of a jaxcart run greedily in Gymnasium's own "
        "CartPole-v1 (solved = every episode scores 500); optionally render one seed's "
        "policy to an animated GIF.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("run_dir", type=Path, metavar="RUN_DIR", help="a jaxcart run directory")
    parser.add_argument(
        "--episodes", type=int, default=NUM_EVAL_EPISODES, help="greedy episodes per seed"
    )
    parser.add_argument(
        "--gif", type=Path, default=None, help="also render one episode of a seed to this GIF"
    )
    parser.add_argument("--seed-index", type=int, default=0, help="the seed --gif renders")
    parser.add_argument(
        "--gif-seed",
        type=int,
        default=EVAL_SEED,
        help="env.reset seed of the GIF's episode (default: the first evaluation episode's)",
    )
    return parser


def main(argv: list[str] | None = None) -> int:
    """``python -m jaxcart.evaluate RUN_DIR``: prints the per-seed Gymnasium evaluation table
    and, with ``--gif``, renders seed ``--seed-index``. Returns 0, or 2 for bad input."""
    import sys

    from jaxcart import rundir
    from jaxcart.train import format_table

    try:
        args = _evaluate_parser().parse_args(argv)
        if args.episodes <= 0:
            raise EvaluateUsageError(f"--episodes must be a positive integer, got {args.episodes}")
        info = rundir.read_run_config(args.run_dir)
        num_seeds = int(info.get("num_seeds", 1))
        if args.gif is not None:
            if args.gif.suffix.lower() != ".gif":
                raise EvaluateUsageError(f"--gif {args.gif} must end in .gif")
            if not args.gif.parent.is_dir():
                raise EvaluateUsageError(
                    f"--gif {args.gif}: directory {args.gif.parent} does not exist"
                )
            if not 0 <= args.seed_index < num_seeds:
                raise EvaluateUsageError(
                    f"--seed-index must be in [0, {num_seeds}) for this {num_seeds}-seed run, "
                    f"got {args.seed_index}"
                )
        params = rundir.load_params(args.run_dir)
        try:
            policy = numpy_policy(params, info["config"].activation, stacked=True)
        except (KeyError, TypeError, ValueError) as exc:
            raise rundir.RunDirError(
                f"{args.run_dir / rundir.PARAMS_FILE} does not hold an actor: {exc}"
            ) from None

        returns = evaluate_gymnasium(policy, num_seeds, args.episodes)
        summary = summarize(returns)
        rows = [
            [
                s,
                f"{summary['mean'][s]:.1f}",
                f"{summary['min'][s]:.0f}",
                "yes" if summary["solved"][s] else "no",
            ]
            for s in range(num_seeds)
        ]
        print(
            f"Greedy evaluation of {args.run_dir}, {args.episodes} episodes per seed in "
            f"gymnasium.make('CartPole-v1') (reset seeds {EVAL_SEED}..."
            f"{EVAL_SEED + args.episodes - 1}):"
        )
        print(format_table(rows, ["seed", "mean", "min", "solved"]))
        print(f"solved {int(summary['solved'].sum())}/{num_seeds} seed(s)", flush=True)

        if args.gif is not None:
            from jaxcart.render import render_gif

            gif = render_gif(
                rundir.load_policy(args.run_dir, args.seed_index), args.gif, seed=args.gif_seed
            )
            print(
                f"wrote {gif.path}: seed {args.seed_index}, {gif.steps} steps, return "
                f"{gif.episode_return:.0f}, {gif.frames} frames ({gif.backend} renderer)"
            )
    except (EvaluateUsageError, rundir.RunDirError, ValueError, ImportError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"error: {exc.strerror or exc}: {exc.filename or ''}".rstrip(": "), file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

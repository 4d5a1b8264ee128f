"""Wall-clock time of the Gymnasium evaluation (``jaxcart.run.greedy.evaluate_gymnasium``):
``--policies`` stacked tanh MLPs (4-64-64-2, jaxcart's actor) x ``--episodes`` greedy episodes
in Gymnasium's CartPole-v1, median of ``--repeats`` runs after one warm-up.

The policies are the worst case, every episode lasting the 500 steps: each MLP is built to
act like a balancing linear controller (its argmax is the sign of ``w . obs``, with ``w``
varied a little per policy), at the cost of a real actor's forward pass.

    python -m benchmarks.env.eval_speed            # 64 x 20, the evaluation after training
    python benchmarks/env/eval_speed.py --policies 256 --repeats 3
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from jaxcart.core import networks
from jaxcart.core.solved import NUM_EVAL_EPISODES, SOLVED_RETURN
from jaxcart.run.greedy import evaluate_gymnasium
from jaxcart.rundir.policy import Policy


def balancing_policies(num_policies: int, hidden: int = 64, seed: int = 0) -> Policy:
    """``num_policies`` stacked MLPs whose greedy action is ``w . obs > 0`` (``w`` near
    ``[0.05, 0.3, 1, 0.4]``, a controller that balances CartPole-v1 for 500 steps): unit 0 of
    each hidden layer carries ``w . obs`` through the tanh layers; the other units get small
    random weights that do not reach the logits."""
    rng = np.random.default_rng(seed)
    w = np.array([0.05, 0.3, 1.0, 0.4]) * rng.uniform(0.9, 1.1, (num_policies, 4))
    sizes = [4, hidden, hidden, 2]
    actor = {}
    for name, n_in, n_out in zip(networks.layer_names(2), sizes[:-1], sizes[1:]):
        kernel = rng.normal(0.0, 0.1, (num_policies, n_in, n_out))
        kernel[:, :, 0] = 0.0
        bias = np.zeros((num_policies, n_out))
        actor[name] = {"kernel": kernel, "bias": bias}
    actor["hidden_0"]["kernel"][:, :, 0] = w
    actor["hidden_1"]["kernel"][:, 0, 0] = 1.0
    actor["out"]["kernel"][:] = 0.0
    actor["out"]["kernel"][:, 0, :] = [-1.0, 1.0]  # logits (-h, h): action 1 when h > 0
    return Policy(actor, activation="tanh", stacked=True)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--policies", type=int, default=64)
    parser.add_argument("--episodes", type=int, default=NUM_EVAL_EPISODES)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args(argv)
    policy = balancing_policies(args.policies)
    returns = evaluate_gymnasium(policy, args.policies, args.episodes)  # warm-up
    times = []
    for _ in range(args.repeats):
        start = time.perf_counter()
        evaluate_gymnasium(policy, args.policies, args.episodes)
        times.append(time.perf_counter() - start)
    steps = int(returns.sum())
    print(
        f"evaluate_gymnasium, {args.policies} policies x {args.episodes} episodes "
        f"({(returns == SOLVED_RETURN).mean():.0%} of episodes at 500, {steps:,} env steps): "
        f"median {statistics.median(times):.3f} s over {args.repeats} runs "
        f"(min {min(times):.3f}, max {max(times):.3f}); "
        f"{steps / statistics.median(times) / 1e6:.2f} M env steps/s"
    )


if __name__ == "__main__":
    main()

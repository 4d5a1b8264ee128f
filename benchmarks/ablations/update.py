"""What each part of the PPO update costs, and what the ideas for speeding it up measure.

Variants of jaxcart's update (:func:`jaxcart.core.ppo.update_epochs`, ``sb3`` preset, vmapped over
S seeds on one pinned core), each compiled in this process and then timed interleaved, round
after round, so that a busy machine slows them all alike; the report gives each variant's
median and its ratio to ``current``:

- ``current``: the update as the trainer runs it;
- ``no-optimizer``: gradient clipping and Adam left out (the gradient applied as is): what
  the optimizer costs;
- ``no-shuffle``: minibatches in rollout order (no permutation, no gather): what shuffling costs;
- ``flat-adam``: Adam on one flat vector per seed (gradients raveled, updates unraveled);
- ``flat-params``: parameters kept as one flat vector per seed, unraveled inside the loss;
- ``fused-first-layer``: actor's and critic's first layers as one ``[4, 128]`` matmul;
- ``seed-map``: seeds one after another (``lax.map``) instead of vmapped: the cost of making a
  seed's numerics independent of how many seeds share the device;
- ``seed-groups-8``: the seeds in groups of 8, vmapped within a group, groups one after
  another (``lax.map``): a smaller working set per gradient step (parameters, Adam moments and
  activations of 8 seeds fit in the core's L2 cache where those of 32 do not).

    python -m benchmarks.ablations.update            # S = 32, 9 rounds
    python -m benchmarks.ablations.update --seeds 1 --rounds 15

Writes ``update_ablation.json`` and ``.md`` to ``--out`` (default
``benchmarks/results/scratch``, not committed; ``--out benchmarks/results`` replaces the committed
figures).
"""

from __future__ import annotations

import argparse
import functools
import re
import statistics
from collections.abc import Callable

import jax
import jax.numpy as jnp
import optax
from jax.flatten_util import ravel_pytree

from benchmarks import lib
from benchmarks.ablations import roofline
from jaxcart.core import networks, ppo
from jaxcart.core.config import PPOConfig, preset

VARIANTS = (
    "current",
    "no-optimizer",
    "no-shuffle",
    "flat-adam",
    "flat-params",
    "fused-first-layer",
    "seed-map",
    "seed-groups-8",
)
"""``seed-groups-N`` with any other N (dividing the seed count) is accepted too."""


def flat_adam(make_optimizer: Callable) -> Callable:
    """``make_optimizer`` applied to the raveled gradient (one vector per seed)."""

    def make(config):
        inner = make_optimizer(config)

        def update(grads, state, params=None):
            flat, unravel = ravel_pytree(grads)
            updates, state = inner.update(flat, state)
            return unravel(updates), state

        return optax.GradientTransformation(lambda p: inner.init(ravel_pytree(p)[0]), update)

    return make


def fused_first_layer(self, params: dict, obs):
    """ActorCritic.apply with both first layers as one matmul (hidden sizes (64, 64), tanh)."""
    actor = params[networks.ROOT][networks.ACTOR]
    critic = params[networks.ROOT][networks.CRITIC]
    kernel = jnp.concatenate([actor["hidden_0"]["kernel"], critic["hidden_0"]["kernel"]], -1)
    bias = jnp.concatenate([actor["hidden_0"]["bias"], critic["hidden_0"]["bias"]], -1)
    hidden = jnp.tanh(obs @ kernel + bias)
    width = actor["hidden_0"]["kernel"].shape[-1]

    def rest(layers, x):
        x = jnp.tanh(x @ layers["hidden_1"]["kernel"] + layers["hidden_1"]["bias"])
        return x @ layers["out"]["kernel"] + layers["out"]["bias"]

    return rest(actor, hidden[..., :width]), rest(critic, hidden[..., width:])[..., 0]


class Patched:
    """Swaps module attributes for the duration of a ``with`` block (tracing happens inside)."""

    def __init__(self, *swaps: tuple[object, str, object]):
        self.swaps, self.saved = swaps, []

    def __enter__(self):
        for owner, name, value in self.swaps:
            self.saved.append((owner, name, getattr(owner, name)))
            setattr(owner, name, value)

    def __exit__(self, *exc):
        for owner, name, value in reversed(self.saved):
            setattr(owner, name, value)


def build(variant: str, config: PPOConfig, seeds: int):
    """``(compiled, args)``: the variant's update compiled for ``seeds`` seeds."""
    update, args = roofline.update_program(config, seeds)
    params, opt_state, batch, keys, configs = args
    one_config = jax.tree.map(lambda x: x[0], configs)
    swaps: list = []
    if variant == "no-optimizer":
        swaps = [(ppo, "make_optimizer", lambda config: optax.identity())]
    elif variant == "no-shuffle":
        swaps = [
            (ppo, "random_permutations", lambda k, n, s: jnp.broadcast_to(jnp.arange(s), (n, s)))
        ]
    elif variant == "flat-adam":
        swaps = [(ppo, "make_optimizer", flat_adam(ppo.make_optimizer))]
    elif variant == "fused-first-layer":
        swaps = [(networks.ActorCritic, "apply", fused_first_layer)]
    elif variant == "flat-params":
        one = jax.tree.map(lambda x: x[0], params)
        unravel = ravel_pytree(one)[1]
        plain = networks.ActorCritic.apply
        swaps = [(networks.ActorCritic, "apply", lambda self, p, obs: plain(self, unravel(p), obs))]
        params = jax.vmap(lambda p: ravel_pytree(p)[0])(params)
    elif variant == "seed-map":

        def update(params, opt_state, batch, keys, configs):
            one = lambda a: ppo.update_epochs(*a[:4], a[4].learning_rate, a[4])
            return jax.lax.map(one, (params, opt_state, batch, keys, configs))

    elif variant.startswith("seed-groups-"):
        vmapped, group = update, int(variant.removeprefix("seed-groups-"))

        def update(*args):
            groups = jax.tree.map(lambda x: x.reshape((-1, group) + x.shape[1:]), args)
            out = jax.lax.map(lambda g: vmapped(*g), groups)
            return jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), out)

    with Patched(*swaps):
        if variant in ("no-optimizer", "flat-adam", "flat-params"):
            opt_state = jax.vmap(ppo.make_optimizer(one_config).init)(params)
        args = (params, opt_state, batch, keys, configs)
        compiled = jax.jit(update).lower(*args).compile()
    jax.block_until_ready(compiled(*args))
    return compiled, args


def measure(config: PPOConfig, seeds: int, variants: list[str], rounds: int) -> list[dict]:
    built = {v: build(v, config, seeds) for v in variants}
    calls = {v: functools.partial(built[v][0], *built[v][1]) for v in variants}
    times = lib.interleaved_times(calls, rounds)
    base = statistics.median(times[variants[0]])
    return [
        {
            "variant": v,
            "seconds": times[v],
            "median_seconds": statistics.median(times[v]),
            "ratio": statistics.median(times[v]) / base,
        }
        for v in variants
    ]


def markdown(report: dict) -> str:
    lines = [
        f"# What the update's parts cost (`{report['preset']}`, S = {report['seeds']} seeds on "
        "one core)",
        "",
        f"Median of {report['rounds']} interleaved rounds; ratio to `{report['rows'][0]['variant']}`.",
        "",
        "| variant | median ms | ratio |",
        "| --- | ---: | ---: |",
    ]
    for r in report["rows"]:
        lines.append(f"| {r['variant']} | {r['median_seconds'] * 1e3:.1f} | {r['ratio']:.3f} |")
    lines += ["", f"Command: `{report['command']}`", ""]
    return "\n".join(lines + lib.machine_markdown(report["machine"]))


def main(argv: list[str] | None = None) -> int:
    parser = lib.arg_parser(__doc__)
    parser.add_argument("--preset", default="sb3")
    parser.add_argument("--seeds", type=int, default=32)
    parser.add_argument("--rounds", type=int, default=9)
    parser.add_argument("--variants", default=",".join(VARIANTS))
    lib.add_out_option(parser)
    args = parser.parse_args(argv)
    args.out = lib.output_dir(args.out)
    variants = lib.split_list(args.variants)
    known = lambda v: v in VARIANTS or re.fullmatch(r"seed-groups-[1-9][0-9]*", v)
    if not variants or variants[0] != "current" or not all(map(known, variants)):
        raise argparse.ArgumentTypeError(f"--variants: 'current' first, then any of {VARIANTS}")
    rows = measure(preset(args.preset), args.seeds, variants, args.rounds)
    report = {
        "command": lib.command_line(),
        "machine": lib.machine_info([str(d) for d in jax.devices()]),
        "preset": args.preset,
        "seeds": args.seeds,
        "rounds": args.rounds,
        "rows": rows,
    }
    lib.write_report(args.out, "update_ablation", report, markdown(report))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

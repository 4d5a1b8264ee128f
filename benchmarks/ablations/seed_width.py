"""What it would cost to make a seed's numbers independent of how many seeds share a device.

jaxcart vmaps its seeds: XLA compiles a different program for each per-device batch width, and
the rounding of its batched matmuls and reductions differs in the last bits, so a seed's run
drifts with the width (the README's Reproducibility section). Computing the seeds one after
another inside the program (``lax.map`` over seeds instead of ``vmap``) runs the same
per-seed program at every width. This script measures, on one pinned core, for each width S:

- whether seed 0 comes out bit-identical at width 1 and width S under each scheme (two
  iterations of :func:`jaxcart.engine.chunk.train_chunk`, ``sb3`` preset);
- the time of one chunk under each scheme, interleaved over ``--rounds``, and the slowdown
  of ``lax.map`` against ``vmap`` (a throughput cost; the issue's bar is 10%).

    python -m benchmarks.ablations.seed_width        # S = 4, 8, 32
    python -m benchmarks.ablations.seed_width --seeds 32 --rounds 9

Writes ``seed_width.json`` and ``seed_width.md`` to ``--out`` (default
``benchmarks/results/scratch``, not committed; ``--out benchmarks/results`` replaces the committed
figures).
"""

from __future__ import annotations

import functools
import statistics

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks import lib

# Imported for its side effect: it pins this process to one core with one JAX device.
from benchmarks.ablations import roofline  # noqa: F401
from jaxcart.core import cartpole
from jaxcart.core.config import preset
from jaxcart.core.ppo import train_iteration
from jaxcart.engine.chunk import guard_divergence
from jaxcart.engine.loop import init_runners

CHUNK = 2


def chunk_program(scheme: str):
    """``CHUNK`` iterations of every seed, the seeds vmapped or mapped one after another;
    takes ``(runners, configs)``, the configs' traced fields ``[S]``."""
    env_params = cartpole.EnvParams()

    def one(runner, config, iteration):
        new, metrics = train_iteration(runner, config, iteration, env_params)
        return guard_divergence(runner, new, metrics, iteration)

    def program(runners, configs):
        def body(runners, iteration):
            if scheme == "vmap":
                return jax.vmap(one, in_axes=(0, 0, None))(runners, configs, iteration)
            return jax.lax.map(lambda a: one(a[0], a[1], iteration), (runners, configs))

        return jax.lax.scan(body, runners, jnp.arange(CHUNK))

    return jax.jit(program)


def inputs(config, seeds: int):
    runners = jax.device_put(init_runners(config, 0, np.arange(seeds), cartpole.EnvParams()))
    return runners, config.per_run(seeds)


def seed0_params(fn, config, seeds: int) -> list[np.ndarray]:
    runners, _ = fn(*inputs(config, seeds))
    return [np.asarray(x[0]) for x in jax.tree.leaves(runners.params)]


def width_row(config, seeds: int, rounds: int) -> dict:
    row = {"seeds": seeds}
    compiled = {}
    for scheme in ("vmap", "map"):
        fn = chunk_program(scheme)
        alone, batched = seed0_params(fn, config, 1), seed0_params(fn, config, seeds)
        row[f"{scheme}_identical"] = all(np.array_equal(a, b) for a, b in zip(alone, batched))
        args = inputs(config, seeds)
        compiled[scheme] = (fn.lower(*args).compile(), args)
        jax.block_until_ready(compiled[scheme][0](*args))
    calls = {
        scheme: functools.partial(compiled[scheme][0], *compiled[scheme][1]) for scheme in compiled
    }
    times = lib.interleaved_times(calls, rounds)
    for scheme, t in times.items():
        row[f"{scheme}_seconds"] = statistics.median(t)
    row["map_over_vmap"] = row["map_seconds"] / row["vmap_seconds"]
    return row


def markdown(report: dict) -> str:
    lines = [
        f"# Seed numerics independent of the per-device width: the cost (`{report['preset']}`, "
        "one core)",
        "",
        f"{CHUNK} training iterations; median of {report['rounds']} interleaved rounds.",
        "",
        "| seeds on the core | vmap ms | lax.map ms | lax.map / vmap | seed 0 identical alone "
        "and in the batch: vmap | lax.map |",
        "| ---: | ---: | ---: | ---: | --- | --- |",
    ]
    for r in report["rows"]:
        lines.append(
            f"| {r['seeds']} | {r['vmap_seconds'] * 1e3:.1f} | {r['map_seconds'] * 1e3:.1f} | "
            f"{r['map_over_vmap']:.2f}x | {'yes' if r['vmap_identical'] else 'no'} | "
            f"{'yes' if r['map_identical'] else 'no'} |"
        )
    lines += ["", f"Command: `{report['command']}`", ""]
    return "\n".join(lines + lib.machine_markdown(report["machine"]))


def main(argv: list[str] | None = None) -> int:
    parser = lib.arg_parser(__doc__)
    parser.add_argument("--preset", default="sb3")
    parser.add_argument("--seeds", type=lib.parse_ints, default="4,8,32")
    parser.add_argument("--rounds", type=int, default=5)
    lib.add_out_option(parser)
    args = parser.parse_args(argv)
    args.out = lib.output_dir(args.out)
    config = preset(args.preset)
    rows = []
    for seeds in args.seeds:
        rows.append(width_row(config, seeds, args.rounds))
        print(rows[-1], flush=True)
    report = {
        "command": lib.command_line(),
        "machine": lib.machine_info([str(d) for d in jax.devices()]),
        "preset": args.preset,
        "rounds": args.rounds,
        "rows": rows,
    }
    lib.write_report(args.out, "seed_width", report, markdown(report))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

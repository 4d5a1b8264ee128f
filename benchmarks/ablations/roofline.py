"""The PPO update against this machine's matmul limit, on one pinned core.

The update is a chain of small matmuls (per seed and gradient step, minibatch M = 64 through
two 4-64-64 MLPs with a 2- and a 1-wide head, forward and backward), vmapped over the S seeds
a device holds. This script measures, in one process pinned to one core with one JAX device:

1. ``gemm``: a large square ``jnp.dot`` (``--gemm-size``, default 2048): what the core's
   matmul units reach on a shape that suits them.
2. ``shape chains``: scanned chains of batched matmuls of the update's own shapes, batched
   over S seeds, each step depending on the last (``x -> tanh(x @ A) -> tanh(. @ B)``):
   ``[S, 64, 4] @ [S, 4, 64]`` (and back), ``[S, 64, 64] @ [S, 64, 64]``, ``[S, 64, 64] @
   [S, 64, 2]`` (and back). Their rates are the ceiling for matmuls of these shapes.
3. ``mlp step``: the same two MLPs' forward, backward and an SGD step on minibatches (no PPO
   loss, no Adam, no shuffling): the update's matmuls alone, as XLA compiles them.
4. ``update``: jaxcart's real update (:func:`jaxcart.core.ppo.update_epochs`, vmapped over S seeds
   on a rollout batch), as the trainer runs it.

Each program's FLOPs are counted analytically (2·m·k·n per matmul; elementwise work not
counted), so ``achieved GFLOP/s = counted FLOPs / median seconds``. The update's fraction of
the limit is reported two ways: against the large GEMM, and against the shape chains
(``predicted seconds = sum over its matmuls of FLOPs / that shape's chain rate``; fraction =
predicted / measured). Finally the update's compiled HLO is counted by op kind (dots, gathers,
transposes, copies, fusions, loops), so what costs more than its FLOPs can be seen.

    python -m benchmarks.ablations.roofline          # about a minute
    python -m benchmarks.ablations.roofline --seeds 1,32 --preset sb3

Writes ``roofline.json`` and ``roofline.md`` to ``--out`` (default
``benchmarks/results/scratch``, not committed; ``--out benchmarks/results`` replaces the committed
figures).
"""

from __future__ import annotations

import os

# One core, one JAX device: the figures are per core (the trainer gives each core a device).
os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
os.environ["XLA_FLAGS"] = (
    os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=1"
).strip()

import re  # noqa: E402
from collections import Counter  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from benchmarks import lib  # noqa: E402
from jaxcart.core import cartpole  # noqa: E402
from jaxcart.core.config import PPOConfig, preset  # noqa: E402
from jaxcart.core.ppo import Batch, collect_rollout, training_batch, update_epochs  # noqa: E402
from jaxcart.engine.loop import init_runners  # noqa: E402

OBS, HIDDEN, ACTIONS = 4, 64, 2


def mlp_sizes(config: PPOConfig) -> list[list[int]]:
    """Layer widths of the actor's and the critic's MLP, input first."""
    actor_hidden = [] if config.linear_actor else list(config.hidden_sizes)
    return [[OBS, *actor_hidden, ACTIONS], [OBS, *config.hidden_sizes, 1]]


def gradient_step_matmuls(config: PPOConfig, m: int) -> list[tuple[str, int, int, int]]:
    """Every matmul of one gradient step on a minibatch of ``m``: ``(kind, m, k, n)``.

    Forward ``[m, in] @ [in, out]``; backward the weight gradient ``[in, m] @ [m, out]`` and,
    except for an MLP's first layer (its input is data), the input gradient ``[m, out] @
    [out, in]``.
    """
    out = []
    for sizes in mlp_sizes(config):
        for i, (k, n) in enumerate(zip(sizes[:-1], sizes[1:])):
            out.append(("forward", m, k, n))
            out.append(("weight-grad", k, m, n))
            if i > 0:
                out.append(("input-grad", m, n, k))
    return out


def flops(matmuls: list[tuple[str, int, int, int]]) -> int:
    return sum(2 * m * k * n for _, m, k, n in matmuls)


# 1. the large GEMM


def gemm_rate(size: int, repeats: int) -> dict:
    a = jnp.asarray(np.random.default_rng(0).standard_normal((size, size)), jnp.float32)
    _, seconds = lib.compile_and_time(lambda a: a @ a, (a,), repeats)
    return {"name": f"gemm {size}x{size}x{size}", "flops": 2 * size**3, "seconds": seconds}


# 2. chains of the update's own shapes


def chain(seeds: int, m: int, k: int, n: int, length: int, repeats: int) -> dict:
    """``length`` steps of ``x [S, m, k] -> tanh(x @ A [S, k, n]) -> tanh(. @ B [S, n, k])``
    (one matmul when ``k == n``); each step depends on the last, as the update's do."""
    rng = np.random.default_rng(0)
    x = jnp.asarray(rng.standard_normal((seeds, m, k)) * 0.1, jnp.float32)
    a = jnp.asarray(rng.standard_normal((seeds, k, n)) / np.sqrt(k), jnp.float32)
    b = jnp.asarray(rng.standard_normal((seeds, n, k)) / np.sqrt(n), jnp.float32)
    square = k == n

    def run(x, a, b):
        def body(x, _):
            y = jnp.tanh(x @ a)
            return (y if square else jnp.tanh(y @ b)), None

        return jax.lax.scan(body, x, None, length=length)[0]

    _, seconds = lib.compile_and_time(run, (x, a, b), repeats)
    count = 2 * seeds * m * k * n * length * (1 if square else 2)
    name = f"[S,{m},{k}]@[S,{k},{n}]" + ("" if square else f" and back @[S,{n},{k}]")
    return {"name": name, "shape": [m, k, n], "flops": count, "seconds": seconds}


def chain_rates(seeds: int, m: int, repeats: int) -> list[dict]:
    length = max(64, 16384 // seeds)
    return [
        chain(seeds, m, OBS, HIDDEN, length, repeats),
        chain(seeds, m, HIDDEN, HIDDEN, length, repeats),
        chain(seeds, m, HIDDEN, ACTIONS, length, repeats),
    ]


def chain_rate_for(shape: tuple[int, int, int], chains: list[dict]) -> float:
    """FLOP/s of the measured chain closest in shape to matmul ``(m, k, n)`` (by its smallest
    dimension, which decides how well a matmul fills the vector units)."""
    smallest = min(shape)
    best = min(chains, key=lambda c: abs(min(c["shape"]) - smallest))
    return best["flops"] / best["seconds"]


# 3. and 4. the MLPs' step alone, and the real update


def rollout_batch(config: PPOConfig, seeds: int):
    """A real rollout batch ``[S, B, ...]``, the runners it came from and every seed's config
    (traced fields ``[S]``)."""
    env_params = cartpole.EnvParams()
    runners = jax.device_put(init_runners(config, 0, np.arange(seeds), env_params))
    configs = config.per_run(seeds)

    def batch_of(runner, run_config):
        runner, rollout = collect_rollout(runner, run_config, env_params)
        return training_batch(runner.params, rollout, run_config)

    batch = jax.jit(jax.vmap(batch_of))(runners, configs)
    return runners, batch, configs


def update_program(config: PPOConfig, seeds: int):
    """``(fn, args)``: jaxcart's update, vmapped over ``seeds``, as the trainer calls it."""
    runners, batch, configs = rollout_batch(config, seeds)
    keys = jax.random.split(jax.random.PRNGKey(0), seeds)

    def update(params, opt_state, batch, keys, configs):
        return jax.vmap(lambda p, o, b, k, c: update_epochs(p, o, b, k, c.learning_rate, c))(
            params, opt_state, batch, keys, configs
        )

    return update, (runners.params, runners.opt_state, batch, keys, configs)


def mlp_step_program(config: PPOConfig, seeds: int, params: dict, batch: Batch):
    """The update's matmuls alone: both MLPs forward and backward on the same minibatches
    (contiguous slices, no shuffle), loss ``sum(logits) + sum(value)``, plain SGD."""
    from jaxcart.core.networks import ActorCritic

    network = ActorCritic.from_config(config)
    steps = config.update_epochs * config.num_minibatches
    shape = (config.num_minibatches, config.minibatch_size)

    def loss(p, obs):
        logits, value = network.apply(p, obs)
        return logits.sum() + value.sum()

    def one_seed(p, obs):
        minibatches = obs.reshape(shape + obs.shape[1:])

        def body(p, i):
            g = jax.grad(loss)(p, minibatches[i % config.num_minibatches])
            return jax.tree.map(lambda w, d: w - 1e-6 * d, p, g), None

        return jax.lax.scan(body, p, jnp.arange(steps))[0]

    return jax.vmap(one_seed), (params, batch.obs)


HLO_OPS = ("dot", "gather", "scatter", "transpose", "copy", "fusion", "while", "sort")


def hlo_census(fn, args: tuple) -> dict:
    """Counts of op kinds in the optimised HLO of ``jit(fn)(*args)`` (every computation)."""
    text = jax.jit(fn).lower(*args).compile().as_text()
    counts = Counter()
    pattern = re.compile(r" = .*?\b(" + "|".join(HLO_OPS) + r")\(")
    for line in text.splitlines():
        found = pattern.search(line)
        if found:
            counts[found.group(1)] += 1
    batched_dots = len(re.findall(r"dot\(.*lhs_batch_dims=\{0\}", text))
    return {**{op: counts.get(op, 0) for op in HLO_OPS}, "batched_dots": batched_dots}


def rate(row: dict) -> float:
    return row["flops"] / row["seconds"]


def measure_seeds(config: PPOConfig, seeds: int, chains: list[dict], repeats: int) -> dict:
    """The MLP step and the update at ``seeds`` seeds on the device, against the limits."""
    steps = config.update_epochs * config.num_minibatches
    matmuls = gradient_step_matmuls(config, config.minibatch_size)
    step_flops = flops(matmuls) * steps * seeds
    # what the update would take if every matmul ran at its own shape's chain rate
    predicted = sum(2 * m * k * n / chain_rate_for((m, k, n), chains) for _, m, k, n in matmuls)
    predicted *= steps * seeds
    update, args = update_program(config, seeds)
    compile_update, update_seconds = lib.compile_and_time(update, args, repeats)
    mlp, mlp_args = mlp_step_program(config, seeds, args[0], args[2])
    _, mlp_seconds = lib.compile_and_time(mlp, mlp_args, repeats)
    return {
        "seeds": seeds,
        "gradient_steps": steps * seeds,
        "flops": step_flops,
        "update_seconds": update_seconds,
        "update_compile_seconds": compile_update,
        "mlp_step_seconds": mlp_seconds,
        "predicted_seconds": predicted,
        "update_gflops": step_flops / update_seconds / 1e9,
        "mlp_step_gflops": step_flops / mlp_seconds / 1e9,
        "fraction_of_shape_rate": predicted / update_seconds,
        "mlp_fraction_of_shape_rate": predicted / mlp_seconds,
        "us_per_gradient_step": update_seconds / (steps * seeds) * 1e6,
        "hlo": hlo_census(update, args),
    }


def markdown(report: dict) -> str:
    gemm = report["gemm"]
    gemm_gflops = rate(gemm) / 1e9
    lines = [
        "# The PPO update against the machine's matmul rate (one core)",
        "",
        f"Preset `{report['preset']}`: per gradient step two MLPs "
        f"({', '.join('-'.join(map(str, s)) for s in report['mlp_sizes'])}) forward and "
        f"backward on a minibatch of {report['minibatch']}; "
        f"{report['flops_per_gradient_step']:,} matmul FLOPs per gradient step (analytic).",
        "",
        "| program | GFLOP/s | note |",
        "| --- | ---: | --- |",
        f"| {gemm['name']} | {gemm_gflops:.1f} | the core's matmul rate on a shape that suits it |",
    ]
    for c in report["chains"]:
        lines.append(
            f"| chain {c['name']}, S={report['chain_seeds']} | {rate(c) / 1e9:.1f} "
            "| the ceiling for this shape |"
        )
    lines += [
        "",
        "| seeds on the core | update ms | µs / gradient step | update GFLOP/s "
        "| % of GEMM | % of own-shape chains | MLP-only step GFLOP/s | MLP-only % of chains |",
        "| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in report["rows"]:
        lines.append(
            f"| {r['seeds']} | {r['update_seconds'] * 1e3:.1f} | {r['us_per_gradient_step']:.1f} "
            f"| {r['update_gflops']:.1f} | {100 * r['update_gflops'] / gemm_gflops:.0f}% "
            f"| {100 * r['fraction_of_shape_rate']:.0f}% | {r['mlp_step_gflops']:.1f} "
            f"| {100 * r['mlp_fraction_of_shape_rate']:.0f}% |"
        )
    lines += [
        "",
        "Op census of the compiled update (optimised HLO, all computations):",
        "",
        "| seeds | " + " | ".join((*HLO_OPS, "batched_dots")) + " |",
        "| ---: |" + " ---: |" * (len(HLO_OPS) + 1),
    ]
    for r in report["rows"]:
        cells = [str(r["hlo"][op]) for op in (*HLO_OPS, "batched_dots")]
        lines.append(f"| {r['seeds']} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "% of own-shape chains = (the update's matmul FLOPs at each shape's chain rate) / "
        "(measured update time): 100% would mean the update costs no more than its matmuls "
        "run back to back. The MLP-only step is the same matmuls with no PPO loss, Adam or "
        "shuffle.",
        "",
        f"Command: `{report['command']}`",
        "",
        *lib.machine_markdown(report["machine"]),
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = lib.arg_parser(__doc__)
    parser.add_argument("--preset", default="sb3")
    parser.add_argument("--seeds", type=lib.parse_ints, default="1,32")
    parser.add_argument("--chain-seeds", type=int, default=32, help="S of the shape chains")
    parser.add_argument("--gemm-size", type=int, default=2048)
    parser.add_argument("--repeats", type=int, default=5)
    lib.add_out_option(parser)
    args = parser.parse_args(argv)
    args.out = lib.output_dir(args.out)
    config = preset(args.preset)
    gemm = gemm_rate(args.gemm_size, args.repeats)
    print(f"{gemm['name']}: {rate(gemm) / 1e9:.1f} GFLOP/s", flush=True)
    chains = chain_rates(args.chain_seeds, config.minibatch_size, args.repeats)
    for c in chains:
        print(f"chain {c['name']}: {rate(c) / 1e9:.1f} GFLOP/s", flush=True)
    rows = []
    for seeds in args.seeds:
        rows.append(measure_seeds(config, seeds, chains, args.repeats))
        r = rows[-1]
        print(
            f"S={seeds}: update {r['update_gflops']:.1f} GFLOP/s "
            f"({100 * r['fraction_of_shape_rate']:.0f}% of own-shape chains), "
            f"MLP-only {r['mlp_step_gflops']:.1f} GFLOP/s",
            flush=True,
        )
    report = {
        "command": lib.command_line(),
        "machine": lib.machine_info([str(d) for d in jax.devices()]),
        "preset": args.preset,
        "mlp_sizes": mlp_sizes(config),
        "minibatch": config.minibatch_size,
        "flops_per_gradient_step": flops(gradient_step_matmuls(config, config.minibatch_size)),
        "gemm": gemm,
        "chain_seeds": args.chain_seeds,
        "chains": chains,
        "rows": rows,
    }
    lib.write_report(args.out, "roofline", report, markdown(report))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

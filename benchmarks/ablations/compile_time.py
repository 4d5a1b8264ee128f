"""Where the cold compile of the default training step goes, and what XLA flags do to it.

The default run (``python -m jaxcart.train``: the ``sb3`` preset, one seed, one device)
compiles one program, :func:`jaxcart.engine.chunk.train_chunk`. Each variant below runs in a fresh
process with the persistent cache off and measures, for that program:

- ``trace``: Python tracing to a jaxpr, ``lower``: jaxpr to StableHLO (JAX's side);
- ``compile``: XLA's side, split with XLA's own timers (``TF_CPP_VMODULE=cpu_compiler=1``)
  into its HLO optimisation passes and the rest (IR emission, LLVM optimisation and machine
  code for every kernel; the number of kernels is counted too);
- the optimised HLO's size (instructions) and its ``while`` loops;
- wall and CPU seconds of each stage, the median of ``--repeats`` fresh processes.

Variants (``--variants``, comma-separated; ``XLA_FLAGS`` of each):

- ``default``: the flags ``python -m jaxcart.train`` uses;
- ``O0``/``O1``: ``--xla_backend_optimization_level=0/1``: less LLVM optimisation, showing
  LLVM's share of the compile (and what it costs at run time: ``--run`` times a chunk);
- ``no-expensive``: ``--xla_llvm_disable_expensive_passes=true``;
- ``split-N``: ``--xla_cpu_parallel_codegen_split_count=N`` (codegen in N parallel parts);
- ``no-thunk``: ``--xla_cpu_use_thunk_runtime=false`` (XLA:CPU's older whole-program runtime);
- ``fusion-emitters``: ``--xla_cpu_use_fusion_emitters=true`` (the MLIR fusion emitters);
- ``stub-guard``, ``stub-update``, ``stub-episodes``: default flags, with the divergence
  guard, the minibatch update or the episode-statistics buffer replaced by a stub, to see
  what each part of the program costs to compile (these programs are not runnable training);
- ``swap-fused-adam``: gradient clipping and Adam as one update over the concatenated
  parameters (:func:`fused_clip_adam`) instead of optax's leaf-by-leaf chain: fewer kernels,
  but not bit-identical (XLA rounds the flat element-wise kernel differently), so not adopted;
- ``swap-one-scatter``: the episode window filled by one scatter of (return, length) pairs
  (the valid mask derived from the count) instead of a scatter each for returns, lengths and
  the valid mask: the same values, not fewer instructions, so not adopted.

    python -m benchmarks.ablations.compile_time      # every variant, 3 processes each
    python -m benchmarks.ablations.compile_time --variants default,O1 --repeats 5 --run

Writes ``compile_time.json`` and ``compile_time.md`` to ``--out`` (default
``benchmarks/results/scratch``, not committed; ``--out benchmarks/results`` replaces the committed
figures).
"""

from __future__ import annotations

import json
import os
import re
import statistics
import subprocess

from benchmarks import lib

VARIANTS = {
    "default": "",
    "O0": "--xla_backend_optimization_level=0",
    "O1": "--xla_backend_optimization_level=1",
    "no-expensive": "--xla_llvm_disable_expensive_passes=true",
    "split-2": "--xla_cpu_parallel_codegen_split_count=2",
    "split-4": "--xla_cpu_parallel_codegen_split_count=4",
    "no-thunk": "--xla_cpu_use_thunk_runtime=false",
    "fusion-emitters": "--xla_cpu_use_fusion_emitters=true",
    # the same flags as default, with one part of the program stubbed out (what it costs)
    "stub-guard": "",
    "stub-update": "",
    "stub-episodes": "",
    # the same flags, with one part of the program computed another way
    "swap-fused-adam": "",
    "swap-one-scatter": "",
}


def fused_clip_adam(max_grad_norm, eps):
    """optax's clip-by-global-norm then Adam (b1 0.9, b2 0.999), with the element-wise work
    done once on all leaves concatenated: the same formulas in the same order, same state."""
    import functools
    import itertools
    import operator

    import jax
    import jax.numpy as jnp
    import optax

    plain = optax.chain(optax.clip_by_global_norm(max_grad_norm), optax.scale_by_adam(eps=eps))

    def update(grads, state, params=None):
        clip_state, adam = state
        leaves, treedef = jax.tree.flatten(grads)
        sqnorm = functools.reduce(operator.add, [jnp.sum(jnp.square(g)) for g in leaves], 0)
        g_norm = jnp.sqrt(sqnorm)
        flat = lambda xs: jnp.concatenate([x.reshape(-1) for x in xs])
        g = flat(leaves)
        g = jax.lax.select(g_norm < max_grad_norm, g, (g / g_norm) * max_grad_norm)
        mu = (1 - 0.9) * g + 0.9 * flat(jax.tree.leaves(adam.mu))
        nu = (1 - 0.999) * g**2 + 0.999 * flat(jax.tree.leaves(adam.nu))
        count = optax.safe_increment(adam.count)
        mu_hat = optax.tree.bias_correction(mu, 0.9, count)
        nu_hat = optax.tree.bias_correction(nu, 0.999, count)
        cuts = list(itertools.accumulate(leaf.size for leaf in leaves))[:-1]

        def unflat(x):
            parts = jnp.split(x, cuts)
            return treedef.unflatten([p.reshape(leaf.shape) for p, leaf in zip(parts, leaves)])

        scaled = mu_hat / (jnp.sqrt(nu_hat + 0.0) + eps)
        adam = adam._replace(count=count, mu=unflat(mu), nu=unflat(nu))
        return unflat(scaled), (clip_state, adam)

    return optax.GradientTransformation(plain.init, update)


def one_scatter(buffer, done, episode_return, episode_length):
    """The episode window filled with one scatter of (return, length) pairs."""
    import jax.numpy as jnp

    from jaxcart.core.metrics import EPISODE_WINDOW, EpisodeBuffer

    valid = jnp.concatenate([buffer.valid, done.reshape(-1)])
    values = jnp.stack(
        [
            jnp.concatenate([buffer.returns, episode_return.reshape(-1).astype(jnp.float32)]),
            jnp.concatenate([buffer.lengths, episode_length.reshape(-1).astype(jnp.float32)]),
        ],
        axis=-1,
    )
    rank = jnp.cumsum(valid[::-1])[::-1]
    slot = jnp.where(valid & (rank <= EPISODE_WINDOW), EPISODE_WINDOW - rank, EPISODE_WINDOW)
    window = jnp.zeros((EPISODE_WINDOW, 2), jnp.float32).at[slot].set(values, mode="drop")
    filled = jnp.minimum(valid.sum(), EPISODE_WINDOW)
    return EpisodeBuffer(
        returns=window[:, 0],
        lengths=window[:, 1],
        valid=jnp.arange(EPISODE_WINDOW) >= EPISODE_WINDOW - filled,
    )


def stub(part: str) -> None:
    """Replaces one part of the training program (:mod:`jaxcart.core.ppo`,
    :mod:`jaxcart.engine.chunk`) with a stub of the same signature."""
    import jax.numpy as jnp

    from jaxcart.core import ppo
    from jaxcart.engine import chunk

    if part == "guard":
        chunk.guard_divergence = lambda old, new, metrics, iteration: (new, metrics)
    elif part == "episodes":
        ppo.update_episode_buffer = lambda buffer, done, episode_return, episode_length: buffer
    elif part == "update":
        names = ("approx_kl", "clip_fraction", "entropy_loss", "policy_gradient_loss")
        names += ("value_loss", "loss")

        def update(params, opt_state, batch, key, hp, learning_rate, config):
            shape = (config.update_epochs, config.num_minibatches)
            return params, opt_state, {n: jnp.zeros(shape) for n in names}

        ppo.update_epochs = update
    elif part == "fused-adam":
        ppo.make_optimizer = lambda hp: fused_clip_adam(hp.max_grad_norm, hp.adam_eps)
        chunk.make_optimizer = ppo.make_optimizer
    elif part == "one-scatter":
        ppo.update_episode_buffer = one_scatter


def child(run: bool, part: str | None) -> dict:
    """In a fresh process: trace, lower and compile the default run's chunk; optionally run it."""
    import time

    import jax

    jax.config.update("jax_enable_compilation_cache", False)
    import jax.numpy as jnp
    import numpy as np

    if part:
        stub(part)
    from jaxcart.core import env as cartpole
    from jaxcart.core.config import preset
    from jaxcart.engine import chunk
    from jaxcart.engine.lowering import fast_lowering
    from jaxcart.engine.trainer import broadcast_hyperparams, default_chunk_size, init_runners

    config = preset("sb3")
    env_params = cartpole.EnvParams()
    chunk_size = default_chunk_size(config.num_iterations)
    runners = jax.device_put(init_runners(config, 0, np.arange(1), env_params))
    hps = broadcast_hyperparams(config, 1)

    def fn(runners, hps, start):
        return chunk.train_chunk(runners, hps, start, config, env_params, chunk_size)

    marks = [(time.perf_counter(), time.process_time())]
    with fast_lowering():  # as the trainer lowers it
        traced = jax.jit(fn).trace(runners, hps, jnp.int32(0))
        marks.append((time.perf_counter(), time.process_time()))
        lowered = traced.lower()
    marks.append((time.perf_counter(), time.process_time()))
    compiled = lowered.compile()
    marks.append((time.perf_counter(), time.process_time()))
    stages = ("trace", "lower", "compile")
    out = {f"{s}_wall": marks[i + 1][0] - marks[i][0] for i, s in enumerate(stages)}
    out.update({f"{s}_cpu": marks[i + 1][1] - marks[i][1] for i, s in enumerate(stages)})
    text = compiled.as_text()
    out["hlo_instructions"] = sum(1 for line in text.splitlines() if " = " in line)
    out["hlo_while_loops"] = text.count(" while(")
    if run:
        jax.block_until_ready(compiled(runners, hps, jnp.int32(0)))
        start = time.perf_counter()
        jax.block_until_ready(compiled(runners, hps, jnp.int32(0)))
        out["run_seconds_per_iteration"] = (time.perf_counter() - start) / chunk_size
    return out


def xla_timers(log: str) -> dict:
    """XLA:CPU's own timers for the training program (module ``jit_fn``) from its log."""

    def seconds(pattern: str) -> float:
        found = re.search(pattern + r" time: ([\d.]+) (ms|s|us)", log)
        if not found:
            return float("nan")
        scale = {"s": 1.0, "ms": 1e-3, "us": 1e-6}[found.group(2)]
        return float(found.group(1)) * scale

    kernels = re.findall(r"Running LLVM verifier time: .*#called: (\d+)\)", log)
    return {
        "hlo_passes_seconds": seconds(r"Running HLO passes on \[jit_fn\] for CPU"),
        "codegen_seconds": seconds(r"Compiling \[jit_fn\] for CPU using JIT"),
        "llvm_kernels": int(kernels[-1]) if kernels else None,
    }


def measure(variant: str, repeats: int, run: bool) -> dict:
    """Median stage times of ``variant`` over ``repeats`` fresh processes."""
    env = dict(os.environ)
    env["XLA_FLAGS"] = f"{env.get('XLA_FLAGS', '')} {VARIANTS[variant]}".strip()
    env.update(TF_CPP_MIN_LOG_LEVEL="0", TF_CPP_VMODULE="cpu_compiler=1")
    command = [*lib.module_command("benchmarks.ablations.compile_time"), "--child"]
    if variant.startswith(("stub-", "swap-")):
        command += ["--stub", variant.split("-", 1)[1]]
    if run and not variant.startswith("stub-"):  # stubbed programs are not training
        command.append("--run")
    samples = []
    for _ in range(repeats):
        done = subprocess.run(
            command, env=env, check=True, capture_output=True, text=True, cwd=lib.REPO_ROOT
        )
        samples.append(json.loads(done.stdout.strip().splitlines()[-1]) | xla_timers(done.stderr))
    row = {"variant": variant, "xla_flags": VARIANTS[variant], "samples": samples}
    for key in samples[0]:
        values = [s[key] for s in samples if s[key] is not None]
        row[key] = statistics.median(values) if values else None
    return row


def markdown(report: dict) -> str:
    lines = [
        "# Cold compile of the default training step",
        "",
        f"`sb3` preset, one seed, one device; median of {report['repeats']} fresh processes, "
        "persistent cache off. Seconds (wall / CPU).",
        "",
        "| variant | XLA flags | trace | lower | XLA compile | of which HLO passes / codegen "
        "| total wall | HLO instructions | kernels | run ms / iteration |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in report["rows"]:
        total = r["trace_wall"] + r["lower_wall"] + r["compile_wall"]
        run = r.get("run_seconds_per_iteration")
        lines.append(
            f"| {r['variant']} | `{r['xla_flags'] or '-'}` | {r['trace_wall']:.2f} / "
            f"{r['trace_cpu']:.2f} | {r['lower_wall']:.2f} / {r['lower_cpu']:.2f} | "
            f"{r['compile_wall']:.2f} / {r['compile_cpu']:.2f} | "
            f"{r['hlo_passes_seconds']:.2f} / {r['codegen_seconds']:.2f} | {total:.2f} | "
            f"{r['hlo_instructions']:,} | {r['llvm_kernels'] or '-'} | "
            f"{f'{run * 1e3:.1f}' if run else '-'} |"
        )
    lines += ["", f"Command: `{report['command']}`", ""]
    lines += lib.machine_markdown(report["machine"])
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = lib.arg_parser(__doc__)
    parser.add_argument("--variants", default=",".join(VARIANTS))
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--run", action="store_true", help="also time a chunk's run")
    lib.add_out_option(parser)
    parser.add_argument("--child", action="store_true", help=argparse_hidden())
    parser.add_argument("--stub", help=argparse_hidden())
    args = parser.parse_args(argv)
    if args.child:
        print(json.dumps(child(args.run, args.stub)))
        return 0
    args.out = lib.output_dir(args.out)
    names = lib.split_list(args.variants)
    unknown = [n for n in names if n not in VARIANTS]
    if unknown:
        parser.error(f"unknown variant(s) {unknown}; choose from {', '.join(VARIANTS)}")
    rows = []
    for name in names:
        rows.append(measure(name, args.repeats, args.run))
        r = rows[-1]
        print(
            f"{name:<13} trace {r['trace_wall']:.2f}  lower {r['lower_wall']:.2f}  "
            f"compile {r['compile_wall']:.2f} s (cpu {r['compile_cpu']:.2f})  "
            f"{r['hlo_instructions']:,} HLO instructions",
            flush=True,
        )
    report = {
        "command": lib.command_line(),
        "machine": lib.machine_info(),
        "repeats": args.repeats,
        "rows": rows,
    }
    lib.write_report(args.out, "compile_time", report, markdown(report))
    return 0


def argparse_hidden() -> str:
    import argparse

    return argparse.SUPPRESS


if __name__ == "__main__":
    raise SystemExit(main())

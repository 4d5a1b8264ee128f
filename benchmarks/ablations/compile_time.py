"""Where the cold compile of the default training step goes, and what XLA flags do to it.

The default run (``python -m jaxcart.train``: the ``sb3`` preset, one seed, one device)
compiles one program, :func:`jaxcart.engine.chunk.train_chunk`. Each variant below runs in a fresh
process with the persistent cache off and measures, for that program:

- ``trace``: Python tracing to a jaxpr, ``lower``: jaxpr to StableHLO (JAX's side);
- ``compile``: XLA's side, split with XLA's own timers (``TF_CPP_VMODULE=cpu_compiler=1``)
  into its HLO optimisation passes and the rest (IR emission, LLVM optimisation and machine
  code for every kernel; the number of kernels is counted too);
- the optimised HLO's size (instructions) and its ``while`` loops;
- wall and CPU seconds of each stage, the median of ``--repeats`` fresh processes, and the
  best (least) total; the processes of all variants run in rounds, interleaved.

Variants (``--variants``, comma-separated; ``XLA_FLAGS`` of each):

- ``default``: the flags ``python -m jaxcart.train`` uses, the program it compiles;
- ``O0``/``O1``/``O2``: ``--xla_backend_optimization_level=0/1/2``: less LLVM optimisation,
  showing LLVM's share of the compile (and what it costs at run time: ``--run`` times a chunk);
- ``no-expensive``: ``--xla_llvm_disable_expensive_passes=true``;
- ``no-slp``: LLVM's SLP vectoriser off (``xla_cpu_disable_slp_vectorizer``);
- ``split-N``: ``--xla_cpu_parallel_codegen_split_count=N`` (codegen in N parallel parts);
- ``no-thunk``: ``--xla_cpu_use_thunk_runtime=false`` (XLA:CPU's older whole-program runtime);
- ``no-fusion-emitters``: ``--xla_cpu_use_fusion_emitters=false`` (XLA:CPU's older LLVM
  emitters instead of the MLIR fusion emitters; other numbers);
- ``hoist-loops``: ``xla_cpu_small_while_loop_byte_threshold=1000000``: XLA compiles every
  while loop small enough into one kernel (the rollout among them; other numbers);
- ``no-unroll``: ``xla_cpu_disable_loop_unrolling`` (LLVM unrolls no loop; other numbers);
- ``hoist-no-unroll``: ``hoist-loops`` and ``no-unroll`` together;
- ``stub-guard``, ``stub-update``, ``stub-episodes``: default flags, with the divergence
  guard, the minibatch update or the episode-statistics window replaced by a stub, to see
  what each part of the program costs to compile (these programs are not runnable training);
- ``swap-fused-adam``: gradient clipping and Adam as one update over the concatenated
  parameters (:func:`fused_clip_adam`) instead of optax's leaf-by-leaf chain: fewer kernels,
  but not bit-identical (XLA rounds the flat element-wise kernel differently), so not adopted;
- ``swap-one-scatter``: the episode window filled by one scatter of (return, length) pairs
  (the valid mask derived from the count);
- ``swap-scatter-window``: the episode window as it was before the ``top_k`` version (a
  reversed cumulative count as each episode's rank, a scatter per field);
- ``swap-leaf-guard``: the divergence guard's finiteness check leaf by leaf, as before.

``--before TREE`` also measures each variant with the benchmark and the code of another source
tree (for example ``git worktree add /tmp/before main``), its processes interleaved with this
tree's (alternating which goes first), so that both sides see the same load.

    python -m benchmarks.ablations.compile_time      # every variant, 3 processes each
    python -m benchmarks.ablations.compile_time --variants default,O1 --repeats 5 --run
    python -m benchmarks.ablations.compile_time --variants default --repeats 5 --run \\
        --before /tmp/before

Writes ``STEM.json`` and ``STEM.md`` (``--stem``, default ``compile_time``) to ``--out``
(default ``benchmarks/results/scratch``, not committed; ``--out benchmarks/results`` replaces the
committed figures).
"""

from __future__ import annotations

import json
import os
import re
import statistics
import subprocess
from pathlib import Path

from benchmarks import lib

VARIANTS = {
    "default": "",
    "O0": "--xla_backend_optimization_level=0",
    "O1": "--xla_backend_optimization_level=1",
    "O2": "--xla_backend_optimization_level=2",
    "no-expensive": "--xla_llvm_disable_expensive_passes=true",
    "no-slp": "--xla_backend_extra_options=xla_cpu_disable_slp_vectorizer",
    "split-2": "--xla_cpu_parallel_codegen_split_count=2",
    "split-4": "--xla_cpu_parallel_codegen_split_count=4",
    "no-thunk": "--xla_cpu_use_thunk_runtime=false",
    "no-fusion-emitters": "--xla_cpu_use_fusion_emitters=false",
    "hoist-loops": "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=1000000",
    "no-unroll": "--xla_backend_extra_options=xla_cpu_disable_loop_unrolling",
    "hoist-no-unroll": "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=1000000,xla_cpu_disable_loop_unrolling",
    # the same flags as default, with one part of the program stubbed out (what it costs)
    "stub-guard": "",
    "stub-update": "",
    "stub-episodes": "",
    # the same flags, with one part of the program computed another way
    "swap-fused-adam": "",
    "swap-one-scatter": "",
    "swap-scatter-window": "",
    "swap-leaf-guard": "",
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


def scatter_window(buffer, done, episode_return, episode_length):
    """The episode window as it was before the ``top_k`` version (the same numbers)."""
    import jax.numpy as jnp

    from jaxcart.core.metrics import EPISODE_WINDOW, EpisodeBuffer

    valid = jnp.concatenate([buffer.valid, done.reshape(-1)])
    returns = jnp.concatenate([buffer.returns, episode_return.reshape(-1).astype(jnp.float32)])
    lengths = jnp.concatenate([buffer.lengths, episode_length.reshape(-1).astype(jnp.float32)])
    rank = jnp.cumsum(valid[::-1])[::-1]
    slot = jnp.where(valid & (rank <= EPISODE_WINDOW), EPISODE_WINDOW - rank, EPISODE_WINDOW)
    empty = jnp.zeros((EPISODE_WINDOW,), jnp.float32)
    return EpisodeBuffer(
        returns=empty.at[slot].set(returns, mode="drop"),
        lengths=empty.at[slot].set(lengths, mode="drop"),
        valid=jnp.zeros((EPISODE_WINDOW,), bool).at[slot].set(True, mode="drop"),
    )


def leaf_guard(old, new, metrics, iteration):
    """The divergence guard with its finiteness check leaf by leaf, as before (same marks)."""
    import jax
    import jax.numpy as jnp

    finite = jnp.all(jnp.array([jnp.all(jnp.isfinite(x)) for x in jax.tree.leaves(new.params)]))
    for name in ("train/loss", "train/value_loss", "train/policy_gradient_loss"):
        finite &= jnp.isfinite(metrics[name])
    frozen = old.diverged_at >= 0
    diverged_at = jnp.where(frozen | finite, old.diverged_at, (iteration + 1).astype(jnp.int32))
    metrics = {k: jnp.where(frozen, jnp.nan, v) for k, v in metrics.items()}
    return new.replace(diverged_at=diverged_at), metrics


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

        def update(params, opt_state, batch, key, learning_rate, config):
            shape = (config.update_epochs, config.num_minibatches)
            return params, opt_state, {n: jnp.zeros(shape) for n in names}

        ppo.update_epochs = update
    elif part == "fused-adam":
        ppo.make_optimizer = lambda config: fused_clip_adam(config.max_grad_norm, config.adam_eps)
        chunk.make_optimizer = ppo.make_optimizer
    elif part == "one-scatter":
        ppo.update_episode_buffer = one_scatter
    elif part == "scatter-window":
        ppo.update_episode_buffer = scatter_window
    elif part == "leaf-guard":
        chunk.guard_divergence = leaf_guard


def child(run: bool, part: str | None) -> dict:
    """In a fresh process: trace, lower and compile the default run's chunk; optionally run it."""
    import time

    import jax

    jax.config.update("jax_enable_compilation_cache", False)
    import jax.numpy as jnp

    if part:
        stub(part)
    from jaxcart.core import cartpole
    from jaxcart.core.config import preset
    from jaxcart.engine import loop as trainer

    # the program `python -m jaxcart.train` compiles: one seed on one device, adaptive chunks
    config = preset("sb3")
    env_params = cartpole.EnvParams()
    state = trainer.initial_state(config, 1, 0, env_params=env_params)
    runners, configs = trainer.place((state.runners, state.config), jax.devices()[:1], 1, None)
    sharding = jax.tree.leaves(runners)[0].sharding
    program = trainer.chunk_program(env_params, state.chunk_size, sharding, adaptive=True)
    args = (runners, configs, jnp.int32(0), jnp.int32(state.chunk_size))

    marks = [(time.perf_counter(), time.process_time())]
    traced = program.trace(*args)
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
        jax.block_until_ready(compiled(*args))
        start = time.perf_counter()
        jax.block_until_ready(compiled(*args))
        out["run_seconds_per_iteration"] = (time.perf_counter() - start) / state.chunk_size
    return out


def xla_timers(log: str) -> dict:
    """XLA:CPU's own timers for the training program (module ``jit_training_chunk``) from its log."""

    def seconds(pattern: str) -> float:
        found = re.search(pattern + r" time: ([\d.]+) (ms|s|us)", log)
        if not found:
            return float("nan")
        scale = {"s": 1.0, "ms": 1e-3, "us": 1e-6}[found.group(2)]
        return float(found.group(1)) * scale

    kernels = re.findall(r"Running LLVM verifier time: .*#called: (\d+)\)", log)
    return {
        "hlo_passes_seconds": seconds(r"Running HLO passes on \[jit_training_chunk\] for CPU"),
        "codegen_seconds": seconds(r"Compiling \[jit_training_chunk\] for CPU using JIT"),
        "llvm_kernels": int(kernels[-1]) if kernels else None,
    }


def one_process(variant: str, run: bool, tree: Path) -> dict:
    """One fresh process of ``tree``'s benchmark compiling ``variant``: its stage times, XLA's
    timers, and the load average when it ended."""
    env = dict(os.environ)
    env["XLA_FLAGS"] = f"{env.get('XLA_FLAGS', '')} {VARIANTS[variant]}".strip()
    env.update(TF_CPP_MIN_LOG_LEVEL="0", TF_CPP_VMODULE="cpu_compiler=1")
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(tree), env.get("PYTHONPATH")]))
    command = [*lib.module_command("benchmarks.ablations.compile_time"), "--child"]
    if variant.startswith(("stub-", "swap-")):
        command += ["--stub", variant.split("-", 1)[1]]
    if run and not variant.startswith("stub-"):  # stubbed programs are not training
        command.append("--run")
    done = subprocess.run(command, env=env, check=True, capture_output=True, text=True, cwd=tree)
    sample = json.loads(done.stdout.strip().splitlines()[-1]) | xla_timers(done.stderr)
    for unit in ("wall", "cpu"):
        sample[f"total_{unit}"] = sum(sample[f"{s}_{unit}"] for s in ("trace", "lower", "compile"))
    sample["load"] = lib.load_average()
    return sample


def measure(names: list[str], repeats: int, run: bool, before: Path | None = None) -> list[dict]:
    """Every variant compiled in ``repeats`` fresh processes of this tree (and of ``before``),
    interleaved: each round runs every (variant, tree) once, in alternating order, so that a
    change of load touches every row alike. One row per (variant, tree): medians and best
    totals."""
    jobs = [(name, name, lib.REPO_ROOT) for name in names]
    if before:
        jobs += [(name, f"{name} (before)", before) for name in names]
    samples: dict[str, list[dict]] = {label: [] for _, label, _ in jobs}
    for i in range(repeats):
        for name, label, tree in jobs if i % 2 == 0 else jobs[::-1]:
            sample = one_process(name, run, tree)
            samples[label].append(sample)
            print(
                f"round {i + 1}: {label:<28} total {sample['total_wall']:.2f} s "
                f"(cpu {sample['total_cpu']:.2f})  {sample['llvm_kernels']} kernels  "
                f"load {sample['load'][0] if sample['load'] else '?'}",
                flush=True,
            )
    rows = []
    for name, label, tree in sorted(jobs, key=lambda job: (names.index(job[0]), job[1])):
        row = {"variant": label, "xla_flags": VARIANTS[name], "tree": str(tree)}
        row["samples"] = samples[label]
        for key in samples[label][0]:
            values = [s[key] for s in samples[label] if s[key] is not None and key != "load"]
            row[key] = statistics.median(values) if values else None
        row["best_total_wall"] = min(s["total_wall"] for s in samples[label])
        row["best_total_cpu"] = min(s["total_cpu"] for s in samples[label])
        rows.append(row)
    return rows


def markdown(report: dict) -> str:
    lines = [
        "# Cold compile of the default training step",
        "",
        f"`sb3` preset, one seed, one device; {report['repeats']} fresh processes per row, "
        "persistent cache off. Seconds (wall / CPU), medians; total wall and CPU also as the "
        "best of the processes.",
        "",
        "| variant | XLA flags | trace | lower | XLA compile | of which HLO passes / codegen "
        "| total wall: best / median | total CPU: best / median | HLO instructions | kernels "
        "| run ms / iteration |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in report["rows"]:
        run = r.get("run_seconds_per_iteration")
        lines.append(
            f"| {r['variant']} | `{r['xla_flags'] or '-'}` | {r['trace_wall']:.2f} / "
            f"{r['trace_cpu']:.2f} | {r['lower_wall']:.2f} / {r['lower_cpu']:.2f} | "
            f"{r['compile_wall']:.2f} / {r['compile_cpu']:.2f} | "
            f"{r['hlo_passes_seconds']:.2f} / {r['codegen_seconds']:.2f} | "
            f"{r['best_total_wall']:.2f} / {r['total_wall']:.2f} | "
            f"{r['best_total_cpu']:.2f} / {r['total_cpu']:.2f} | "
            f"{r['hlo_instructions']:,} | {r['llvm_kernels'] or '-'} | "
            f"{f'{run * 1e3:.1f}' if run else '-'} |"
        )
    loads = [s["load"][0] for r in report["rows"] for s in r["samples"] if s.get("load")]
    if loads:
        lines += [
            "",
            f"1-minute load average after each process: {min(loads):.2f} to {max(loads):.2f}.",
        ]
    lines += ["", f"Command: `{report['command']}`", ""]
    lines += lib.machine_markdown(report["machine"])
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = lib.arg_parser(__doc__)
    parser.add_argument("--variants", default=",".join(VARIANTS))
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--run", action="store_true", help="also time a chunk's run")
    parser.add_argument(
        "--before", type=Path, help="another source tree to measure too, interleaved"
    )
    parser.add_argument("--stem", default="compile_time", help="report file name (no suffix)")
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
    before = args.before.resolve() if args.before else None
    rows = measure(names, args.repeats, args.run, before)
    for r in rows:
        print(
            f"{r['variant']:<28} total best {r['best_total_wall']:.2f} s, median "
            f"{r['total_wall']:.2f} (cpu {r['total_cpu']:.2f})  compile "
            f"{r['compile_wall']:.2f} s  {r['llvm_kernels']} kernels  "
            f"{r['hlo_instructions']:,} HLO instructions",
            flush=True,
        )
    report = {
        "command": lib.command_line(),
        "machine": lib.machine_info(),
        "repeats": args.repeats,
        "before": str(before) if before else None,
        "rows": rows,
    }
    lib.write_report(args.out, args.stem, report, markdown(report))
    return 0


def argparse_hidden() -> str:
    import argparse

    return argparse.SUPPRESS


if __name__ == "__main__":
    raise SystemExit(main())

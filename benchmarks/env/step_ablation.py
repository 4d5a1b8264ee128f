"""What one jaxcart env step costs, part by part, in the throughput benchmark's harness.

Variants of the step, each run through the harness's one JAX rollout
(``contenders.jax_rollout``: same actions, every output consumed) on one pinned
core with one JAX device, timed interleaved over ``--rounds``:

- ``step_batch``: jaxcart's env as benchmarked (physics, termination, autoreset with reset
  states from the keyed counter hash);
- ``fixed-reset``: the same with the reset states fixed (no hashing): what drawing them costs;
- ``physics-only``: :func:`jaxcart.core.cartpole.step_env` alone (no autoreset at all; episodes run on
  past their end, so this is not a usable env, only a floor);
- ``sincos-once``: ``step_batch`` with sin and cos of the pole angle evaluated once per env
  (:func:`jaxcart.gym.kernels.sin_cos_once`, as the Gymnasium vector adapter does). XLA:CPU
  otherwise calls libm's ``sincosf`` in each of the three fusions that use them. Same values,
  but not adopted for training: it changes which multiply-adds XLA contracts into FMAs in the
  training program, so training is no longer bit-identical (``benchmarks/RESULTS.md``);
- ``gymnax``: gymnax 1.x's ``vmap(step)`` for reference (if installed).

    benchmarks/.venv-bench/bin/python -m benchmarks.env.step_ablation
    benchmarks/.venv-bench/bin/python -m benchmarks.env.step_ablation --num-envs 65536

Writes ``env_step_ablation.json`` and ``.md`` to ``--out`` (default
``benchmarks/results/scratch``, not committed; ``--out benchmarks/results`` replaces the committed
figures).
"""

from __future__ import annotations

import os

os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})

import functools  # noqa: E402
import statistics  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

import jaxcart.core.cartpole as cartpole  # noqa: E402
from benchmarks import lib  # noqa: E402
from benchmarks.env import contenders  # noqa: E402
from jaxcart.core import pytree  # noqa: E402
from jaxcart.core.cartpole import hash_uniform  # noqa: E402
from jaxcart.gym import kernels  # noqa: E402

VARIANTS = ("step_batch", "fixed-reset", "physics-only", "sincos-once", "gymnax")


def rollout(variant: str, num_envs: int, num_steps: int):
    """``(fn, carry)`` of the harness's rollout with the variant's step."""
    if variant == "gymnax":
        return contenders.gymnax_random_rollout(num_envs, num_steps)
    params = cartpole.EnvParams()

    def step(key, state, actions):
        if variant == "step_batch":
            return cartpole.step_batch(key, state, actions, params)[:5]
        if variant == "sincos-once":
            final_obs, next_state, reward, terminated, truncated = cartpole.step_env(
                state, actions, params, kernels.sin_cos_once
            )
            done = terminated | truncated
            noise = hash_uniform(
                key, (done.shape[0], 4), final_obs.dtype, params.reset_low, params.reset_high
            )
            fresh = (noise, cartpole.state_from_obs(noise))
            obs, state = pytree.where(done, fresh, (final_obs, next_state))
            return obs, state, reward, terminated, truncated
        final_obs, next_state, reward, terminated, truncated = cartpole.step_env(
            state, actions, params
        )
        if variant == "physics-only":
            return final_obs, next_state, reward, terminated, truncated
        done = terminated | truncated
        noise = jnp.full_like(final_obs, 0.01)
        fresh = (noise, cartpole.state_from_obs(noise))
        obs, state = pytree.where(done, fresh, (final_obs, next_state))
        return obs, state, reward, terminated, truncated

    def reset_state(key, n):
        keys = jax.random.split(key, n)
        return jax.vmap(cartpole.reset, in_axes=(0, None))(keys, params)[1]

    return contenders.jax_rollout(step, reset_state, num_envs, num_steps)


def main(argv: list[str] | None = None) -> int:
    parser = lib.arg_parser(__doc__)
    parser.add_argument("--num-envs", type=int, default=4096)
    parser.add_argument("--rounds", type=int, default=7)
    lib.add_out_option(parser)
    args = parser.parse_args(argv)
    args.out = lib.output_dir(args.out)
    num_steps = contenders.scan_length(args.num_envs)
    built = {}
    for variant in VARIANTS:
        try:
            fn, carry = rollout(variant, args.num_envs, num_steps)
        except contenders.Unavailable as e:
            print(f"{variant}: {e}")
            continue
        compiled = fn.lower(carry).compile()
        built[variant] = [compiled, compiled(carry)]
        jax.block_until_ready(built[variant][1])

    def step(holder: list):  # runs the next call on the last one's state
        holder[1] = holder[0](holder[1])
        return holder[1]

    calls = {v: functools.partial(step, holder) for v, holder in built.items()}
    times = lib.interleaved_times(calls, args.rounds)
    steps = args.num_envs * num_steps
    rows = [
        {"variant": v, "steps_per_second": steps / statistics.median(t), "seconds": t}
        for v, t in times.items()
    ]
    lines = [
        f"# One jaxcart env step, part by part (N = {args.num_envs:,}, one core)",
        "",
        f"Median of {args.rounds} interleaved calls of {steps:,} env steps each.",
        "",
        "| variant | M steps/s | ns per env step |",
        "| --- | ---: | ---: |",
    ]
    for r in rows:
        rate = r["steps_per_second"]
        lines.append(f"| {r['variant']} | {rate / 1e6:.1f} | {1e9 / rate:.1f} |")
    report = {
        "command": lib.command_line(),
        "machine": lib.machine_info([str(d) for d in jax.devices()]),
        "num_envs": args.num_envs,
        "rows": rows,
    }
    text = "\n".join(
        lines
        + ["", f"Command: `{report['command']}`", ""]
        + lib.machine_markdown(report["machine"])
    )
    lib.write_report(args.out, "env_step_ablation", report, text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Where one PPO iteration's time goes: rollout, GAE, update; and compile time.

Each phase is jitted on its own, vmapped over S seeds on one CPU device (what each core runs
when seeds are sharded), and timed as the median of repeated calls after a warm-up:

    python -m benchmarks.ablations.profile_step --preset sb3 --seeds 1,32 --out benchmarks/results

Writes ``profile_step.json`` and ``profile_step.md`` to ``--out`` (default
``benchmarks/results/scratch``, not committed).
"""

from __future__ import annotations

import os

os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=1")

import functools

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks import lib
from jaxcart.core import cartpole
from jaxcart.core.config import preset
from jaxcart.core.ppo import collect_rollout, training_batch, update_epochs
from jaxcart.engine.chunk import train_chunk
from jaxcart.engine.loop import init_runners


def profile(preset_name: str, seeds: int) -> dict:
    config = preset(preset_name)
    env_params = cartpole.EnvParams()
    runners = jax.device_put(init_runners(config, 0, np.arange(seeds), env_params))
    configs = config.per_run(seeds)  # every seed's config, traced fields [S]

    rollout_fn = jax.vmap(lambda r: collect_rollout(r, config, env_params))
    _, rollout_s = lib.compile_and_time(rollout_fn, (runners,))
    _, rollout = jax.jit(rollout_fn)(runners)

    # GAE (and the flattening into one batch, free): the stage between rollout and update
    gae_fn = jax.vmap(lambda r, roll, c: training_batch(r.params, roll, c))
    _, gae_s = lib.compile_and_time(gae_fn, (runners, rollout, configs))
    batch = jax.jit(gae_fn)(runners, rollout, configs)
    keys = jax.random.split(jax.random.PRNGKey(0), seeds)
    update_fn = jax.vmap(
        lambda r, b, k, c: update_epochs(r.params, r.opt_state, b, k, c.learning_rate, c)
    )
    _, update_s = lib.compile_and_time(update_fn, (runners, batch, keys, configs))

    chunk = functools.partial(train_chunk, env_params=env_params, chunk_size=2)
    compile_s, chunk_s = lib.compile_and_time(chunk, (runners, configs, jnp.int32(0)), repeats=3)
    iteration_s = chunk_s / 2
    return {
        "preset": preset_name,
        "seeds": seeds,
        "compile_s": compile_s,
        "iteration_s": iteration_s,
        "rollout_s": rollout_s,
        "gae_s": gae_s,
        "update_s": update_s,
        "other_s": max(0.0, iteration_s - rollout_s - gae_s - update_s),
        "gradient_steps_per_iteration": config.update_epochs * config.num_minibatches,
        "update_us_per_gradient_step": update_s
        / (config.update_epochs * config.num_minibatches)
        * 1e6,
        "rollout_us_per_env_step": rollout_s / config.num_steps * 1e6,
    }


def markdown_lines(report: dict, preset_name: str) -> list[str]:
    """The Markdown summary of ``profile_step.json``."""
    lines = [
        f"# Where one `{preset_name}` iteration's time goes (one CPU device)",
        "",
        "| seeds on the device | compile s | iteration ms | rollout ms | GAE ms | update ms "
        "| other ms | update µs / gradient step | rollout µs / step |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in report["rows"]:
        lines.append(
            f"| {r['seeds']} | {r['compile_s']:.2f} | {r['iteration_s'] * 1e3:.1f} | "
            f"{r['rollout_s'] * 1e3:.1f} | "
            f"{r['gae_s'] * 1e3:.2f} | {r['update_s'] * 1e3:.1f} | {r['other_s'] * 1e3:.1f} | "
            f"{r['update_us_per_gradient_step']:.0f} | {r['rollout_us_per_env_step']:.1f} |"
        )
    command = report["command"]
    return [*lines, "", f"Command: `{command}`", "", *lib.machine_markdown(report["machine"])]


def main() -> None:
    parser = lib.arg_parser(__doc__)
    parser.add_argument("--preset", default="sb3")
    parser.add_argument("--seeds", type=lib.parse_ints, default="1,32")
    lib.add_out_option(parser)
    args = parser.parse_args()
    args.out = lib.output_dir(args.out)
    rows = [profile(args.preset, s) for s in args.seeds]
    report = {"command": lib.command_line(), "machine": lib.machine_info(), "rows": rows}
    lib.write_json(args.out / "profile_step.json", report)
    lib.write_markdown(args.out / "profile_step.md", markdown_lines(report, args.preset))


if __name__ == "__main__":
    main()

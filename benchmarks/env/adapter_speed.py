"""Speed of jaxcart's Gymnasium adapter against Gymnasium's own CartPole, through one harness.

Pairs, each at every number of envs N in ``--sizes`` where it applies:

- ``single`` (N = 1): ``jaxcart.gym.adapter.JaxCartPoleEnv`` against Gymnasium's
  ``CartPoleEnv``, reset whenever an episode ends.
- ``vector``: ``JaxCartPoleVectorEnv(N)`` against Gymnasium's ``CartPoleVectorEnv(N)``, both
  with their default next-step autoreset.
- ``vector-same-step``: ``JaxCartPoleVectorEnv(N, autoreset_mode="SameStep")`` (which builds
  the ``final_obs`` info) against the same Gymnasium ``CartPoleVectorEnv(N)`` (which has no
  same-step mode).
- ``sync`` (1 < N <= 64): Gymnasium's ``SyncVectorEnv`` of N ``JaxCartPoleEnv`` against N
  ``CartPoleEnv`` (what ``gym.make_vec(..., vectorization_mode="sync")`` builds, without the
  wrappers).

The envs are built directly (no ``TimeLimit``/``OrderEnforcing``/checker wrappers, which cost
both sides the same). Both contenders of a pair run the same harness code on the same
uniformly random actions (``numpy.random.default_rng((seed, repeat)).integers(0, 2, ...)``,
drawn before the timed loop), the same number of steps, and every output is consumed (reward
summed, ends counted, one observation element and the info's size read). Measurements
alternate between the two contenders (the order flips every repeat); the figures are medians
over ``--repeats``. Construction, compilation, the first reset and a short warm-up are
excluded.

Also measured: JAX's per-call dispatch cost on this machine (which bounds N = 1), where a
jaxcart step's time goes (the action check, the compiled call, the transfer, the unpacking),
and, in a subprocess, the single and vector pairs again with JAX's CPU computations run on the
calling thread (``jax_cpu_enable_async_dispatch=False``, a process-wide JAX setting).

    python -m benchmarks.env.adapter_speed            # about a minute and a half
    python -m benchmarks.env.adapter_speed --quick    # smoke test, seconds
    python -m benchmarks.env.adapter_speed --sizes 1,64 --repeats 9 --kinds vector

Writes ``adapter_speed.json`` and ``.md`` to ``--out`` (default ``benchmarks/results/scratch``, not
committed; ``--out benchmarks/results`` replaces the committed figures).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
from gymnasium.envs.classic_control.cartpole import CartPoleEnv, CartPoleVectorEnv

from benchmarks import lib
from jaxcart.gym import adapter
from jaxcart.gym.adapter import JaxCartPoleEnv, JaxCartPoleVectorEnv

STEM = "adapter_speed"
KINDS = ("single", "vector", "vector-same-step", "sync")
DEFAULT_SIZES = (1, 64, 4096)
SEED = 0
# Env steps (N per vector step) per measurement; the sync pair steps N Python envs per step.
# The vector pairs: 293 steps at N = 4096 (about 60 ms), so that other jobs on a shared machine
# do not decide a measurement (at 120,000 it was 29 steps, about 6 ms).
ENV_STEPS = {"single": 30_000, "vector": 1_200_000, "vector-same-step": 1_200_000, "sync": 10_000}
SYNC_MAX_ENVS = 64  # a SyncVectorEnv of 4096 single envs takes tens of ms per step
MAX_STEPS, MIN_STEPS = 10_000, 10
LABELS = {
    "single": "single env",
    "vector": "vector env (next-step autoreset)",
    "vector-same-step": "vector env, jaxcart same-step vs Gymnasium next-step",
    "sync": "SyncVectorEnv of single envs",
}


def make_pair(kind: str, num_envs: int) -> dict[str, Callable[[], object]]:
    """Constructors of the two contenders of ``kind`` at ``num_envs``: jaxcart, Gymnasium."""
    if kind == "single":
        return {"jaxcart": JaxCartPoleEnv, "gymnasium": CartPoleEnv}
    if kind == "vector":
        return {
            "jaxcart": lambda: JaxCartPoleVectorEnv(num_envs),
            "gymnasium": lambda: CartPoleVectorEnv(num_envs),
        }
    if kind == "vector-same-step":
        return {
            "jaxcart": lambda: JaxCartPoleVectorEnv(num_envs, autoreset_mode="SameStep"),
            "gymnasium": lambda: CartPoleVectorEnv(num_envs),
        }
    return {
        "jaxcart": lambda: gym.vector.SyncVectorEnv([JaxCartPoleEnv] * num_envs),
        "gymnasium": lambda: gym.vector.SyncVectorEnv([CartPoleEnv] * num_envs),
    }


def applies(kind: str, num_envs: int) -> bool:
    """The single env runs at N = 1 only (a SyncVectorEnv of one env would repeat it), the
    SyncVectorEnv pair up to :data:`SYNC_MAX_ENVS`."""
    if kind == "single":
        return num_envs == 1
    return kind != "sync" or 1 < num_envs <= SYNC_MAX_ENVS


def num_steps(kind: str, num_envs: int, quick: bool) -> int:
    steps = ENV_STEPS[kind] // num_envs // (10 if quick else 1)
    return int(min(MAX_STEPS, max(MIN_STEPS, steps)))


def actions_for(kind: str, num_envs: int, steps: int, repeat: int) -> list:
    """The actions of measurement ``repeat``: the same for both contenders."""
    rng = np.random.default_rng((SEED, repeat + 1))  # repeat -1: the warm-up
    if kind == "single":
        return [int(a) for a in rng.integers(0, 2, steps)]
    return list(rng.integers(0, 2, (steps, num_envs)))


def drive(env, actions: list, single: bool) -> tuple[float, dict]:
    """Steps ``env`` through ``actions``, consuming every output; returns the seconds taken
    and what was consumed (to check that both contenders did the same work)."""
    reward_sum, ends, obs_sum, info_items = 0.0, 0, 0.0, 0
    start = time.perf_counter()
    if single:
        for action in actions:
            obs, reward, terminated, truncated, info = env.step(action)
            reward_sum += reward
            obs_sum += obs[0]
            info_items += len(info)
            if terminated or truncated:
                ends += 1
                env.reset()
    else:
        for action in actions:
            obs, reward, terminated, truncated, info = env.step(action)
            reward_sum += reward.sum()
            ends += np.count_nonzero(terminated) + np.count_nonzero(truncated)
            obs_sum += obs[-1, -1]
            info_items += len(info)
    seconds = time.perf_counter() - start
    consumed = {"reward_sum": float(reward_sum), "episode_ends": int(ends)}
    consumed.update(obs_sum=float(obs_sum), info_items=info_items)
    return seconds, consumed


def measure_pair(kind: str, num_envs: int, repeats: int, quick: bool) -> dict:
    """Both contenders of ``kind`` at ``num_envs``, measured alternately ``repeats`` times."""
    steps = num_steps(kind, num_envs, quick)
    single = kind == "single"
    envs, setup = {}, {}
    for name, make in make_pair(kind, num_envs).items():
        start = time.perf_counter()
        envs[name] = make()
        envs[name].reset(seed=SEED)
        setup[name] = time.perf_counter() - start
        drive(envs[name], actions_for(kind, num_envs, max(2, steps // 20), -1), single)
    rates: dict[str, list[float]] = {name: [] for name in envs}
    consumed: dict[str, list[dict]] = {name: [] for name in envs}
    for repeat in range(repeats):
        actions = actions_for(kind, num_envs, steps, repeat)
        order = list(envs) if repeat % 2 == 0 else list(envs)[::-1]
        for name in order:
            seconds, used = drive(envs[name], actions, single)
            rates[name].append(num_envs * steps / seconds)
            consumed[name].append(used)
    for env in envs.values():
        env.close()
    paired = [j / g for j, g in zip(rates["jaxcart"], rates["gymnasium"])]
    return {
        "kind": kind,
        "num_envs": num_envs,
        "steps_per_measurement": steps,
        "setup_seconds": setup,
        "steps_per_second": rates,
        "median_steps_per_second": {k: statistics.median(v) for k, v in rates.items()},
        "paired_ratios": paired,
        "median_paired_ratio": statistics.median(paired),
        "episode_ends": {k: sum(c["episode_ends"] for c in v) for k, v in consumed.items()},
    }


def per_call_microseconds(fn: Callable[[], object], calls: int, repeats: int = 7) -> float:
    """Median over ``repeats`` of the mean time of one ``fn()`` in a loop of ``calls``, µs."""
    fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(calls):
            fn()
        times.append((time.perf_counter() - start) / calls * 1e6)
    return statistics.median(times)


def dispatch_costs(quick: bool) -> dict:
    """JAX's fixed cost per call on this machine, µs: an empty jitted function; a small one
    and its result fetched to NumPy; the same with over 1000 flops, which XLA's CPU client
    hands to a worker thread instead of running it on the calling thread."""
    calls = 1000 if quick else 10000
    empty = jax.jit(lambda: None)
    add_one = jax.jit(lambda x: x + 1)
    small, large = jnp.zeros(5), jnp.zeros(1024)
    return {
        "empty_jit_call_us": per_call_microseconds(empty, calls),
        "small_call_and_fetch_us": per_call_microseconds(lambda: np.array(add_one(small)), calls),
        "call_and_fetch_over_1000_flops_us": per_call_microseconds(
            lambda: np.array(add_one(large)), calls
        ),
    }


def profile_vector(num_envs: int, quick: bool) -> dict:
    """Where a ``JaxCartPoleVectorEnv`` step's time goes, µs per step (reaches into the
    adapter's internals: the compiled step, its device rows, its keys)."""
    env = JaxCartPoleVectorEnv(num_envs)
    env.reset(seed=SEED)
    actions = np.random.default_rng(SEED).integers(0, 2, num_envs)
    calls = max(20, (100 if quick else 1000) * 64 // max(num_envs, 64))
    inputs = np.concatenate([actions, [1, 2]]).astype(np.uint32)  # actions, then a key

    def compiled_call():  # as JaxCartPoleVectorEnv.step: the new rows go into the spare buffer
        rows = env._step_fn(env._rows, env._spare, inputs, env._floats)
        env._rows, env._spare = rows, env._rows
        rows.block_until_ready()

    rows = np.array(env._rows)

    def read():  # the step's one transfer: a read-only view, no copy on CPU
        return np.asarray(env._rows)[0, 0]

    def unpack():
        obs = rows[:4].T.astype(np.float32)
        code = rows[6].astype(np.uint8)  # terminated + 2 * truncated
        return obs, rows[5].astype(np.float32), (code & 1) != 0, (code & 2) != 0

    gymnasium = CartPoleVectorEnv(num_envs)
    gymnasium.reset(seed=SEED)
    angles = np.random.default_rng(SEED).uniform(-0.2, 0.2, num_envs)
    with jax.enable_x64(True):
        trig = jax.jit(lambda theta: (jnp.sin(theta), jnp.cos(theta)))
        device_angles = jnp.asarray(angles)
    profile = {
        "jaxcart step": per_call_microseconds(lambda: env.step(actions), calls),
        "action check (action_space.contains)": per_call_microseconds(
            lambda: env.action_space.contains(actions), calls
        ),
        "action check (the adapter's: integer array, every action 0 or 1)": per_call_microseconds(
            lambda: adapter._valid_actions(actions, env.action_space), calls
        ),
        "compiled call, waited for": per_call_microseconds(compiled_call, calls),
        "device-to-host read (np.asarray, no copy)": per_call_microseconds(read, calls),
        "unpacking (obs cast, reward, flags)": per_call_microseconds(unpack, calls),
        "f64 sin and cos of N angles, one jitted XLA call": per_call_microseconds(
            lambda: jax.block_until_ready(trig(device_angles)), calls
        ),
        "f64 sin and cos of N angles, NumPy": per_call_microseconds(
            lambda: (np.sin(angles), np.cos(angles)), calls
        ),
        "Gymnasium CartPoleVectorEnv step": per_call_microseconds(
            lambda: gymnasium.step(actions), calls
        ),
    }
    hlo = env._step_fn.as_text()
    return {
        "num_envs": num_envs,
        "microseconds_per_step": profile,
        "step_fusions": hlo[hlo.index("ENTRY") :].count(" fusion("),
        "sin_cos_in_fused_computations": hlo.count(" sine(") + hlo.count(" cosine("),
    }


def profile_single(quick: bool) -> dict:
    """Where a ``JaxCartPoleEnv`` step's time goes, µs per step."""
    env, gymnasium = JaxCartPoleEnv(), CartPoleEnv()
    calls = 1000 if quick else 10000

    def step(e):
        if e.step(1)[2]:
            e.reset()

    def compiled_call():
        env._device_state = env._step_fn(env._device_state, env._device_actions[1], env._floats)
        env._device_state.block_until_ready()

    for e in (env, gymnasium):
        e.reset(seed=SEED)
        e.step(1)
    profile = {
        "jaxcart step": per_call_microseconds(lambda: step(env), calls),
        "action check (action_space.contains)": per_call_microseconds(
            lambda: env.action_space.contains(1), calls
        ),
        "compiled call, waited for": per_call_microseconds(compiled_call, calls),
        "device-to-host copy (np.array)": per_call_microseconds(
            lambda: np.array(env._device_state), calls
        ),
        "Gymnasium CartPoleEnv step": per_call_microseconds(lambda: step(gymnasium), calls),
    }
    return {"num_envs": 1, "microseconds_per_step": profile}


def results_table(results: list[dict]) -> str:
    rows = []
    for r in results:
        med = r["median_steps_per_second"]
        ratios = r["paired_ratios"]
        rows.append(
            [
                LABELS[r["kind"]],
                f"{r['num_envs']:,}",
                lib.format_rate(med["jaxcart"]),
                lib.format_rate(med["gymnasium"]),
                lib.format_ratio(med["jaxcart"] / med["gymnasium"]),
                f"{lib.format_ratio(min(ratios))} - {lib.format_ratio(max(ratios))}",
            ]
        )
    headers = ["pair", "N", "jaxcart steps/s", "Gymnasium steps/s", "ratio", "paired range"]
    return lib.markdown_table(headers, rows, "lrrrrr")


def profile_tables(report: dict) -> list[str]:
    out = []
    for prof in report["profiles"]:
        rows = [[k, f"{v:,.1f}"] for k, v in prof["microseconds_per_step"].items()]
        env = "vector env" if "step_fusions" in prof else "single env"
        title = f"{env}, N = {prof['num_envs']:,}:"
        out += [title, "", lib.markdown_table(["", "µs"], rows), ""]
    return out


def dispatch_lines(d: dict, asynchronous: bool = True) -> list[str]:
    how = (
        "with JAX's default asynchronous CPU dispatch, XLA's CPU client runs it on a worker "
        "thread and the caller waits for it"
        if asynchronous
        else "here run on the calling thread too"
    )
    return [
        "JAX's fixed cost per call on this machine (µs, median):",
        "",
        f"- an empty jitted function: {d['empty_jit_call_us']:.1f}",
        f"- a 5-element `x + 1`, result fetched to NumPy: {d['small_call_and_fetch_us']:.1f}",
        f"- the same on 1024 elements (over XLA's 1000-flop threshold; {how}): "
        f"{d['call_and_fetch_over_1000_flops_us']:.1f}",
    ]


def sync_dispatch_lines(report: dict) -> list[str]:
    """The subprocess run with ``jax_cpu_enable_async_dispatch=False``, if there was one."""
    sync = report.get("sync_dispatch")
    if not sync:
        return []
    return [
        "The same pairs in a fresh interpreter with "
        '`jax.config.update("jax_cpu_enable_async_dispatch", False)` set before JAX first '
        "runs, so that XLA runs every step on the calling thread (a process-wide JAX setting, "
        "which the adapter leaves to the user):",
        "",
        results_table(sync["results"]),
        "",
        *dispatch_lines(sync["dispatch"], asynchronous=False),
        "",
    ]


def markdown(report: dict) -> str:
    s = report["settings"]
    d = report["dispatch"]
    lines = [
        "# jaxcart's Gymnasium adapter against Gymnasium's CartPole",
        "",
        "Env steps per second (N envs together), uniformly random actions drawn before the "
        "timed loop, every output consumed, the same harness for both. Median of "
        f"{s['repeats']} alternating measurements; *ratio* = jaxcart / Gymnasium of the "
        "medians (above 1: jaxcart faster), *paired range* = the lowest and highest ratio of "
        "the measurements taken back to back. Construction, compilation and warm-up "
        "excluded. Both float64 (jaxcart's default, as Gymnasium's).",
        "",
        results_table(report["results"]),
        "",
        *dispatch_lines(d),
        "",
        *sync_dispatch_lines(report),
        "Where a jaxcart step's time goes (µs per step, each part timed on its own in a loop; "
        "Gymnasium's step alongside). The compiled step is jaxcart's `step_env` plus the "
        "autoreset; XLA:CPU runs it as "
        f"{report['profiles'][-1]['step_fusions']} fusions that hold "
        f"{report['profiles'][-1]['sin_cos_in_fused_computations']} sin/cos evaluations "
        "of θ between them (`jaxcart.gym.kernels.sin_cos_once` makes it one sin and one cos, "
        "a single libm `sincos` call per env; XLA's own choice was two of each, one pair per "
        "fusion that uses them). The f64 trigonometry is timed alone below:",
        "",
        *profile_tables(report),
    ]
    lines += lib.provenance_markdown(report)
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    parser = lib.arg_parser(__doc__)
    parser.add_argument(
        "--sizes",
        type=lambda t: lib.parse_ints(t, "sizes must be positive"),
        default=list(DEFAULT_SIZES),
        help="numbers of envs N (default 1,64,4096)",
    )
    parser.add_argument("--repeats", type=int, default=None, help="default 7 (--quick: 3)")
    parser.add_argument(
        "--kinds",
        type=lib.split_list,
        default=list(KINDS),
        help=f"comma-separated pairs to run (default all: {','.join(KINDS)})",
    )
    parser.add_argument("--quick", action="store_true", help="smoke test: a tenth of the steps")
    parser.add_argument(
        "--jax-sync-dispatch",
        action="store_true",
        help="run JAX's CPU computations on the calling thread "
        "(jax_cpu_enable_async_dispatch=False); the full run does this in a subprocess too",
    )
    parser.add_argument(
        "--no-profile",
        action="store_true",
        help="measure the pairs and the dispatch cost only; write the JSON only",
    )
    parser.add_argument("--out", type=Path, default=None, help="output folder")
    parser.add_argument(
        "--from-json", type=Path, default=None, help="only re-render the Markdown of a saved run"
    )
    return parser


def measure_all(args, repeats: int) -> list[dict]:
    """Every pair of ``args.kinds`` at every size of ``args.sizes``, printed as it goes."""
    results = []
    for n in args.sizes:
        for kind in [k for k in KINDS if k in args.kinds and applies(k, n)]:
            row = measure_pair(kind, n, repeats, args.quick)
            results.append(row)
            med = row["median_steps_per_second"]
            print(
                f"{kind:>16} N={n:>5}: jaxcart {med['jaxcart']:>12,.0f}  "
                f"gymnasium {med['gymnasium']:>12,.0f}  ratio {row['median_paired_ratio']:.2f}",
                flush=True,
            )
    return results


def sync_dispatch_run(args, repeats: int) -> dict:
    """The single and vector pairs again in a fresh interpreter whose JAX runs computations
    on the calling thread (the setting must precede JAX's first use, hence the subprocess)."""
    kinds = ",".join(k for k in ("single", "vector") if k in args.kinds)
    with tempfile.TemporaryDirectory() as tmp:
        command = [*lib.module_command("benchmarks.env.adapter_speed"), "--jax-sync-dispatch"]
        command.append("--no-profile")
        command += ["--kinds", kinds, "--sizes", ",".join(map(str, args.sizes))]
        command += ["--repeats", str(repeats), "--out", tmp] + ["--quick"] * args.quick
        print("with jax_cpu_enable_async_dispatch=False:", flush=True)
        subprocess.run(command, check=True, stdout=sys.stderr, cwd=lib.REPO_ROOT)
        sub = json.loads((Path(tmp) / f"{STEM}.json").read_text())
    return {"results": sub["results"], "dispatch": sub["dispatch"]}


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.jax_sync_dispatch:
        # Must precede JAX's first use of the CPU.
        jax.config.update("jax_cpu_enable_async_dispatch", False)
    if args.from_json:
        report = json.loads(args.from_json.read_text())
        lib.write_markdown(args.from_json.with_suffix(".md"), markdown(report).splitlines())
        return 0
    unknown = set(args.kinds) - set(KINDS)
    if unknown:
        raise SystemExit(f"unknown --kinds {sorted(unknown)}; choose from {', '.join(KINDS)}")
    repeats = args.repeats or (3 if args.quick else 7)
    out = lib.output_dir(args.out)
    settings = {"sizes": args.sizes, "repeats": repeats, "kinds": args.kinds, "seed": SEED}
    settings.update(quick=args.quick, env_steps_per_measurement=ENV_STEPS)
    settings.update(jax_cpu_enable_async_dispatch=not args.jax_sync_dispatch)
    report = lib.new_report(
        STEM, settings, ["jaxcart", "gymnasium"], [str(d) for d in jax.devices()]
    )
    report["results"] = measure_all(args, repeats)
    report["dispatch"] = dispatch_costs(args.quick)
    if not args.no_profile:
        report["profiles"] = [profile_single(args.quick)] + [
            profile_vector(n, args.quick) for n in args.sizes
        ]
    if not (args.jax_sync_dispatch or args.no_profile):
        report["sync_dispatch"] = sync_dispatch_run(args, repeats)
    report["load_average_end"] = lib.load_average()
    out.mkdir(parents=True, exist_ok=True)
    lib.write_json(out / f"{STEM}.json", report)
    if not args.no_profile:
        lib.write_markdown(out / f"{STEM}.md", markdown(report).splitlines())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

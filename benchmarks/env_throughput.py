"""CartPole-v1 environment throughput: steps per second with random actions and autoreset on.

Contenders, each at every number of parallel environments N in ``--sizes``:

- ``jaxcart``: ``jit(scan(vmap(jaxcart.env.step)))`` with actions drawn by ``jax.random``
  inside the scan; the env axis is sharded over all JAX devices (one per CPU core) when N is
  divisible by the device count (see :func:`jaxcart_random_rollout`).
- ``gymnax``: gymnax 1.x ``CartPole-v1`` (its ``step`` autoresets), run the same way.
- ``gymnasium-vector``: Gymnasium's NumPy ``CartPoleVectorEnv``
  (``make_vec(..., vectorization_mode="vector_entry_point")``), actions from ``rng.integers``.
- ``gymnasium-sync``: ``SyncVectorEnv`` of ``gym.make("CartPole-v1")`` (a Python loop over
  N envs); skipped above ``--sync-max-envs``.
- ``envpool``: ``envpool.make("CartPole-v1", env_type="gymnasium", num_envs=N)`` (C++ threads).

Random actions are generated inside the timed region for every contender. Compilation (JAX)
or construction and reset (the others) is timed on its own and excluded from throughput. Each
measurement runs enough steps to take about ``--seconds``; the figure is the median of
``--repeats`` measurements.

    python benchmarks/env_throughput.py                    # the full run (several minutes)
    python benchmarks/env_throughput.py --quick            # smoke test, seconds
    python benchmarks/env_throughput.py --sizes 1,256 --repeats 3 --only jaxcart,gymnax

Writes ``env_throughput.json``, ``.md`` and ``.png`` to ``--out`` (default
``benchmarks/results``, or ``benchmarks/results/quick`` with ``--quick``). Install the
peers with ``bash benchmarks/setup_venvs.sh`` and run with ``benchmarks/.venv-bench/bin/python``;
a contender that is not installed is reported as unavailable.
"""

from __future__ import annotations

from jaxcart import devices

devices.use_all_host_cores()

import argparse  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402
from collections.abc import Callable  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from pathlib import Path  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from jax.sharding import Mesh, NamedSharding, PartitionSpec  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import benchlib  # noqa: E402

import jaxcart.env as cartpole  # noqa: E402

CONTENDERS = ("jaxcart", "gymnax", "gymnasium-vector", "gymnasium-sync", "envpool")
LABELS = {
    "jaxcart": "jaxcart (jit/scan/vmap)",
    "gymnax": "gymnax 1.x (jit/scan/vmap)",
    "gymnasium-vector": "Gymnasium CartPoleVectorEnv (NumPy)",
    "gymnasium-sync": "Gymnasium SyncVectorEnv",
    "envpool": "EnvPool (C++)",
}
DEFAULT_SIZES = (1, 16, 256, 4096, 65536)
QUICK_SIZES = (1, 16, 256)
# Env steps per compiled call (num_steps x num_envs) aimed at; a call is a scan this long.
STEPS_PER_CALL = 2**19
MAX_SCAN_LENGTH = 2000


class Unavailable(Exception):
    """A contender cannot run here (not installed, or fails to start); the message says why."""


@dataclass
class Runner:
    """One contender at one size: ``call()`` runs ``steps_per_call`` env steps and blocks."""

    call: Callable[[], None]
    steps_per_call: int
    setup_seconds: float
    notes: dict = field(default_factory=dict)
    close: Callable[[], None] = lambda: None


def env_sharding(num_envs: int) -> NamedSharding:
    """Shards a leading env axis over all JAX devices when ``num_envs`` divides evenly,
    otherwise keeps it on the first device."""
    devs = jax.devices()
    if num_envs % len(devs) != 0:
        devs = devs[:1]
    return NamedSharding(Mesh(np.array(devs), ("env",)), PartitionSpec("env"))


def scan_length(num_envs: int) -> int:
    """Steps per compiled call: about :data:`STEPS_PER_CALL` env steps, at most
    :data:`MAX_SCAN_LENGTH` and at least 4."""
    return int(min(MAX_SCAN_LENGTH, max(4, STEPS_PER_CALL // num_envs)))


def jaxcart_random_rollout(num_envs: int, num_steps: int):
    """jaxcart's contender: ``num_steps`` steps of ``num_envs`` envs with uniform random actions.

    The batch steps with :func:`jaxcart.env.step_batch` (one key per step for the whole
    batch; reset states from jaxcart's counter hash). Uniform random actions are 32 to a word:
    one ``jax.random.bits`` word per 32 envs per step, unpacked bit by bit. The carry's leaves
    have a leading env axis, sharded over the devices by :func:`env_sharding`; each env keeps
    its own key so shards draw independent numbers.

    Returns:
        ``(rollout, state)``: ``rollout(state) -> state`` is jitted (state donated) and runs
        ``num_steps x num_envs`` env steps; ``state`` is the initial carry, on the devices.
        The carry counts finished episodes per env, so the result depends on every step.
    """
    params = cartpole.EnvParams()
    sharding = env_sharding(num_envs)
    local_envs = num_envs // sharding.mesh.size  # each device steps its own share

    def one_step(carry, t):
        env_state, keys, episodes = carry
        # Per step: one action word per 32 envs and one reset key, folded from the env's key.
        key = jax.random.fold_in(keys[0], t)
        action_key, reset_key = jax.random.split(key)
        words = jax.random.bits(action_key, ((local_envs + 31) // 32,), jnp.uint32)
        shifts = jnp.arange(32, dtype=jnp.uint32)
        actions = ((words[:, None] >> shifts) & 1).reshape(-1)[:local_envs].astype(jnp.int32)
        _, env_state, _, terminated, truncated, _ = cartpole.step_batch(
            reset_key, env_state, actions, params
        )
        episodes = episodes + (terminated | truncated).astype(jnp.int32)
        return (env_state, keys, episodes), None

    def rollout(carry):
        carry, _ = jax.lax.scan(one_step, carry, jnp.arange(num_steps, dtype=jnp.uint32))
        return carry

    keys = jax.random.split(jax.random.PRNGKey(0), num_envs + 1)
    _, env_state = jax.vmap(cartpole.reset, in_axes=(0, None))(keys[1:], params)
    step_keys = jax.random.split(keys[0], num_envs)
    state = (env_state, step_keys, jnp.zeros((num_envs,), jnp.int32))
    state = jax.device_put(state, sharding)
    # shard_map: every device runs the whole scan on its own envs, no cross-device traffic.
    spec = sharding.spec
    local = jax.shard_map(rollout, mesh=sharding.mesh, in_specs=(spec,), out_specs=spec)
    fn = jax.jit(local, out_shardings=sharding, donate_argnums=0)
    return fn, state


def gymnax_random_rollout(num_envs: int, num_steps: int):
    """gymnax 1.x ``CartPole-v1`` driven exactly like :func:`jaxcart_random_rollout`."""
    try:
        import gymnax
    except ImportError as e:
        raise Unavailable(f"gymnax is not installed ({e})") from None
    env, params = gymnax.make("CartPole-v1")
    sharding = env_sharding(num_envs)

    def one_step(carry, _):
        env_state, keys, episodes = carry
        split = jax.vmap(lambda k: jax.random.split(k, 3))(keys)
        keys, action_keys, step_keys = split[:, 0], split[:, 1], split[:, 2]
        actions = jax.vmap(jax.random.bernoulli)(action_keys).astype(jnp.int32)
        out = jax.vmap(env.step, in_axes=(0, 0, 0, None))(step_keys, env_state, actions, params)
        if len(out) == 6:  # gymnax >= 1.0: obs, state, reward, terminated, truncated, info
            _, env_state, _, terminated, truncated, _ = out
            done = terminated | truncated
        else:  # gymnax 0.0.x: obs, state, reward, done, info
            _, env_state, _, done, _ = out
        episodes = episodes + done.astype(jnp.int32)
        return (env_state, keys, episodes), None

    def rollout(carry):
        carry, _ = jax.lax.scan(one_step, carry, None, length=num_steps)
        return carry

    keys = jax.random.split(jax.random.PRNGKey(0), num_envs + 1)
    _, env_state = jax.vmap(env.reset, in_axes=(0, None))(keys[1:], params)
    step_keys = jax.random.split(keys[0], num_envs)
    state = (env_state, step_keys, jnp.zeros((num_envs,), jnp.int32))
    state = jax.device_put(state, sharding)
    fn = jax.jit(rollout, out_shardings=sharding, donate_argnums=0)
    return fn, state


def jax_runner(make_rollout, num_envs: int) -> Runner:
    """Compiles (timed) a rollout of :func:`scan_length` steps; each call continues the state."""
    num_steps = scan_length(num_envs)
    start = time.perf_counter()
    fn, state = make_rollout(num_envs, num_steps)
    compiled = fn.lower(state).compile()
    compile_seconds = time.perf_counter() - start
    holder = [state]

    def call():
        holder[0] = compiled(holder[0])
        jax.block_until_ready(holder[0])

    devices_used = len(env_sharding(num_envs).mesh.devices.flat)
    return Runner(
        call=call,
        steps_per_call=num_envs * num_steps,
        setup_seconds=compile_seconds,
        notes={"scan_length": num_steps, "devices": devices_used},
    )


def gymnasium_runner(num_envs: int, mode: str) -> Runner:
    """Gymnasium's vector env (``mode``: ``vector_entry_point`` or ``sync``), one step a call."""
    try:
        import gymnasium as gym
    except ImportError as e:
        raise Unavailable(f"gymnasium is not installed ({e})") from None
    start = time.perf_counter()
    envs = gym.make_vec("CartPole-v1", num_envs=num_envs, vectorization_mode=mode)
    envs.reset(seed=0)
    setup = time.perf_counter() - start
    rng = np.random.default_rng(0)

    def call():
        envs.step(rng.integers(0, 2, size=num_envs))

    return Runner(
        call=call,
        steps_per_call=num_envs,
        setup_seconds=setup,
        notes={"env": type(envs).__name__, "autoreset": str(envs.metadata.get("autoreset_mode"))},
        close=envs.close,
    )


def envpool_runner(num_envs: int) -> Runner:
    """EnvPool's CartPole-v1 (synchronous: each call steps all envs), one step a call."""
    try:
        import envpool
    except ImportError as e:
        raise Unavailable(f"envpool is not installed ({e})") from None
    start = time.perf_counter()
    envs = envpool.make("CartPole-v1", env_type="gymnasium", num_envs=num_envs, seed=0)
    envs.reset()
    setup = time.perf_counter() - start
    rng = np.random.default_rng(0)

    def call():
        envs.step(rng.integers(0, 2, size=num_envs, dtype=np.int32))

    spec = envs.spec.config
    return Runner(
        call=call,
        steps_per_call=num_envs,
        setup_seconds=setup,
        notes={"num_threads": getattr(spec, "num_threads", None)},
        close=envs.close,
    )


def make_runner(name: str, num_envs: int) -> Runner:
    if name == "jaxcart":
        return jax_runner(jaxcart_random_rollout, num_envs)
    if name == "gymnax":
        return jax_runner(gymnax_random_rollout, num_envs)
    if name == "gymnasium-vector":
        return gymnasium_runner(num_envs, "vector_entry_point")
    if name == "gymnasium-sync":
        return gymnasium_runner(num_envs, "sync")
    if name == "envpool":
        return envpool_runner(num_envs)
    raise ValueError(name)


def timed(runner: Runner, calls: int) -> float:
    start = time.perf_counter()
    for _ in range(calls):
        runner.call()
    return time.perf_counter() - start


def measure(runner: Runner, repeats: int, seconds: float) -> dict:
    """Warm-up call, then calibrates calls per measurement to take about ``seconds``;
    returns per-repeat seconds and steps/s and their median."""
    runner.call()
    calls, elapsed = 1, timed(runner, 1)
    while elapsed < seconds / 4 and calls < 2**24:
        calls *= 2
        elapsed = timed(runner, calls)
    calls = max(1, round(calls * seconds / max(elapsed, 1e-9)))
    times = [timed(runner, calls) for _ in range(repeats)]
    steps = calls * runner.steps_per_call
    rates = [steps / t for t in times]
    return {
        "steps_per_measurement": steps,
        "seconds": times,
        "steps_per_second": rates,
        "median_steps_per_second": statistics.median(rates),
    }


def run_one(name: str, num_envs: int, args) -> dict:
    row = {"contender": name, "num_envs": num_envs}
    if name == "gymnasium-sync" and num_envs > args.sync_max_envs:
        row.update(status="skipped", reason=f"N > --sync-max-envs {args.sync_max_envs}")
        return row
    try:
        runner = make_runner(name, num_envs)
    except Unavailable as e:
        row.update(status="unavailable", reason=str(e))
        return row
    except Exception as e:  # a peer that fails to build is reported, not fatal
        traceback.print_exc()
        row.update(status="unavailable", reason=f"{type(e).__name__}: {e}")
        return row
    try:
        row.update(status="ok", setup_seconds=runner.setup_seconds, **runner.notes)
        row.update(measure(runner, args.repeats, args.seconds))
    finally:
        runner.close()
    return row


def result(rows: list[dict], name: str, n: int) -> dict | None:
    for r in rows:
        if r["contender"] == name and r["num_envs"] == n:
            return r
    return None


def rate(rows: list[dict], name: str, n: int) -> float | None:
    r = result(rows, name, n)
    return r["median_steps_per_second"] if r and r["status"] == "ok" else None


def cell(rows: list[dict], name: str, n: int) -> str:
    r = result(rows, name, n)
    if r is None:
        return "-"
    if r["status"] == "ok":
        return benchlib.format_rate(r["median_steps_per_second"])
    return r["status"]


def markdown(report: dict) -> str:
    rows, sizes, names = report["results"], report["settings"]["sizes"], report["contenders"]
    headers = ["contender"] + [f"N={n:,}" for n in sizes]
    throughput = [[LABELS[c]] + [cell(rows, c, n) for n in sizes] for c in names]
    ratio_rows = []
    for c in names:
        if c == "jaxcart":
            continue
        line = [f"jaxcart / {c}"]
        for n in sizes:
            a, b = rate(rows, "jaxcart", n), rate(rows, c, n)
            line.append(benchlib.format_ratio(a / b if a and b else None))
        ratio_rows.append(line)
    setup_rows = []
    for c in names:
        line = [LABELS[c]]
        for n in sizes:
            r = result(rows, c, n)
            ok = r is not None and r["status"] == "ok"
            line.append(f"{r['setup_seconds']:.2f}" if ok else "-")
        setup_rows.append(line)
    notes = []
    for r in rows:
        if r["status"] != "ok" and (r["status"] == "unavailable" or r["num_envs"] == sizes[-1]):
            notes.append(f"- {r['contender']} N={r['num_envs']:,}: {r['status']}: {r['reason']}")
    s = report["settings"]
    out = [
        "# CartPole-v1 environment throughput",
        "",
        "Env steps per second (all N envs together), uniformly random actions generated inside "
        "the timed loop, autoreset on. Median of "
        f"{s['repeats']} measurements of about {s['seconds']} s each; compile/setup excluded.",
        "",
        benchlib.markdown_table(headers, throughput),
        "",
        "Speed-up of jaxcart over each peer (higher = jaxcart faster):",
        "",
        benchlib.markdown_table(["ratio"] + headers[1:], ratio_rows),
        "",
        "Compile time (JAX contenders) or construction + reset time (others), seconds, "
        "excluded from the throughput above:",
        "",
        benchlib.markdown_table(["contender"] + headers[1:], setup_rows),
        "",
    ]
    if notes:
        out += ["Not measured:", "", *sorted(set(notes)), ""]
    out += [
        "How each contender runs:",
        "",
        "- gymnax: `jit(scan(vmap(step)))`, per-env PRNG keys split every step into an action "
        "key (`jax.random.bernoulli`) and a reset key (gymnax's own API takes a key per env).",
        "- jaxcart: `jit(shard_map(scan(step_batch)))`: one key per step for the whole batch, "
        "actions from `jax.random.bits` (one 32-bit word per 32 envs), reset states from "
        "jaxcart's counter hash (`jaxcart.env.hash_uniform`).",
        f"- Both: {s['steps_per_call']:,} env steps per compiled call (scan length at most "
        f"{s['max_scan_length']}); env axis split over the "
        f"{len(report['machine']['jax_devices'])} JAX device(s) when N divides evenly.",
        "- Gymnasium and EnvPool: one `step(rng.integers(0, 2, N))` per call; "
        f"SyncVectorEnv skipped for N > {s['sync_max_envs']:,}. They reset a finished "
        "episode on the env's next step (a step that only resets, counted like the others; "
        "about 1 in 23 with random actions), jaxcart and gymnax on the same step.",
        "",
        f"Command: `{report['command']}`",
        "",
        "Machine:",
        "",
        *benchlib.machine_markdown(report["machine"]),
        f"- load average at end: {report['load_average_end']}",
        "",
    ]
    return "\n".join(out)


def plot(report: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = report["results"]
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for c in report["contenders"]:
        pts = [
            (r["num_envs"], r["median_steps_per_second"])
            for r in rows
            if r["contender"] == c and r["status"] == "ok"
        ]
        if pts:
            xs, ys = zip(*pts)
            ax.plot(xs, ys, marker="o", label=LABELS[c], lw=2.5 if c == "jaxcart" else 1.5)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("parallel environments N")
    ax.set_ylabel("env steps / s (median)")
    cpu = report["machine"]["cpu_model"]
    ax.set_title(
        f"CartPole-v1 random-action throughput\n{cpu}, {report['machine']['cpus_available']} cores",
        fontsize=10,
    )
    ax.grid(True, which="both", alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def parse_sizes(text: str) -> list[int]:
    try:
        sizes = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated integers, got {text!r}"
        ) from None
    if not sizes or any(n <= 0 for n in sizes):
        raise argparse.ArgumentTypeError(f"sizes must be positive, got {text!r}")
    return sizes


def parse_names(text: str) -> list[str]:
    names = [v.strip() for v in text.split(",") if v.strip()]
    unknown = [n for n in names if n not in CONTENDERS]
    if unknown:
        raise argparse.ArgumentTypeError(
            f"unknown contender(s) {', '.join(unknown)}; choose from {', '.join(CONTENDERS)}"
        )
    return names


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--sizes",
        type=parse_sizes,
        default=None,
        help="numbers of envs N (default 1,16,256,4096,65536)",
    )
    parser.add_argument(
        "--repeats",
        type=int,
        default=None,
        help="measurements per point, median reported (default 5)",
    )
    parser.add_argument(
        "--seconds", type=float, default=None, help="target seconds per measurement (default 1.0)"
    )
    parser.add_argument(
        "--only", type=parse_names, default=list(CONTENDERS), help="comma-separated contenders"
    )
    parser.add_argument(
        "--sync-max-envs", type=int, default=4096, help="largest N for SyncVectorEnv"
    )
    parser.add_argument(
        "--quick", action="store_true", help="smoke test: N=1,16,256, 2 repeats of 0.1 s"
    )
    parser.add_argument(
        "--from-json",
        type=Path,
        default=None,
        help="only re-render the Markdown and plot of an earlier run's JSON (next to it)",
    )
    parser.add_argument(
        "--out", type=Path, default=None, help="output folder (default benchmarks/results[/quick])"
    )
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.from_json:
        report = json.loads(args.from_json.read_text())
        write_outputs(report, args.from_json.parent)
        return 0
    quick = args.quick
    args.sizes = args.sizes or list(QUICK_SIZES if quick else DEFAULT_SIZES)
    args.repeats = args.repeats or (2 if quick else 5)
    args.seconds = args.seconds or (0.1 if quick else 1.0)
    out = args.out or (benchlib.RESULTS_DIR / "quick" if quick else benchlib.RESULTS_DIR)
    names = [c for c in CONTENDERS if c in args.only]

    jax_devices = [str(d) for d in jax.devices()]
    report = {
        "benchmark": "env_throughput",
        "command": benchlib.command_line(),
        "machine": benchlib.machine_info(jax_devices),
        "settings": {
            "sizes": args.sizes,
            "repeats": args.repeats,
            "seconds": args.seconds,
            "sync_max_envs": args.sync_max_envs,
            "steps_per_call": STEPS_PER_CALL,
            "max_scan_length": MAX_SCAN_LENGTH,
            "quick": quick,
        },
        "contenders": names,
        "results": [],
    }
    print(f"JAX devices: {', '.join(jax_devices)}")
    for n in args.sizes:
        for name in names:
            row = run_one(name, n, args)
            report["results"].append(row)
            if row["status"] == "ok":
                print(
                    f"N={n:>6,}  {name:<17} {row['median_steps_per_second']:>16,.0f} steps/s "
                    f"(setup {row['setup_seconds']:.2f} s)",
                    flush=True,
                )
            else:
                print(f"N={n:>6,}  {name:<17} {row['status']}: {row['reason']}", flush=True)
    report["load_average_end"] = benchlib.load_average()

    out.mkdir(parents=True, exist_ok=True)
    benchlib.write_json(out / "env_throughput.json", report)
    write_outputs(report, out)
    return 0


def write_outputs(report: dict, out: Path) -> None:
    """Writes the Markdown and the plot of ``report`` to ``out`` and prints the Markdown."""
    text = markdown(report)
    (out / "env_throughput.md").write_text(text)
    plot(report, out / "env_throughput.png")
    print(text)
    print(f"wrote {out / 'env_throughput.json'}, .md and .png")


if __name__ == "__main__":
    raise SystemExit(main())

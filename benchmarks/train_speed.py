"""PPO training speed on CartPole-v1: jaxcart against Stable-Baselines3 and rejax.

Contenders, each in a fresh subprocess (clean compile caches and memory):

- ``sb3``: Stable-Baselines3 ``PPO("MlpPolicy", "CartPole-v1", seed=0).learn(80_000)``,
  every hyperparameter at its default (PyTorch, CPU, torch's default thread count);
  ``sb3-1thread``: the same after ``torch.set_num_threads(1)`` (often faster for a small MLP;
  ratios are taken against the faster of the two).
- ``jaxcart-sb3-xS``: jaxcart's ``sb3`` preset (the same hyperparameters), S seeds trained
  together in one compiled program (``jaxcart.trainer.train``).
- ``jaxcart-fast-xS``: jaxcart's ``fast`` preset.
- ``rejax-sb3-xS``: rejax's PPO at SB3's hyperparameters (1 env x 2048 steps, 40 iterations,
  32 minibatches of 64, 10 epochs, lr 3e-4, gamma 0.99, lambda 0.95, clip 0.2, entropy 0,
  value coef 0.5, grad norm 0.5, 64-64 tanh), S seeds as a ``vmap`` over ``train`` sharded
  over the CPU devices like jaxcart's. rejax 0.1.3 needs gymnax 0.0.x, so it runs in its own
  virtualenv (``--rejax-python``, default ``benchmarks/.venv-rejax/bin/python``).

Per contender: setup (construction, initialisation and, for JAX, compilation) and training
wall time, their sum ("including compile"), env steps/s, the whole process's wall time
(imports and evaluation included), peak memory (max RSS of the subprocess, from ``wait4``),
CPU time / wall time during training and over the process, and the solve rate: every seed's
greedy policy plays 20 episodes of Gymnasium's own ``CartPole-v1`` (solved = all 20 reach
500). JAX's persistent compilation cache is off, so compile times are cold; ``--warm-cache``
adds a second run of each JAX contender reading a cache written by the first.

    python benchmarks/train_speed.py                      # full run (minutes)
    python benchmarks/train_speed.py --quick              # smoke test: few steps, 1-2 seeds
    python benchmarks/train_speed.py --only jaxcart-sb3,rejax --seeds 1,8

Writes ``train_speed.json``, ``.md`` and ``.png`` (and ``logs/``) to ``--out`` (default
``benchmarks/results``, or ``benchmarks/results/quick`` with ``--quick``). Set up both
virtualenvs with ``bash benchmarks/setup_venvs.sh`` and run with
``benchmarks/.venv-bench/bin/python``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import benchlib

SB3_TIMESTEPS = 80_000
QUICK_TIMESTEPS = {"sb3": 4096, "fast": 1024}
FULL_SEEDS = (1, 8, 64)
QUICK_SEEDS = (1, 2)
DEFAULT_REJAX_PYTHON = benchlib.REPO_ROOT / "benchmarks" / ".venv-rejax" / "bin" / "python"
EVAL_EPISODES = 20
UNAVAILABLE_EXIT = 3

# Where rejax's PPO differs from SB3's at these settings (it has no options for them).
REJAX_DIFFERENCES = (
    "Adam eps 1e-8 (SB3 1e-5), separate Adam optimisers and gradient clipping for actor and "
    "critic, clipped value loss, default (lecun-normal) rather than orthogonal init, and "
    "time-limit truncation treated as termination"
)


# Contenders


def contender_names(seeds: list[int], fast_seeds: list[int]) -> list[str]:
    """Every contender, in table order."""
    names = ["sb3", "sb3-1thread"]
    names += [f"jaxcart-sb3-x{s}" for s in seeds]
    names += [f"jaxcart-fast-x{s}" for s in fast_seeds]
    names += [f"rejax-sb3-x{s}" for s in seeds]
    return names


def parse_name(name: str) -> tuple[str, str, int]:
    """``"jaxcart-sb3-x8"`` -> ``("jaxcart", "sb3", 8)``; ``"sb3"`` -> ``("sb3", "default", 1)``,
    ``"sb3-1thread"`` -> ``("sb3", "1thread", 1)``."""
    if name.startswith("sb3"):
        return "sb3", name.removeprefix("sb3").removeprefix("-") or "default", 1
    kind, preset, seeds = name.split("-")
    return kind, preset, int(seeds.removeprefix("x"))


def label(name: str) -> str:
    kind, preset, seeds = parse_name(name)
    if kind == "sb3":
        threads = "1 torch thread" if preset == "1thread" else "default torch threads"
        return f"SB3 PPO ({threads})"
    return f"{kind} {preset} x{seeds}"


# Child side: one contender, in its own process


class ChildUnavailable(Exception):
    """The contender's packages are missing in this interpreter."""


def configure_jax_cache(cache_dir: str | None) -> None:
    """Persistent compilation cache off (cold compile), or on in ``cache_dir``."""
    import jax

    if cache_dir:
        jax.config.update("jax_enable_compilation_cache", True)
        jax.config.update("jax_compilation_cache_dir", cache_dir)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    else:
        jax.config.update("jax_enable_compilation_cache", False)


def evaluate_policy(policy, num_policies: int) -> dict:
    """Gymnasium evaluation with jaxcart's evaluator: per-seed mean/min and solved flags."""
    from jaxcart.evaluate import evaluate_gymnasium, summarize

    start = time.perf_counter()
    returns = evaluate_gymnasium(policy, num_policies, EVAL_EPISODES)
    summary = summarize(returns)
    return {
        "eval_seconds": time.perf_counter() - start,
        "eval_mean": [float(v) for v in summary["mean"]],
        "eval_min": [float(v) for v in summary["min"]],
        "solved": int(summary["solved"].sum()),
    }


def child_sb3(quick: bool, one_thread: bool) -> dict:
    try:
        import torch
        from stable_baselines3 import PPO
    except ImportError as e:
        raise ChildUnavailable(f"stable-baselines3/torch not installed ({e})") from None
    import numpy as np

    if one_thread:  # the usual advice for small MLPs on CPU; SB3 itself leaves torch's default
        torch.set_num_threads(1)

    timesteps = QUICK_TIMESTEPS["sb3"] if quick else SB3_TIMESTEPS
    t0 = time.perf_counter()
    model = PPO("MlpPolicy", "CartPole-v1", seed=0, device="cpu")
    t1, c1 = time.perf_counter(), time.process_time()
    model.learn(timesteps)
    t2, c2 = time.perf_counter(), time.process_time()

    def policy(obs: np.ndarray) -> np.ndarray:
        actions, _ = model.predict(obs.reshape(-1, 4), deterministic=True)
        return np.asarray(actions).reshape(obs.shape[:-1])

    return {
        "num_seeds": 1,
        "env_steps": int(model.num_timesteps),
        "setup_seconds": t1 - t0,
        "compile_seconds": 0.0,
        "train_seconds": t2 - t1,
        "train_cpu_seconds": c2 - c1,
        "torch_threads": torch.get_num_threads(),
        "hyperparameters": {
            "n_steps": model.n_steps,
            "batch_size": model.batch_size,
            "n_epochs": model.n_epochs,
            "learning_rate": model.learning_rate,
        },
        **evaluate_policy(policy, 1),
    }


def child_jaxcart(preset_name: str, num_seeds: int, quick: bool, cache_dir: str | None) -> dict:
    from jaxcart import devices

    devices.use_all_host_cores()
    import jax

    configure_jax_cache(cache_dir)
    from jaxcart.config import preset
    from jaxcart.evaluate import numpy_policy
    from jaxcart.trainer import train

    overrides = {"total_timesteps": QUICK_TIMESTEPS[preset_name]} if quick else {}
    config = preset(preset_name, **overrides)
    marks = {}

    def on_compiled(seconds: float) -> None:
        marks["compiled_cpu"] = time.process_time()

    t0 = time.perf_counter()
    result = train(config, num_seeds=num_seeds, seed=0, on_compiled=on_compiled)
    t1, c1 = time.perf_counter(), time.process_time()
    params = jax.device_get(result.params)
    return {
        "num_seeds": num_seeds,
        "env_steps": int(result.env_steps),
        "setup_seconds": (t1 - t0) - result.run_seconds,
        "compile_seconds": result.compile_seconds,
        "train_seconds": result.run_seconds,
        "train_cpu_seconds": c1 - marks["compiled_cpu"],
        "jax_devices": [str(d) for d in jax.devices()],
        "devices_used": result.num_devices,
        "config": config.to_dict(),
        **evaluate_policy(numpy_policy(params, config.activation, stacked=True), num_seeds),
    }


def rejax_config(quick: bool) -> dict:
    """rejax ``PPO.create`` arguments for SB3's PPO defaults on CartPole-v1."""
    iterations = -(-(QUICK_TIMESTEPS["sb3"] if quick else SB3_TIMESTEPS) // 2048)
    total = iterations * 2048
    return dict(
        env="CartPole-v1",
        num_envs=1,
        num_steps=2048,
        num_epochs=10,
        num_minibatches=32,  # 2048 / 64
        learning_rate=3e-4,
        max_grad_norm=0.5,
        gamma=0.99,
        gae_lambda=0.95,
        clip_eps=0.2,
        ent_coef=0.0,
        vf_coef=0.5,
        total_timesteps=total,
        # One evaluation "period" spanning the whole run, and the evaluation itself replaced
        # by a no-op below, so rejax's in-training evaluation costs nothing.
        eval_freq=total,
        skip_initial_evaluation=True,
        agent_kwargs={"activation": "tanh", "hidden_layer_sizes": (64, 64)},
    )


def child_rejax(num_seeds: int, quick: bool, cache_dir: str | None) -> dict:
    flag = "--xla_force_host_platform_device_count"
    if flag not in os.environ.get("XLA_FLAGS", ""):
        cores = len(os.sched_getaffinity(0))
        os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {flag}={cores}".strip()
    try:
        import jax
        import jax.numpy as jnp
        import numpy as np
        from jax.sharding import Mesh, NamedSharding, PartitionSpec
        from rejax import PPO
    except ImportError as e:
        raise ChildUnavailable(f"rejax not installed in {sys.executable} ({e})") from None
    configure_jax_cache(cache_dir)
    from jaxcart.evaluate import NumpyPolicy

    config = rejax_config(quick)
    t0 = time.perf_counter()
    algo = PPO.create(**config)
    algo = algo.replace(eval_callback=lambda algo, ts, rng: jnp.zeros(()))
    devs = jax.devices()
    count = max(d for d in range(1, len(devs) + 1) if num_seeds % d == 0)
    sharding = NamedSharding(Mesh(np.array(devs[:count]), ("seed",)), PartitionSpec("seed"))
    base = jax.random.PRNGKey(0)
    keys = jax.vmap(lambda i: jax.random.fold_in(base, i))(jnp.arange(num_seeds, dtype=jnp.uint32))
    keys = jax.device_put(keys, sharding)
    train = jax.jit(jax.vmap(algo.train))
    c0 = time.perf_counter()
    compiled = train.lower(keys).compile()
    t1, cpu1 = time.perf_counter(), time.process_time()
    ts, _ = compiled(keys)
    jax.block_until_ready(ts)
    t2, cpu2 = time.perf_counter(), time.process_time()

    p = jax.device_get(ts.actor_ts.params["params"])
    kernels = [p["features"]["Dense_0"]["kernel"], p["features"]["Dense_1"]["kernel"]]
    kernels.append(p["action_logits"]["kernel"])
    biases = [p["features"]["Dense_0"]["bias"], p["features"]["Dense_1"]["bias"]]
    biases.append(p["action_logits"]["bias"])
    policy = NumpyPolicy(kernels, biases, "tanh", stacked=True)
    return {
        "num_seeds": num_seeds,
        "env_steps": int(np.sum(jax.device_get(ts.global_step))),
        "setup_seconds": t1 - t0,
        "compile_seconds": t1 - c0,
        "train_seconds": t2 - t1,
        "train_cpu_seconds": cpu2 - cpu1,
        "jax_devices": [str(d) for d in devs],
        "devices_used": count,
        "config": {k: v for k, v in config.items() if k != "env"},
        "differences_from_sb3": REJAX_DIFFERENCES,
        **evaluate_policy(policy, num_seeds),
    }


def child_main(args: argparse.Namespace) -> int:
    """Runs one contender and writes its JSON to ``--child-out``."""
    kind, preset_name, num_seeds = parse_name(args.child)
    try:
        if kind == "sb3":
            data = child_sb3(args.quick, one_thread=preset_name == "1thread")
        elif kind == "jaxcart":
            data = child_jaxcart(preset_name, num_seeds, args.quick, args.cache_dir)
        elif kind == "rejax":
            data = child_rejax(num_seeds, args.quick, args.cache_dir)
        else:
            raise ValueError(f"unknown contender {args.child!r}")
        data["status"] = "ok"
        code = 0
    except ChildUnavailable as e:
        data, code = {"status": "unavailable", "reason": str(e)}, UNAVAILABLE_EXIT
    data["python"] = sys.executable
    data["packages"] = benchlib.package_versions()
    benchlib.write_json(Path(args.child_out), data)
    return code


# Parent side: subprocesses, tables, plot


def run_child(
    name: str,
    python: str,
    out_dir: Path,
    quick: bool,
    cache_dir: str | None,
    warm: bool,
    timeout: float,
) -> dict:
    """Runs ``name`` in a fresh ``python`` process; adds wall time, max RSS and CPU time from
    ``wait4`` to what the child reported. ``warm``: ``cache_dir`` already holds its programs."""
    import subprocess

    suffix = "-warm" if warm else ""
    log_path = out_dir / "logs" / f"{name}{suffix}.log"
    log_path.parent.mkdir(parents=True, exist_ok=True)
    result_path = out_dir / "logs" / f"{name}{suffix}.json"
    result_path.unlink(missing_ok=True)
    cmd = [python, str(Path(__file__).resolve()), "--child", name, "--child-out", str(result_path)]
    if quick:
        cmd.append("--quick")
    if cache_dir:
        cmd += ["--cache-dir", cache_dir]
    env = dict(os.environ)
    env.setdefault("PYTHONUNBUFFERED", "1")
    with open(log_path, "w") as log:
        start = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env, cwd=Path.cwd())
        timed_out = False
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if time.perf_counter() - start > timeout:
                proc.kill()
                timed_out = True
                pid, status, usage = os.wait4(proc.pid, 0)
                break
            time.sleep(0.05)
        wall = time.perf_counter() - start
        proc.returncode = os.waitstatus_to_exitcode(status)  # reaped here, not by Popen
    row = {"contender": name, "warm_cache": bool(suffix), "log": str(log_path)}
    if result_path.exists():
        row.update(json.loads(result_path.read_text()))
    elif timed_out:
        row.update(status="failed", reason=f"timed out after {timeout:.0f} s")
    else:
        tail = log_path.read_text().strip().splitlines()[-5:]
        row.update(status="failed", reason=f"exit {proc.returncode}: " + " | ".join(tail))
    cpu = usage.ru_utime + usage.ru_stime
    row.update(
        process_wall_seconds=wall,
        peak_rss_mib=usage.ru_maxrss / 1024,  # KiB on Linux
        process_cpu_seconds=cpu,
        process_cpu_ratio=cpu / wall if wall > 0 else None,
    )
    if row.get("status") == "ok":
        row["total_seconds"] = row["setup_seconds"] + row["train_seconds"]
        row["steps_per_second"] = row["env_steps"] / row["train_seconds"]
        row["steps_per_second_incl_setup"] = row["env_steps"] / row["total_seconds"]
        row["train_cpu_ratio"] = row["train_cpu_seconds"] / row["train_seconds"]
        row["solve_rate"] = row["solved"] / row["num_seeds"]
    return row


def find(rows: list[dict], name: str, warm: bool = False) -> dict | None:
    for r in rows:
        if r["contender"] == name and r["warm_cache"] == warm and r.get("status") == "ok":
            return r
    return None


def best_sb3(rows: list[dict]) -> dict | None:
    """The faster (total wall time) of the SB3 rows."""
    candidates = [r for r in (find(rows, "sb3"), find(rows, "sb3-1thread")) if r]
    return min(candidates, key=lambda r: r["total_seconds"]) if candidates else None


def row_label(r: dict) -> str:
    return label(r["contender"]) + (" (warm cache)" if r["warm_cache"] else "")


def fmt_s(v: float | None) -> str:
    return "-" if v is None else f"{v:,.2f}"


def ratio_cells(r: dict, ref: dict | None) -> list[str]:
    """Speed-up over ``ref`` in wall time per trained agent, including and excluding
    setup/compile, and in env steps/s."""
    if ref is None:
        return ["-", "-", "-"]
    per_agent = lambda row, key: row[key] / row["num_seeds"]
    return [
        benchlib.format_ratio(per_agent(ref, "total_seconds") / per_agent(r, "total_seconds")),
        benchlib.format_ratio(per_agent(ref, "train_seconds") / per_agent(r, "train_seconds")),
        benchlib.format_ratio(r["steps_per_second"] / ref["steps_per_second"]),
    ]


def markdown(report: dict) -> str:
    rows = report["results"]
    ok = [r for r in rows if r.get("status") == "ok"]
    headers = [
        "contender",
        "seeds",
        "env steps",
        "compile s",
        "setup s",
        "train s",
        "total s (incl. compile)",
        "process s",
        "steps/s (excl. compile)",
        "steps/s (incl.)",
        "peak RSS MiB",
        "CPU/wall train",
        "CPU/wall process",
        "eval mean return",
        "solved",
    ]
    table = []
    for r in ok:
        table.append(
            [
                row_label(r),
                r["num_seeds"],
                f"{r['env_steps']:,}",
                fmt_s(r["compile_seconds"]),
                fmt_s(r["setup_seconds"]),
                fmt_s(r["train_seconds"]),
                fmt_s(r["total_seconds"]),
                fmt_s(r["process_wall_seconds"]),
                benchlib.format_rate(r["steps_per_second"]),
                benchlib.format_rate(r["steps_per_second_incl_setup"]),
                f"{r['peak_rss_mib']:,.0f}",
                f"{r['train_cpu_ratio']:.2f}",
                f"{r['process_cpu_ratio']:.2f}",
                f"{sum(r['eval_mean']) / len(r['eval_mean']):.1f}",
                f"{r['solved']}/{r['num_seeds']}",
            ]
        )
    sb3 = best_sb3(rows)
    ratio_headers = [
        "contender",
        "vs SB3: wall/agent incl. compile",
        "vs SB3: excl. compile",
        "vs SB3: steps/s",
        "vs rejax (same seeds): wall incl. compile",
        "vs rejax: excl. compile",
        "vs rejax: steps/s",
    ]
    ratio_rows = []
    for r in ok:
        if r["contender"].startswith("sb3"):
            continue
        kind, _, seeds = parse_name(r["contender"])
        rejax = None if kind == "rejax" else find(rows, f"rejax-sb3-x{seeds}", r["warm_cache"])
        ratio_rows.append([row_label(r), *ratio_cells(r, sb3), *ratio_cells(r, rejax)])
    failed = [r for r in rows if r.get("status") != "ok"]
    s = report["settings"]
    out = [
        "# PPO training speed on CartPole-v1",
        "",
        "Each contender ran in a fresh subprocess. *setup* = construction + initialisation + "
        "compilation (JAX) before the first training step; *train* = the training loop; "
        "*total* = setup + train; *process* = the whole subprocess (imports and the Gymnasium "
        "evaluation included). Peak RSS and process CPU time come from `wait4` on the "
        "subprocess. *solved* = seeds whose greedy policy scored 500 in all "
        f"{EVAL_EPISODES} episodes of Gymnasium's `CartPole-v1`. Compile times are cold "
        "(JAX's persistent compilation cache off)"
        + (
            "; with `--warm-cache` the cold run writes a fresh cache and the *warm cache* run "
            "reads it."
            if s["warm_cache"]
            else "."
        ),
        "",
        benchlib.markdown_table(headers, table),
        "",
        "Speed-ups (higher = that row is faster). Wall time is compared per trained agent "
        "(SB3 trains one agent per process; S seeds count as S agents), steps/s as measured. "
        "SB3 = the faster of its two rows"
        + (f" ({row_label(sb3)})" if sb3 else "")
        + "; rejax = the rejax row with the same number of seeds:",
        "",
        benchlib.markdown_table(ratio_headers, ratio_rows),
        "",
    ]
    if failed:
        out += ["Not measured:", ""]
        out += [f"- {r['contender']}: {r['status']}: {r.get('reason', '')}" for r in failed]
        out += [""]
    out += [
        "Notes:",
        "",
        f'- SB3: `PPO("MlpPolicy", "CartPole-v1", seed=0, device="cpu")'
        f".learn({QUICK_TIMESTEPS['sb3'] if s['quick'] else SB3_TIMESTEPS:_})`, "
        "all hyperparameters at their defaults (n_steps 2048, so 80,000 becomes 40 rollouts = "
        "81,920 steps); once with torch's default thread count (one per core) and once after "
        "`torch.set_num_threads(1)`, which is often faster for a 64-64 MLP and much faster "
        "when the cores are busy.",
        "- jaxcart's *setup* is initialising the seeds (NumPy, on the host) and compiling the "
        "training step (*compile*, which includes tracing and lowering).",
        "- jaxcart: `jaxcart.trainer.train(preset(...), num_seeds=S, seed=0)`; seeds sharded "
        "over the CPU devices (one per core).",
        f"- rejax: SB3's hyperparameters except where rejax has no option: {REJAX_DIFFERENCES}; "
        "its periodic evaluation replaced by a no-op; S seeds as `jit(vmap(train))` sharded "
        "over the CPU devices.",
    ]
    if s["quick"]:
        out.append(
            "- **--quick**: total timesteps cut to "
            f"{QUICK_TIMESTEPS['sb3']:,} (sb3 settings) and {QUICK_TIMESTEPS['fast']:,} (fast) "
            "per seed, so nothing is expected to be solved."
        )
    out += [
        "",
        f"Command: `{report['command']}`",
        "",
        "Machine:",
        "",
        *benchlib.machine_markdown(report["machine"]),
        f"- rejax interpreter: `{s['rejax_python']}`"
        + (f" (rejax {report['rejax_version']})" if report.get("rejax_version") else ""),
        f"- load average at end: {report['load_average_end']}",
        "",
    ]
    return "\n".join(out)


def plot(report: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in report["results"] if r.get("status") == "ok" and not r["warm_cache"]]
    fig, ax = plt.subplots(figsize=(9.5, 4.5))
    groups = [("jaxcart", "sb3", "C0"), ("jaxcart", "fast", "C2"), ("rejax", "sb3", "C1")]
    for kind, preset_name, color in groups:
        pts = sorted(
            (r["num_seeds"], r["total_seconds"], r["train_seconds"])
            for r in rows
            if parse_name(r["contender"])[:2] == (kind, preset_name)
        )
        if not pts:
            continue
        xs, total, train = zip(*pts)
        name = f"{kind} {preset_name}"
        ax.plot(xs, total, "o-", color=color, label=f"{name}, incl. compile")
        ax.plot(xs, train, "o--", color=color, alpha=0.6, label=f"{name}, excl. compile")
    sb3 = best_sb3(report["results"])
    seeds = sorted({r["num_seeds"] for r in rows} | {1})
    if sb3:
        ax.plot(
            seeds,
            [sb3["total_seconds"] * s for s in seeds],
            ":",
            color="C3",
            label="SB3, S sequential runs (best 1-seed time x S)",
        )
    for r, marker in ((find(rows, "sb3"), "s"), (find(rows, "sb3-1thread"), "D")):
        if r:
            ax.plot([1], [r["total_seconds"]], marker, color="C3", label=row_label(r))
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("seeds trained (independent agents)")
    ax.set_ylabel("wall time, s")
    m = report["machine"]
    title = "PPO on CartPole-v1: wall time vs seeds"
    if report["settings"]["quick"]:
        title += " (--quick: shortened runs)"
    ax.set_title(f"{title}\n{m['cpu_model']}, {m['cpus_available']} cores", fontsize=10)
    ax.set_xticks(seeds, [str(s) for s in seeds])
    ax.minorticks_off()
    ax.grid(True, which="major", alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5))
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def parse_ints(text: str) -> list[int]:
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated integers, got {text!r}"
        ) from None
    if not values or any(v <= 0 for v in values):
        raise argparse.ArgumentTypeError(f"expected positive integers, got {text!r}")
    return values


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--quick", action="store_true", help="smoke test: short runs, seeds 1,2")
    parser.add_argument(
        "--only",
        default=None,
        help="comma-separated contender names or prefixes (sb3, jaxcart, jaxcart-fast, "
        "rejax-sb3-x8, ...)",
    )
    parser.add_argument(
        "--seeds", type=parse_ints, default=None, help="seed counts (default 1,8,64)"
    )
    parser.add_argument(
        "--fast-seeds",
        type=parse_ints,
        default=None,
        help="seed counts for the fast preset (default 1,8)",
    )
    parser.add_argument(
        "--warm-cache",
        action="store_true",
        help="also time JAX contenders with a warm persistent compilation cache",
    )
    parser.add_argument(
        "--rejax-python", default=str(DEFAULT_REJAX_PYTHON), help="interpreter with rejax installed"
    )
    parser.add_argument("--timeout", type=float, default=1800, help="seconds per contender")
    parser.add_argument(
        "--out", type=Path, default=None, help="output folder (default benchmarks/results[/quick])"
    )
    parser.add_argument(
        "--from-json",
        type=Path,
        default=None,
        help="only re-render the Markdown and plot of an earlier run's JSON (next to it)",
    )
    parser.add_argument("--child", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--child-out", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--cache-dir", default=None, help=argparse.SUPPRESS)
    return parser


def selected(names: list[str], only: str | None) -> list[str]:
    if not only:
        return names
    wanted = [w.strip() for w in only.split(",") if w.strip()]
    picked = [n for n in names if any(n == w or n.startswith(w + "-") for w in wanted)]
    if not picked:
        raise SystemExit(f"--only {only!r} matches none of: {', '.join(names)}")
    return picked


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.child:
        return child_main(args)
    if args.from_json:
        write_outputs(json.loads(args.from_json.read_text()), args.from_json.parent)
        return 0
    quick = args.quick
    seeds = args.seeds or list(QUICK_SEEDS if quick else FULL_SEEDS)
    fast_seeds = args.fast_seeds or list(QUICK_SEEDS if quick else FULL_SEEDS[:2])
    names = selected(contender_names(seeds, fast_seeds), args.only)
    out = args.out or (benchlib.RESULTS_DIR / "quick" if quick else benchlib.RESULTS_DIR)
    out.mkdir(parents=True, exist_ok=True)

    rejax_python = args.rejax_python
    report = {
        "benchmark": "train_speed",
        "command": benchlib.command_line(),
        "machine": benchlib.machine_info(),
        "settings": {
            "quick": quick,
            "seeds": seeds,
            "fast_seeds": fast_seeds,
            "warm_cache": args.warm_cache,
            "rejax_python": rejax_python,
            "eval_episodes": EVAL_EPISODES,
        },
        "contenders": names,
        "results": [],
    }
    for name in names:
        kind = parse_name(name)[0]
        python = sys.executable
        if kind == "rejax":
            python = rejax_python
            if not Path(python).exists():
                report["results"].append(
                    {
                        "contender": name,
                        "warm_cache": False,
                        "status": "unavailable",
                        "reason": f"{python} not found; run `bash benchmarks/setup_venvs.sh`",
                    }
                )
                print(f"{name:<18} unavailable: {python} not found", flush=True)
                continue
        runs = [(None, False)]
        tmp = None
        if args.warm_cache and kind != "sb3":
            # The first run writes the cache (cold compile), the second reads it.
            tmp = tempfile.mkdtemp(prefix=f"jaxcache-{name}-")
            runs = [(tmp, False), (tmp, True)]
        for cache_dir, warm in runs:
            row = run_child(name, python, out, quick, cache_dir, warm, args.timeout)
            report["results"].append(row)
            if row.get("status") == "ok":
                if kind == "rejax":
                    report["rejax_version"] = row["packages"].get("rejax")
                print(
                    f"{row_label(row):<34} compile {row['compile_seconds']:6.2f} s  "
                    f"setup {row['setup_seconds']:6.2f} s  "
                    f"train {row['train_seconds']:7.2f} s  "
                    f"{row['steps_per_second']:>10,.0f} steps/s  "
                    f"RSS {row['peak_rss_mib']:5.0f} MiB  "
                    f"solved {row['solved']}/{row['num_seeds']}",
                    flush=True,
                )
            else:
                print(f"{name:<32} {row['status']}: {row.get('reason')}", flush=True)
        if tmp:
            shutil.rmtree(tmp, ignore_errors=True)
    report["load_average_end"] = benchlib.load_average()

    benchlib.write_json(out / "train_speed.json", report)
    print()
    write_outputs(report, out)
    return 0


def write_outputs(report: dict, out: Path) -> None:
    """Writes the Markdown and the plot of ``report`` to ``out`` and prints the Markdown."""
    text = markdown(report)
    (out / "train_speed.md").write_text(text)
    plot(report, out / "train_speed.png")
    print(text)
    print(f"wrote {out / 'train_speed.json'}, .md and .png")


if __name__ == "__main__":
    raise SystemExit(main())

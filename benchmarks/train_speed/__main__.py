"""PPO training speed on CartPole-v1 (and Acrobot-v1): jaxcart against Stable-Baselines3, sbx
and rejax.

Contenders, each in a fresh subprocess (clean compile caches and memory):

- ``sb3``: Stable-Baselines3 ``PPO("MlpPolicy", "CartPole-v1", seed=0).learn(80_000)``,
  every hyperparameter at its default (PyTorch, CPU, torch's default thread count);
  ``sb3-1thread``: the same after ``torch.set_num_threads(1)`` (often faster for a small MLP;
  ratios are taken against the faster of the two).
- ``sb3-zoo-xS``: SB3 at rl-zoo3's tuned CartPole-v1 settings (8 envs, 100k steps, n_steps
  32, batch 256, 20 epochs, gamma 0.98, lambda 0.8, linear learning rate from 1e-3 and clip
  range from 0.2). ``sb3-default-xS``, ``sb3-zoo-xS`` with S > 1 seeds: S one-seed trainings
  as parallel processes, one per core (one torch thread each), inside the contender's process.
- ``sbx-default-xS``, ``sbx-zoo-xS``: sbx (SB3's JAX port) at its defaults (80k steps) and at
  the same rl-zoo3 settings; S > 1 as for SB3. sbx runs in its own virtualenv
  (``--sbx-python``, default ``benchmarks/.venv-sbx/bin/python``).
- ``jaxcart-sb3-xS``: jaxcart's ``sb3`` preset (SB3's hyperparameters), S seeds trained
  together in one compiled program (``jaxcart.engine.loop.train``); ``jaxcart-fast-xS``: its
  ``fast`` preset; ``jaxcart-purejaxrl-xS``: its ``purejaxrl`` preset, i.e. jaxcart running
  PureJaxRL's CartPole configuration (PureJaxRL itself is a script in a GitHub repository,
  not an installable package, so it is not run here).
- ``rejax-sb3-xS``: rejax's PPO at SB3's hyperparameters (1 env x 2048 steps, 40 iterations,
  32 minibatches of 64, 10 epochs, lr 3e-4, gamma 0.99, lambda 0.95, clip 0.2, entropy 0,
  value coef 0.5, grad norm 0.5, 64-64 tanh); ``rejax-cartpole-xS``: at rejax's own CartPole
  configuration (``configs/gymnax/cartpole.yaml``: 5 envs x 100 steps, 100k steps). S seeds as
  a ``vmap`` over ``train`` sharded over the CPU devices like jaxcart's. rejax 0.1.3 needs
  gymnax 0.0.x, so it runs in its own virtualenv (``--rejax-python``, default
  ``benchmarks/.venv-rejax/bin/python``).
- Acrobot-v1, only when ``--only`` or ``--seeds-for`` names them: ``jaxcart-acrobot-xS``,
  jaxcart's ``acrobot`` preset (``--env Acrobot-v1``, on gymnax 1.x's Acrobot), and
  ``rejax-acrobot-xS``, rejax's PPO at its own Acrobot configuration
  (``configs/gymnax/acrobot.yaml``: 5 envs x 100 steps, 100k steps, observations
  normalised), seeds as for ``rejax-cartpole``.

Per contender: setup (construction, initialisation and, for JAX, compilation) and training
wall time, their sum ("including compile"), env steps/s, the whole process's wall time
(imports and evaluation included), peak memory (max RSS of the subprocess, from ``wait4``),
CPU time / wall time during training and over the process, and the solve rate: every seed's
greedy policy plays 20 episodes of Gymnasium's own ``CartPole-v1`` (solved = all 20 reach
500), or of ``Acrobot-v1`` for the Acrobot contenders (solved = the mean reaches its
``reward_threshold``, -100). JAX's persistent compilation cache is off, so compile times are cold; ``--warm-cache``
adds a second run of each JAX contender reading a cache written by the first.

``--time-to-solve`` runs every tool at its own CartPole configurations with 1 and 64 seeds
(``--seeds``) for the report's time-to-solve table: the whole process's wall time, compile
and evaluation included, against SB3's one-seed time. SB3 and sbx above one seed are slow
(about 25 minutes for SB3's 64) and run only with ``--slow`` or ``--seeds-for``.

    python -m benchmarks.train_speed                      # training-speed table (minutes)
    python -m benchmarks.train_speed --quick              # smoke test: few steps, 1-2 seeds
    python -m benchmarks.train_speed --only jaxcart-sb3,rejax --seeds 1,8
    python -m benchmarks.train_speed --time-to-solve --seeds 1          # N = 1
    python -m benchmarks.train_speed --time-to-solve --seeds 64 --slow  # N = 64
    python -m benchmarks.train_speed --seeds-for sbx-zoo=1,8 --only sbx
    python -m benchmarks.train_speed --time-to-solve --only jaxcart-acrobot,rejax-acrobot --seeds 64

Writes ``train_speed.json``, ``.md`` and ``.png`` (``time_to_solve.*`` with
``--time-to-solve``; and ``logs/``) to ``--out`` (default ``benchmarks/results/scratch``, not
committed; ``--out benchmarks/results`` replaces the committed figures). Set up the
virtualenvs with ``bash benchmarks/setup_venvs.sh`` and run with
``benchmarks/.venv-bench/bin/python``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks import lib
from benchmarks.train_speed.common import (
    EVAL_EPISODES,
    GROUPS,
    OPT_IN_GROUPS,
    TIME_TO_SOLVE_STEM,
    ChildUnavailable,
    contender_names,
    default_groups,
    env_of,
    opt_in_groups_named,
    parse_name,
    time_to_solve_groups,
)
from benchmarks.train_speed.contenders import jaxcart as jaxcart_contender
from benchmarks.train_speed.contenders import rejax as rejax_contender
from benchmarks.train_speed.contenders import sb3 as sb3_contender
from benchmarks.train_speed.contenders import sbx as sbx_contender
from benchmarks.train_speed.report import markdown, plot, row_label

FULL_SEEDS = (1, 8, 64)
QUICK_SEEDS = (1, 2)
TIME_TO_SOLVE_SEEDS = (1, 64)
DEFAULT_REJAX_PYTHON = lib.REPO_ROOT / "benchmarks" / ".venv-rejax" / "bin" / "python"
DEFAULT_SBX_PYTHON = lib.REPO_ROOT / "benchmarks" / ".venv-sbx" / "bin" / "python"
UNAVAILABLE_EXIT = 3
STEM = "train_speed"

# Each kind's run(preset_name, num_seeds, quick, cache_dir) -> (data, greedy policy).
RUNNERS = {
    "sb3": sb3_contender.run,
    "jaxcart": jaxcart_contender.run,
    "rejax": rejax_contender.run,
    "sbx": sbx_contender.run,
}


# Child side: one contender, in its own process


def evaluate_policy(policy, num_policies: int, env_id: str) -> dict:
    """Gymnasium evaluation of every contender alike, with jaxcart's evaluator: greedy episodes
    in ``gymnasium.make(env_id)``, per-seed mean/min and solved flags (``env_id``'s
    definition: all 500 for CartPole-v1, the mean at least the ``reward_threshold`` else)."""
    from jaxcart.run.greedy import evaluate_gymnasium, summarize

    start = time.perf_counter()
    returns = evaluate_gymnasium(policy, num_policies, EVAL_EPISODES, env_id=env_id)
    summary = summarize(returns, env_id)
    return {
        "env_id": env_id,
        "eval_seconds": time.perf_counter() - start,
        "eval_mean": [float(v) for v in summary["mean"]],
        "eval_min": [float(v) for v in summary["min"]],
        "solved": int(summary["solved"].sum()),
    }


def child_main(args: argparse.Namespace) -> int:
    """Runs one contender, evaluates its policies and writes its JSON to ``--child-out``."""
    kind, preset_name, num_seeds = parse_name(args.child)
    try:
        if kind not in RUNNERS:
            raise ValueError(f"unknown contender {args.child!r}")
        budget = {"timesteps": args.timesteps} if args.timesteps else {}  # jaxcart, rejax
        data, policy = RUNNERS[kind](preset_name, num_seeds, args.quick, args.cache_dir, **budget)
        data.update(evaluate_policy(policy, data["num_seeds"], env_of(args.child)))
        data["status"] = "ok"
        code = 0
    except ChildUnavailable as e:
        data, code = {"status": "unavailable", "reason": str(e)}, UNAVAILABLE_EXIT
    data["python"] = sys.executable
    data["packages"] = lib.package_versions()
    lib.write_json(Path(args.child_out), data)
    return code


# Parent side: subprocesses


def wait_with_timeout(proc: subprocess.Popen, timeout: float) -> tuple[int, object, bool]:
    """Reaps ``proc`` with ``wait4``, killing it after ``timeout`` seconds.

    Returns:
        ``(wait status, resource usage, timed out)``.
    """
    start = time.perf_counter()
    while True:
        pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
        if pid:
            return status, usage, False
        if time.perf_counter() - start > timeout:
            proc.kill()
            pid, status, usage = os.wait4(proc.pid, 0)
            return status, usage, True
        time.sleep(0.05)


def add_rates(row: dict) -> None:
    """Totals, rates and ratios of a measured row."""
    row["total_seconds"] = row["setup_seconds"] + row["train_seconds"]
    row["steps_per_second"] = row["env_steps"] / row["train_seconds"]
    row["steps_per_second_incl_setup"] = row["env_steps"] / row["total_seconds"]
    row["train_cpu_ratio"] = row["train_cpu_seconds"] / row["train_seconds"]
    row["solve_rate"] = row["solved"] / row["num_seeds"]


def run_child(
    name: str,
    python: str,
    out_dir: Path,
    quick: bool,
    cache_dir: str | None,
    warm: bool,
    timeout: float,
    timesteps: int | None = None,
) -> dict:
    """Runs ``name`` in a fresh ``python`` process; adds wall time, max RSS and CPU time from
    ``wait4`` to what the child reported. ``warm``: ``cache_dir`` already holds its programs."""
    suffix = "-warm" if warm else ""
    log_path = out_dir / "logs" / f"{name}{suffix}.log"
    log_path.parent.mkdir(parents=True, exist_ok=True)
    result_path = out_dir / "logs" / f"{name}{suffix}.json"
    result_path.unlink(missing_ok=True)
    cmd = [*lib.module_command("benchmarks.train_speed", python), "--child", name]
    cmd += ["--child-out", str(result_path.resolve())]
    if quick:
        cmd.append("--quick")
    if timesteps:
        cmd += ["--timesteps", str(timesteps)]
    if cache_dir:
        cmd += ["--cache-dir", cache_dir]
    env = dict(os.environ)
    env.setdefault("PYTHONUNBUFFERED", "1")
    with open(log_path, "w") as log:
        start = time.perf_counter()
        proc = subprocess.Popen(
            cmd, stdout=log, stderr=subprocess.STDOUT, env=env, cwd=lib.REPO_ROOT
        )
        status, usage, timed_out = wait_with_timeout(proc, timeout)
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
        add_rates(row)
    return row


def print_row(row: dict) -> None:
    if row.get("status") == "ok":
        compile_s = row["compile_seconds"]
        print(
            f"{row_label(row):<34} compile "
            + ("   n/a" if compile_s is None else f"{compile_s:6.2f}")
            + " s  "
            f"setup {row['setup_seconds']:6.2f} s  "
            f"train {row['train_seconds']:7.2f} s  "
            f"{row['steps_per_second']:>10,.0f} steps/s  "
            f"RSS {row['peak_rss_mib']:5.0f} MiB  "
            f"process {row['process_wall_seconds']:7.2f} s  "
            f"solved {row['solved']}/{row['num_seeds']}",
            flush=True,
        )
    else:
        print(f"{row['contender']:<32} {row['status']}: {row.get('reason')}", flush=True)


def run_contender(name: str, report: dict, args: argparse.Namespace, out: Path) -> None:
    """Runs ``name`` (twice with ``--warm-cache``, for JAX) and appends its rows to ``report``."""
    kind = parse_name(name)[0]
    python = {"rejax": args.rejax_python, "sbx": args.sbx_python}.get(kind, sys.executable)
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
        return
    runs = [(None, False)]
    tmp = None
    if args.warm_cache and kind != "sb3":
        # The first run writes the cache (cold compile), the second reads it.
        tmp = tempfile.mkdtemp(prefix=f"jaxcache-{name}-")
        runs = [(tmp, False), (tmp, True)]
    for cache_dir, warm in runs:
        row = run_child(
            name, python, out, args.quick, cache_dir, warm, args.timeout, args.timesteps
        )
        report["results"].append(row)
        if row.get("status") == "ok" and kind in ("rejax", "sbx"):
            package = {"rejax": "rejax", "sbx": "sbx-rl"}[kind]
            report[f"{kind}_version"] = row["packages"].get(package)
        print_row(row)
    if tmp:
        shutil.rmtree(tmp, ignore_errors=True)


# Command line


def parse_seeds_for(text: str) -> tuple[list[str], list[int]]:
    """``--seeds-for`` ``GROUP=N[,N...]`` -> (the groups it names, the seed counts). GROUP is a
    group (``sbx-zoo``) or a tool (``sbx``: all its groups but ``sb3-1thread``)."""
    key, sep, counts = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(
            f"expected GROUP=N[,N...] (e.g. sbx-zoo=1,64), got {text!r}"
        )
    # A tool's name stands for its CartPole groups; an opt-in group is named in full.
    skip = ("sb3-1thread", *OPT_IN_GROUPS)
    groups = [g for g in GROUPS if g == key or (g.startswith(key + "-") and g not in skip)]
    if not groups:
        raise argparse.ArgumentTypeError(
            f"unknown contender group {key!r}; choose a tool or one of: {', '.join(GROUPS)}"
        )
    seeds = lib.parse_ints(counts)
    if groups == ["sb3-1thread"] and seeds != [1]:
        raise argparse.ArgumentTypeError("sb3-1thread trains one seed; use sb3-default=N")
    return groups, seeds


def build_parser() -> argparse.ArgumentParser:
    parser = lib.arg_parser(__doc__)
    parser.add_argument("--quick", action="store_true", help="smoke test: short runs, seeds 1,2")
    parser.add_argument(
        "--only",
        default=None,
        help="comma-separated contender names or prefixes (sb3, jaxcart, jaxcart-fast, "
        "rejax-sb3-x8, sbx, ...); the Acrobot-v1 groups jaxcart-acrobot and rejax-acrobot run "
        "only when named in full (at --seeds)",
    )
    parser.add_argument(
        "--time-to-solve",
        action="store_true",
        help="every tool at its own CartPole configurations, --seeds (default 1,64) seeds each, "
        "for the time-to-solve table (SB3 and sbx above one seed only with --slow)",
    )
    parser.add_argument(
        "--slow",
        action="store_true",
        help="with --time-to-solve: also SB3 and sbx above one seed (one process per seed, "
        "one per core; about 25 minutes for SB3's 64)",
    )
    parser.add_argument(
        "--seeds",
        type=lib.parse_ints,
        default=None,
        help="seed counts (default 1,8,64; 1,64 with --time-to-solve)",
    )
    parser.add_argument(
        "--fast-seeds",
        type=lib.parse_ints,
        default=None,
        help="seed counts for the fast preset (default 1,8; --seeds with --time-to-solve)",
    )
    parser.add_argument(
        "--seeds-for",
        type=parse_seeds_for,
        action="append",
        default=[],
        metavar="GROUP=N[,N...]",
        help="seed counts of one contender group or tool, replacing the defaults; repeatable "
        f"(groups: {', '.join(GROUPS)})",
    )
    parser.add_argument(
        "--warm-cache",
        action="store_true",
        help="also time JAX contenders with a warm persistent compilation cache",
    )
    parser.add_argument(
        "--rejax-python", default=str(DEFAULT_REJAX_PYTHON), help="interpreter with rejax installed"
    )
    parser.add_argument(
        "--sbx-python", default=str(DEFAULT_SBX_PYTHON), help="interpreter with sbx installed"
    )
    parser.add_argument("--timeout", type=float, default=3600, help="seconds per contender")
    parser.add_argument(
        "--timesteps",
        type=int,
        default=None,
        metavar="N",
        help="env steps per seed for every contender, in place of its configuration's "
        "(jaxcart and rejax contenders only): one point of a time-to-solve curve "
        "(benchmarks.train_speed.budgets draws them)",
    )
    lib.add_output_options(parser)
    parser.add_argument("--child", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--child-out", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--cache-dir", default=None, help=argparse.SUPPRESS)
    return parser


def selected(names: list[str], only: str | None) -> list[str]:
    if not only:
        return names
    wanted = lib.split_list(only)
    picked = [n for n in names if any(n == w or n.startswith(w + "-") for w in wanted)]
    if not picked:
        raise SystemExit(f"--only {only!r} matches none of: {', '.join(names)}")
    return picked


def seeds_by_group(args: argparse.Namespace) -> dict[str, list[int]]:
    """Each contender group's seed counts: the mode's defaults (with the opt-in groups that
    ``--only`` names, at the mode's seeds), then ``--seeds-for``."""
    if args.time_to_solve:
        seeds = args.seeds or list(TIME_TO_SOLVE_SEEDS)
        groups = time_to_solve_groups(seeds, args.slow)
        if args.fast_seeds:
            groups["jaxcart-fast"] = args.fast_seeds
    else:
        seeds = args.seeds or list(QUICK_SEEDS if args.quick else FULL_SEEDS)
        fast = args.fast_seeds or list(QUICK_SEEDS if args.quick else FULL_SEEDS[:2])
        groups = default_groups(seeds, fast)
    if args.only:
        groups.update(dict.fromkeys(opt_in_groups_named(lib.split_list(args.only)), seeds))
    for names, counts in args.seeds_for:
        groups.update(dict.fromkeys(names, counts))
    if args.time_to_solve:  # SB3's one-seed row is the table's reference
        groups["sb3-default"] = sorted({1, *groups["sb3-default"]})
    return groups


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.child:
        return child_main(args)
    if args.from_json:
        lib.rerender(args.from_json, args.from_json.stem, markdown, plot)
        return 0
    if args.time_to_solve and args.quick and not args.seeds:
        args.seeds = list(QUICK_SEEDS)
    groups = seeds_by_group(args)
    names = selected(contender_names(groups), args.only)
    if args.timesteps and any(parse_name(n)[0] not in ("jaxcart", "rejax") for n in names):
        raise SystemExit("--timesteps sets jaxcart and rejax contenders only; pick them --only")
    out = lib.output_dir(args.out)
    out.mkdir(parents=True, exist_ok=True)
    settings = {
        "quick": args.quick,
        "time_to_solve": args.time_to_solve,
        "slow": args.slow,
        "seeds_by_group": groups,
        "seeds": groups.get("jaxcart-sb3", []),
        "fast_seeds": groups.get("jaxcart-fast", []),
        "warm_cache": args.warm_cache,
        "rejax_python": args.rejax_python,
        "sbx_python": args.sbx_python,
        "eval_episodes": EVAL_EPISODES,
        "timesteps": args.timesteps,
    }
    report = lib.new_report("train_speed", settings, names)
    for name in names:
        run_contender(name, report, args, out)
    print()
    stem = TIME_TO_SOLVE_STEM if args.time_to_solve else STEM
    lib.save_report(report, out, stem, markdown, plot)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

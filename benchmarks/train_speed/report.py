"""train_speed's report: the Markdown tables and notes, and the plot, from the JSON report."""

from __future__ import annotations

from pathlib import Path

from benchmarks import lib
from benchmarks.train_speed.common import (
    DEFAULT_ENV,
    DESCRIPTIONS,
    EVAL_EPISODES,
    GROUPS,
    PROCESS_KINDS,
    QUICK_TIMESTEPS,
    SB3_TIMESTEPS,
    ZOO_SOURCE,
    env_of,
    group_of,
    label,
    parse_name,
)
from benchmarks.train_speed.contenders.rejax import REJAX_DIFFERENCES

HEADERS = [
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
RATIO_HEADERS = [
    "contender",
    "vs SB3: wall/agent incl. compile",
    "vs SB3: excl. compile",
    "vs SB3: steps/s",
    "vs rejax (same seeds): wall incl. compile",
    "vs rejax: excl. compile",
    "vs rejax: steps/s",
]


TIME_TO_SOLVE_HEADERS = [
    "contender",
    "config",
    "N",
    "wall s (compile incl.)",
    "compile s",
    "of which eval s",
    "peak RSS MiB",
    "CPU s / wall",
    "solved",
    "SB3 1-seed wall / this wall",
]


def find(rows: list[dict], name: str, warm: bool = False) -> dict | None:
    for r in rows:
        if r["contender"] == name and r["warm_cache"] == warm and r.get("status") == "ok":
            return r
    return None


def best_sb3(rows: list[dict]) -> dict | None:
    """The faster (total wall time) of the SB3 rows."""
    candidates = [r for r in (find(rows, "sb3"), find(rows, "sb3-1thread")) if r]
    return min(candidates, key=lambda r: r["total_seconds"]) if candidates else None


def sb3_one_seed_wall(rows: list[dict]) -> dict | None:
    """The SB3-defaults one-seed row with the least whole-process wall time (of ``sb3`` and
    ``sb3-1thread``): the time-to-solve table's reference."""
    candidates = [r for r in (find(rows, "sb3"), find(rows, "sb3-1thread")) if r]
    return min(candidates, key=lambda r: r["process_wall_seconds"]) if candidates else None


def row_label(r: dict) -> str:
    return label(r["contender"]) + (" (warm cache)" if r["warm_cache"] else "")


def row_env(r: dict) -> str:
    """The env a row trained and was evaluated on (rows saved before there was a choice
    carry no ``env_id``: their group says it)."""
    return r.get("env_id") or env_of(r["contender"])


def envs_of(rows: list[dict]) -> list[str]:
    """The envs of ``rows``, CartPole-v1 first."""
    return sorted({row_env(r) for r in rows}, key=lambda e: (e != DEFAULT_ENV, e))


def solved_note(envs: list[str]) -> str:
    """What *solved* means for each of ``envs``."""
    parts = [
        f"all {EVAL_EPISODES} greedy episodes in Gymnasium's `CartPole-v1` reached 500"
        if env == DEFAULT_ENV
        else f"the mean of {EVAL_EPISODES} greedy episodes in Gymnasium's `{env}` reached its "
        "`reward_threshold` (Acrobot-v1: -100)"
        for env in envs
    ]
    return "; or, on another env, ".join(parts)


def fmt_s(v: float | None) -> str:
    return "-" if v is None else f"{v:,.2f}"


def ratio_cells(r: dict, ref: dict | None) -> list[str]:
    """Speed-up over ``ref`` in wall time per trained agent, including and excluding
    setup/compile, and in env steps/s."""
    if ref is None:
        return ["-", "-", "-"]
    per_agent = lambda row, key: row[key] / row["num_seeds"]
    return [
        lib.format_ratio(per_agent(ref, "total_seconds") / per_agent(r, "total_seconds")),
        lib.format_ratio(per_agent(ref, "train_seconds") / per_agent(r, "train_seconds")),
        lib.format_ratio(r["steps_per_second"] / ref["steps_per_second"]),
    ]


def table_row(r: dict) -> list:
    """One measured contender's row of the main table."""
    return [
        row_label(r),
        r["num_seeds"],
        f"{r['env_steps']:,}",
        fmt_s(r["compile_seconds"]),
        fmt_s(r["setup_seconds"]),
        fmt_s(r["train_seconds"]),
        fmt_s(r["total_seconds"]),
        fmt_s(r["process_wall_seconds"]),
        lib.format_rate(r["steps_per_second"]),
        lib.format_rate(r["steps_per_second_incl_setup"]),
        f"{r['peak_rss_mib']:,.0f}",
        f"{r['train_cpu_ratio']:.2f}",
        f"{r['process_cpu_ratio']:.2f}",
        f"{sum(r['eval_mean']) / len(r['eval_mean']):.1f}",
        f"{r['solved']}/{r['num_seeds']}",
    ]


def ratio_rows(rows: list[dict], sb3: dict | None) -> list[list[str]]:
    """Speed-ups of every non-SB3 row over SB3 (CartPole rows) and over rejax with the same
    seeds on the same env (``rejax-sb3`` on CartPole, ``rejax-acrobot`` on Acrobot)."""
    out = []
    for r in rows:
        if r.get("status") != "ok" or r["contender"].startswith("sb3"):
            continue
        kind, _, seeds = parse_name(r["contender"])
        cartpole = row_env(r) == DEFAULT_ENV
        rejax_group = "rejax-sb3" if cartpole else f"rejax-{parse_name(r['contender'])[1]}"
        rejax = None if kind == "rejax" else find(rows, f"{rejax_group}-x{seeds}", r["warm_cache"])
        out.append(
            [row_label(r), *ratio_cells(r, sb3 if cartpole else None), *ratio_cells(r, rejax)]
        )
    return out


def config_cell(r: dict) -> str:
    """What a time-to-solve row ran: the group's configuration (at another step budget with
    ``--timesteps``), and how S > 1 seeds of a one-seed tool were spread over processes."""
    text = DESCRIPTIONS[group_of(r["contender"])][1]
    if r.get("timesteps"):  # --timesteps: another budget than the configuration's
        text += f", run for {r['env_steps'] // r['num_seeds']:,} steps (--timesteps)"
    if r["contender"] == "sb3":
        text += ", torch's default threads"
    if r["num_seeds"] > 1 and parse_name(r["contender"])[0] in PROCESS_KINDS:
        text += f"; {r['num_seeds']} one-seed processes, {r.get('jobs', '?')} at a time"
    return text


def compile_cell(r: dict) -> str:
    if parse_name(r["contender"])[0] == "sb3":
        return "-"  # nothing to compile
    if r.get("compile_seconds") is None:
        return "in training"  # sbx jits inside learn(); not timed apart
    return fmt_s(r["compile_seconds"])


def time_to_solve_row(r: dict, ref: dict | None) -> list:
    """One row of the time-to-solve table; ``ref`` is SB3's one-seed row."""
    rss = f"{r['peak_rss_mib']:,.0f}"
    if r.get("processes_peak_rss_mib"):
        rss = f"{r['processes_peak_rss_mib']:,.0f}†"
    wall = r["process_wall_seconds"]
    return [
        DESCRIPTIONS[group_of(r["contender"])][0],
        config_cell(r),
        r["num_seeds"],
        fmt_s(wall),
        compile_cell(r),
        fmt_s(r.get("eval_seconds")),
        rss,
        f"{r['process_cpu_ratio']:.2f}",
        f"{r['solved']}/{r['num_seeds']}",
        # SB3 ran CartPole-v1 only: no reference for another env's rows
        lib.format_ratio(ref["process_wall_seconds"] / wall)
        if ref and row_env(r) == DEFAULT_ENV
        else "-",
    ]


def time_to_solve_section(report: dict) -> list[str]:
    """The time-to-solve table (cold runs, by seed count then tool) and its notes."""
    budget = report["settings"].get("timesteps")  # --timesteps: every row ran that budget
    rows = [
        {**r, "timesteps": budget}
        for r in report["results"]
        if r.get("status") == "ok" and not r["warm_cache"]
    ]
    # CartPole rows first, then each other env's, each by seed count then tool
    rows.sort(
        key=lambda r: (
            row_env(r) != DEFAULT_ENV,
            row_env(r),
            r["num_seeds"],
            GROUPS.index(group_of(r["contender"])),
        )
    )
    ref = sb3_one_seed_wall(rows)
    s = report["settings"]
    envs = envs_of(rows) or [DEFAULT_ENV]
    out = [
        "## Time to solve",
        "",
        "Wall time of each contender's whole process, from its start to its exit: Python's "
        "start, imports, construction, compilation, training, and the evaluation of every "
        f"seed's greedy policy for {EVAL_EPISODES} episodes of Gymnasium's "
        + " or ".join(f"`{e}`" for e in envs)
        + " (the env the row trained on) by the harness's one evaluator (*of which eval s*); "
        f"*solved* = seeds for which {solved_note(envs)}. Every contender had every core: jaxcart and "
        "rejax train the N seeds in one program sharded over the cores; SB3 and sbx train one "
        "seed per process, N > 1 seeds as one process per core at a time. The last column is "
        "SB3's one-seed wall time (its defaults, the faster of its two thread settings"
        + (f": {row_label(ref)}, {ref['process_wall_seconds']:,.1f} s" if ref else "")
        + ") divided by the row's (higher = faster; CartPole-v1 rows only).",
        "",
        lib.markdown_table(
            TIME_TO_SOLVE_HEADERS, [time_to_solve_row(r, ref) for r in rows], align="llr" + "r" * 7
        ),
        "",
        "- *compile s*: JAX's compilation, cold (persistent cache off), inside the wall time; "
        "SB3 compiles nothing; sbx jits inside `learn()`, not timed apart.",
        "- *peak RSS*: max RSS of the contender's process from `wait4`. † N one-seed processes: "
        "the sum of the contender's process's peak and each pool worker's (an upper bound of "
        "the whole tree's peak; `wait4` reports only the largest single process). *CPU s / "
        "wall*: user + system CPU time of the process and every worker it waited for.",
        f"- rl-zoo3 configuration ({ZOO_SOURCE}): 8 envs (`make_vec_env`), 100,000 steps, "
        "n_steps 32, batch_size 256, gae_lambda 0.8, gamma 0.98, n_epochs 20, ent_coef 0.0, "
        "learning rate linear from 1e-3 and clip range linear from 0.2 (x progress remaining).",
        "- rejax's CartPole configuration: keraJLi/rejax `configs/gymnax/cartpole.yaml`, ppo: "
        "5 envs x 100 steps, 100,000 steps, 5 epochs, 5 minibatches, lr 7.5e-4, grad norm 0.5, "
        "gamma 0.99, lambda 0.95, clip 0.2, entropy 0.01, value coef 0.5, 64-64 tanh.",
    ]
    if any(group_of(r["contender"]) == "rejax-acrobot" for r in rows):
        out.append(
            "- rejax's Acrobot configuration: keraJLi/rejax `configs/gymnax/acrobot.yaml`, ppo: "
            "the CartPole values above on gymnax's Acrobot-v1, with observations normalised "
            "by a running mean and variance (`normalize_observations`), which its greedy "
            "policy applies before the network in the Gymnasium evaluation; that policy is "
            "checked against rejax's own actor on sampled observations inside the timed "
            "process (under a second; `policy_check_seconds` in the JSON)."
        )
    acrobot = [r for r in rows if group_of(r["contender"]) == "jaxcart-acrobot"]
    if acrobot:
        c = acrobot[0].get("config") or {}  # the preset as the contender trained it
        steps = acrobot[0]["env_steps"] // acrobot[0]["num_seeds"]
        shape = (
            f" ({c['num_envs']} envs x {c['num_steps']} steps, {steps:,} steps, "
            f"{c['update_epochs']} epochs of minibatch "
            f"{c['minibatch_size']}, {'-'.join(map(str, c['hidden_sizes']))} "
            f"{c['activation']}, lr {c['learning_rate']:g} annealed, entropy {c['ent_coef']:g})"
            if c
            else ""
        )
        out.append(
            f"- jaxcart's `acrobot` preset: `python -m jaxcart.train --preset acrobot`{shape}, "
            "on gymnax's Acrobot-v1."
        )
    out += [
        "- *jaxcart running PureJaxRL's configuration* is jaxcart's `purejaxrl` preset "
        "(PureJaxRL's CartPole hyperparameters on jaxcart's trainer), not PureJaxRL's "
        "`ppo.py`: PureJaxRL is a script in a GitHub repository, not a package on PyPI, and "
        "this machine has no network access to GitHub.",
    ]
    if s.get("time_to_solve") and not s.get("slow"):
        out.append("- SB3 and sbx above one seed were not run (`--slow` runs them).")
    return out + [""]


def notes(s: dict) -> list[str]:
    """How each contender ran (``s``: the report's settings)."""
    out = [
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
        "- jaxcart: `jaxcart.engine.loop.train(preset(...), num_runs=S, seed=0)`; seeds sharded "
        "over the CPU devices (one per core).",
        f"- rejax: SB3's hyperparameters except where rejax has no option: {REJAX_DIFFERENCES}; "
        "its periodic evaluation replaced by a no-op; S seeds as `jit(vmap(train))` sharded "
        "over the CPU devices.",
        "- SB3 and sbx with S > 1 seeds: S one-seed trainings (seeds 0 ... S-1) in a pool of "
        "one `spawn`-ed process per core, each limited to one torch or XLA thread, inside the "
        "contender's process; their *setup* is 0 and *train* is the pool's wall time (worker "
        "start-up and every seed's construction and training). sbx jit-compiles inside "
        "`learn()`, so its compilation is inside *train* (compile shown as -).",
    ]
    if s["quick"]:
        quick = ", ".join(f"{v:,} ({k})" for k, v in QUICK_TIMESTEPS.items())
        out.append(
            f"- **--quick**: total timesteps per seed cut to {quick} settings, so nothing is "
            "expected to be solved."
        )
    return out + [""]


def markdown(report: dict) -> str:
    rows = report["results"]
    ok = [r for r in rows if r.get("status") == "ok"]
    sb3 = best_sb3(rows)
    failed = [r for r in rows if r.get("status") != "ok"]
    s = report["settings"]
    title = "time to solve" if s.get("time_to_solve") else "training speed"
    envs = envs_of(ok) or [DEFAULT_ENV]
    out = [
        f"# PPO {title} on {' and '.join(envs)}",
        "",
        "Each contender ran in a fresh subprocess. *setup* = construction + initialisation + "
        "compilation (JAX) before the first training step; *train* = the training loop; "
        "*total* = setup + train; *process* = the whole subprocess (imports and the Gymnasium "
        "evaluation included). Peak RSS and process CPU time come from `wait4` on the "
        f"subprocess. *solved* = seeds for which {solved_note(envs)}. Compile "
        "times are cold "
        "(JAX's persistent compilation cache off)"
        + (
            "; with `--warm-cache` the cold run writes a fresh cache and the *warm cache* run "
            "reads it."
            if s["warm_cache"]
            else "."
        ),
        "",
        lib.markdown_table(HEADERS, [table_row(r) for r in ok]),
        "",
        "Speed-ups (higher = that row is faster). Wall time is compared per trained agent "
        "(SB3 trains one agent per process; S seeds count as S agents), steps/s as measured. "
        "SB3 = the faster of its two rows"
        + (f" ({row_label(sb3)}; CartPole-v1 rows only)" if sb3 else "")
        + "; rejax = the rejax row with the same number of seeds on the same env:",
        "",
        lib.markdown_table(RATIO_HEADERS, ratio_rows(rows, sb3)),
        "",
    ]
    tts = time_to_solve_section(report)
    if s.get("time_to_solve"):
        out[2:2] = [*tts, "## Training speed", ""]
    else:
        out += tts
    if failed:
        out += ["Not measured:", ""]
        out += [f"- {r['contender']}: {r['status']}: {r.get('reason', '')}" for r in failed]
        out += [""]
    out += notes(s)
    rejax_version = f" (rejax {report['rejax_version']})" if report.get("rejax_version") else ""
    extra = [f"- rejax interpreter: `{s['rejax_python']}`{rejax_version}"]
    if report.get("sbx_version") or s.get("sbx_python"):
        sbx_version = f" (sbx-rl {report['sbx_version']})" if report.get("sbx_version") else ""
        extra.append(f"- sbx interpreter: `{s['sbx_python']}`{sbx_version}")
    out += lib.provenance_markdown(report, extra)
    return "\n".join(out)


PLOT_GROUPS = [
    ("jaxcart", "sb3", "C0"),
    ("jaxcart", "fast", "C2"),
    ("jaxcart", "purejaxrl", "C4"),
    ("rejax", "sb3", "C1"),
    ("rejax", "cartpole", "C5"),
    ("sbx", "default", "C6"),
    ("sbx", "zoo", "C7"),
    ("sb3", "zoo", "C8"),
    ("jaxcart", "acrobot", "C9"),
    ("rejax", "acrobot", "k"),
]


def plot(report: dict, path: Path) -> None:
    """Wall time against seeds per contender group: setup + train with and without compile,
    or (time-to-solve runs) the whole process's wall time."""
    rows = [r for r in report["results"] if r.get("status") == "ok" and not r["warm_cache"]]
    tts = bool(report["settings"].get("time_to_solve"))
    key = "process_wall_seconds" if tts else "total_seconds"
    fig, ax = lib.pyplot().subplots(figsize=(9.5, 4.5))
    for kind, preset_name, color in PLOT_GROUPS:
        pts = sorted(
            (r["num_seeds"], r[key], r["train_seconds"])
            for r in rows
            if parse_name(r["contender"])[:2] == (kind, preset_name)
        )
        if not pts:
            continue
        xs, total, train = zip(*pts)
        name = f"{kind} {preset_name}"
        ax.plot(xs, total, "o-", color=color, label=name if tts else f"{name}, incl. compile")
        if not tts:
            ax.plot(xs, train, "o--", color=color, alpha=0.6, label=f"{name}, excl. compile")
    sb3 = sb3_one_seed_wall(rows) if tts else best_sb3(report["results"])
    seeds = sorted({r["num_seeds"] for r in rows} | {1})
    if sb3:
        ax.plot(
            seeds,
            [sb3[key] * s for s in seeds],
            ":",
            color="C3",
            label="SB3, S sequential runs (best 1-seed time x S)",
        )
    for r, marker in ((find(rows, "sb3"), "s"), (find(rows, "sb3-1thread"), "D")):
        if r:
            ax.plot([1], [r[key]], marker, color="C3", label=row_label(r))
    sb3_processes = [r for r in rows if group_of(r["contender"]) == "sb3-default"]
    for r in (r for r in sb3_processes if r["num_seeds"] > 1):
        ax.plot([r["num_seeds"]], [r[key]], "s", color="C3", mfc="none", label=row_label(r))
    what = "whole-process wall time (time to solve)" if tts else "wall time"
    title = f"PPO on {' and '.join(envs_of(rows) or [DEFAULT_ENV])}: {what} vs seeds"
    if report["settings"]["quick"]:
        title += " (--quick: shortened runs)"
    title = lib.machine_title(title, report["machine"])
    labels = ("seeds trained (independent agents)", "wall time, s", title)
    legend = {"fontsize": 7, "loc": "center left", "bbox_to_anchor": (1.01, 0.5)}
    lib.finish_loglog(fig, ax, path, labels, xticks=seeds, legend=legend)

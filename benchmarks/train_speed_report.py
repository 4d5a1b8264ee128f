"""train_speed.py's report: the Markdown tables and notes, and the plot, from the JSON report."""

from __future__ import annotations

from pathlib import Path

import benchlib
from train_speed_common import EVAL_EPISODES, QUICK_TIMESTEPS, SB3_TIMESTEPS, label, parse_name
from train_speed_rejax import REJAX_DIFFERENCES

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
        benchlib.format_rate(r["steps_per_second"]),
        benchlib.format_rate(r["steps_per_second_incl_setup"]),
        f"{r['peak_rss_mib']:,.0f}",
        f"{r['train_cpu_ratio']:.2f}",
        f"{r['process_cpu_ratio']:.2f}",
        f"{sum(r['eval_mean']) / len(r['eval_mean']):.1f}",
        f"{r['solved']}/{r['num_seeds']}",
    ]


def ratio_rows(rows: list[dict], sb3: dict | None) -> list[list[str]]:
    """Speed-ups of every non-SB3 row over SB3 and over rejax with the same seeds."""
    out = []
    for r in rows:
        if r.get("status") != "ok" or r["contender"].startswith("sb3"):
            continue
        kind, _, seeds = parse_name(r["contender"])
        rejax = None if kind == "rejax" else find(rows, f"rejax-sb3-x{seeds}", r["warm_cache"])
        out.append([row_label(r), *ratio_cells(r, sb3), *ratio_cells(r, rejax)])
    return out


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
        "- jaxcart: `jaxcart.trainer.train(preset(...), num_runs=S, seed=0)`; seeds sharded "
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
    return out + [""]


def markdown(report: dict) -> str:
    rows = report["results"]
    ok = [r for r in rows if r.get("status") == "ok"]
    sb3 = best_sb3(rows)
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
        benchlib.markdown_table(HEADERS, [table_row(r) for r in ok]),
        "",
        "Speed-ups (higher = that row is faster). Wall time is compared per trained agent "
        "(SB3 trains one agent per process; S seeds count as S agents), steps/s as measured. "
        "SB3 = the faster of its two rows"
        + (f" ({row_label(sb3)})" if sb3 else "")
        + "; rejax = the rejax row with the same number of seeds:",
        "",
        benchlib.markdown_table(RATIO_HEADERS, ratio_rows(rows, sb3)),
        "",
    ]
    if failed:
        out += ["Not measured:", ""]
        out += [f"- {r['contender']}: {r['status']}: {r.get('reason', '')}" for r in failed]
        out += [""]
    out += notes(s)
    rejax_version = f" (rejax {report['rejax_version']})" if report.get("rejax_version") else ""
    rejax_line = f"- rejax interpreter: `{s['rejax_python']}`{rejax_version}"
    out += benchlib.provenance_markdown(report, [rejax_line])
    return "\n".join(out)


def plot(report: dict, path: Path) -> None:
    rows = [r for r in report["results"] if r.get("status") == "ok" and not r["warm_cache"]]
    fig, ax = benchlib.pyplot().subplots(figsize=(9.5, 4.5))
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
    title = "PPO on CartPole-v1: wall time vs seeds"
    if report["settings"]["quick"]:
        title += " (--quick: shortened runs)"
    title = benchlib.machine_title(title, report["machine"])
    labels = ("seeds trained (independent agents)", "wall time, s", title)
    legend = {"fontsize": 7, "loc": "center left", "bbox_to_anchor": (1.01, 0.5)}
    benchlib.finish_loglog(fig, ax, path, labels, xticks=seeds, legend=legend)

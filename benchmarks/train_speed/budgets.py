"""Time to solve as a curve: seeds solved against whole-process wall time, one point per step
budget, for each contender of ``benchmarks.train_speed`` runs made with ``--timesteps``.

    python -m benchmarks.train_speed --time-to-solve --only jaxcart-acrobot,rejax-acrobot \\
        --seeds 64 --timesteps 51200 --out DIR/51200      # and the other budgets
    python -m benchmarks.train_speed.budgets DIR/* --out DIR/time_to_solve_curve

Every point is one contender process (compile and the harness's Gymnasium evaluation
included) at one budget; the curve is what a user with that much wall time gets. Writes
``<out>.png`` and ``<out>.md`` (the points as a table).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from benchmarks.train_speed.common import DESCRIPTIONS, TIME_TO_SOLVE_STEM, group_of


def read_points(dirs: list[Path]) -> dict[str, list[dict]]:
    """Contender group -> its rows (``status`` ok) across ``dirs``, by env steps per seed."""
    points: dict[str, list[dict]] = {}
    for d in dirs:
        report = json.loads((d / f"{TIME_TO_SOLVE_STEM}.json").read_text())
        for row in report["results"]:
            if row.get("status") == "ok":
                points.setdefault(group_of(row["contender"]), []).append(row)
    return {
        g: sorted(rows, key=lambda r: r["env_steps"] / r["num_seeds"]) for g, rows in points.items()
    }


def table(points: dict[str, list[dict]]) -> str:
    lines = [
        "| contender | env steps per seed | process wall s | compile s | train s | solved |",
        "| --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    for group, rows in points.items():
        for r in rows:
            lines.append(
                f"| {DESCRIPTIONS[group][0]} | {r['env_steps'] // r['num_seeds']:,} | "
                f"{r['process_wall_seconds']:.1f} | {r['compile_seconds']:.1f} | "
                f"{r['train_seconds']:.1f} | {r['solved']}/{r['num_seeds']} |"
            )
    return "\n".join(lines) + "\n"


def draw(points: dict[str, list[dict]], out: Path) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 5), layout="constrained")
    ax = fig.add_subplot()
    for group, rows in points.items():
        x = [r["process_wall_seconds"] for r in rows]
        y = [r["solved"] / r["num_seeds"] for r in rows]
        ax.plot(x, y, "o-", label=DESCRIPTIONS[group][0])
        for r, xi, yi in zip(rows, x, y):
            steps = r["env_steps"] // r["num_seeds"]
            ax.annotate(
                f"{steps / 1000:.0f}k",
                (xi, yi),
                xytext=(4, -12),
                fontsize=8,
                textcoords="offset points",
            )
    env = next(iter(points.values()))[0]["env_id"]
    ax.set(
        title=f"{env}: seeds solved against whole-process wall time (labels: env steps per seed)",
        xlabel="process wall time, s (compile and evaluation included)",
        ylabel="fraction of seeds solved",
        ylim=(-0.02, 1.02),
    )
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    fig.savefig(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("dirs", nargs="+", type=Path, help="train_speed --out directories")
    parser.add_argument("--out", type=Path, required=True, help="output path without suffix")
    args = parser.parse_args(argv)
    points = read_points(args.dirs)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".md").write_text(table(points))
    draw(points, args.out.with_suffix(".png"))
    print(table(points))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

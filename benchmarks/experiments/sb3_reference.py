r"""Train Stable-Baselines3's PPO with its defaults and save it as a jaxcart run directory.

The CartPole course comparison: SB3's ``PPO("MlpPolicy", "CartPole-v1").learn(80_000)`` and
jaxcart's ``sb3`` preset on the same axes. The work is ``python -m jaxcart.sb3``'s
(:mod:`jaxcart.run.sb3`); this entry point keeps the benchmarks' command and its option names
(``--timesteps``) for the experiments that call it:

    benchmarks/.venv-bench/bin/python -m benchmarks.experiments.sb3_reference \
        --num-seeds 3 --out runs/sb3-torch
    python -m jaxcart.train --num-seeds 3 --out runs/jaxcart-sb3
    python -m jaxcart.plot runs/sb3-torch runs/jaxcart-sb3 --out benchmarks/results/sb3_vs_jaxcart.png

(needs ``torch`` and ``stable-baselines3``: ``bash benchmarks/setup_venvs.sh``).
"""

from __future__ import annotations

from pathlib import Path

from benchmarks import lib
from jaxcart import sb3


def main() -> None:
    parser = lib.arg_parser(__doc__)
    parser.add_argument("--num-seeds", type=int, default=3)
    parser.add_argument("--timesteps", type=int, default=80_000)
    parser.add_argument(
        "--threads", type=int, default=1, help="torch threads (1 is fastest for this tiny MLP)"
    )
    parser.add_argument(
        "--first-seed", type=int, default=0, help="seeds are first-seed ... first-seed+num-seeds-1"
    )
    parser.add_argument(
        "--jobs", type=int, default=1, help="seeds trained at once, one process each (one per core)"
    )
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    argv = ["--num-seeds", args.num_seeds, "--total-timesteps", args.timesteps]
    argv += ["--threads", args.threads, "--first-seed", args.first_seed, "--jobs", args.jobs]
    raise SystemExit(sb3.main([*map(str, argv), "--out", str(args.out)]))


if __name__ == "__main__":
    main()

"""Hyperparameter search against rl-zoo3 itself: ``jaxcart.tune`` beside
``python -m rl_zoo3.train --algo ppo --env CartPole-v1 --optimize``, the same trial budget and
rl-zoo3's CartPole-v1 training budget per trial; trials per hour, the best score against wall
time, and the best trial at an equal wall time scored again on held-out seeds.

- ``rl-zoo3``: rl-zoo3's own ``train.py`` in the SB3 venv (``--sb3-python``) as it runs:
  its CartPole-v1 config (ppo.yml: 8 envs, 100k steps), its sampler (``sample_ppo_params``:
  TPE, 10 random start-up trials, ``--seed`` the sampler's seed), its median pruner, its
  scoring (one evaluation of 5 greedy episodes at the end of the trial's training, with the
  default ``--n-evaluations``, one per 100k steps), ``--n-jobs`` (default: one per core, as
  Optuna threads) and one torch thread per job (``--num-threads 1``); its study in
  ``OUT/rl-zoo3.db``, its small logs in ``OUT/rl-zoo3-logs``, ``--no-optim-plots``.
- ``jaxcart``: ``python -m jaxcart.tune --score eval`` with rl-zoo3's float space (the
  default ``--space rl-zoo3``) over rl-zoo3's CartPole-v1 shape settings (8 envs x 32 steps,
  minibatch 256, 20 epochs, 100k steps; constant learning rate and clip, as rl-zoo3's trials
  train), ``--batch-trials`` trials x ``--num-seeds`` seeds per compiled program, TPE; the
  score the IQM over its seeds of each seed's greedy mean return over 20 episodes; every
  compile timed (``--no-compile-cache``; ``--warm-cache`` lets it use its cache).

What differs, by design: rl-zoo3 also samples shape settings (n_steps 32-4096, batch size
4-1024, epochs 1-20, the network and its activation) that jaxcart's default space leaves at
rl-zoo3's CartPole values; a rl-zoo3 trial is one seed scored by 5 episodes, a jaxcart trial
``--num-seeds`` seeds scored by 20 each.

Each contender is one whole process (imports, compiles and evaluation included), timed from
outside, alone; the report reads each study's trial completion times from its Optuna storage.
Then the held-out check: the cut-off is the earlier contender's finish (``--cutoff`` to set
it); each contender's best complete trial as of the cut-off, and as of its own finish, is
trained again by its own trainer on ``--heldout-seeds`` fresh seeds from ``--heldout-seed``
(rl-zoo3's through its ``train.py`` with the trial's values as ``-params``, jaxcart's through
``python -m jaxcart.train``) and every seed's greedy policy plays the same 20 Gymnasium
CartPole-v1 episodes (reset seeds 1,000,000 + e)::

    .venv/bin/python -m benchmarks.tune --quick --sb3-python /tmp/sb3venv/bin/python  # minutes
    .venv/bin/python -m benchmarks.tune --sb3-python benchmarks/.venv-bench/bin/python
    .venv/bin/python -m benchmarks.tune --only jaxcart --trials 32 --num-seeds 4

The SB3 venv needs rl-zoo3 with pandas, which its ``--optimize`` writes its report with
(``benchmarks/setup_venvs.sh`` installs ``rl_zoo3[plots]``); the harness checks that first.
"""

from __future__ import annotations

import json
import os
import shlex
import shutil
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from benchmarks import lib

CONTENDERS = ("jaxcart", "rl-zoo3")
QUICK = {
    "trials": 4,
    "batch_trials": 2,
    "num_seeds": 2,
    "timesteps": 4096,
    "heldout_seeds": 2,
    # A smoke test's rl-zoo3 draws its trials in a known order (one job) from a seed whose four
    # random start-up draws are among its cheapest (n_steps x batch size x epochs): one draw of
    # n_steps 4096 with batch size 8 trains 40k minibatches and takes minutes, even for 4k steps.
    "zoo_n_jobs": 1,
    "sampler_seed": 36,
}
SB3_VENV = Path("benchmarks/.venv-bench/bin/python")
ZOO_TIMESTEPS = 100_000
# rl-zoo3's CartPole-v1 shape settings (hyperparams/ppo.yml), as jaxcart's options; its float
# settings are what both searches draw. rl-zoo3's trials train with a constant learning rate
# and clip range (the sampled floats replace the config's lin_ schedules).
JAXCART_BASE = (
    *("--num-envs", "8", "--num-steps", "32", "--minibatch-size", "256"),
    *("--update-epochs", "20", "--no-anneal-lr", "--no-anneal-clip"),
)
HELDOUT_EPISODES = 20


def cores() -> int:
    return len(os.sched_getaffinity(0))


def parse_args(argv: list[str] | None = None):
    parser = lib.arg_parser(__doc__)
    parser.add_argument("--only", type=lib.split_list, default=list(CONTENDERS))
    parser.add_argument("--trials", type=int, default=32, help="trial budget of each contender")
    parser.add_argument("--batch-trials", type=int, default=8, help="jaxcart's trials per batch")
    parser.add_argument("--num-seeds", type=int, default=4, help="jaxcart's seeds per trial")
    parser.add_argument(
        "--timesteps", type=int, default=ZOO_TIMESTEPS, help="env steps per seed and trial"
    )
    parser.add_argument(
        "--space", action="append", default=None, help="jaxcart's space (default: rl-zoo3)"
    )
    parser.add_argument(
        "--pruner",
        default="none",
        choices=["none", "median", "halving"],
        help="jaxcart's pruner (rl-zoo3 runs its own, --zoo-pruner)",
    )
    parser.add_argument(
        "--sampler-seed", type=int, default=0, help="both samplers' seed (rl-zoo3's --seed)"
    )
    parser.add_argument(
        "--warm-cache",
        action="store_true",
        help="let jaxcart use its persistent compilation cache (default: --no-compile-cache, "
        "every compile timed, whatever ran before)",
    )
    parser.add_argument("--sb3-python", type=Path, default=SB3_VENV)
    parser.add_argument(
        "--zoo-n-jobs", type=int, default=cores(), help="rl-zoo3's --n-jobs (default: cores)"
    )
    parser.add_argument(
        "--zoo-num-threads", type=int, default=1, help="rl-zoo3's --num-threads (-1: torch's)"
    )
    parser.add_argument("--zoo-pruner", default="median", choices=["none", "median", "halving"])
    parser.add_argument("--heldout-seeds", type=int, default=8, help="0 skips the held-out check")
    parser.add_argument("--heldout-seed", type=int, default=10_000, help="first held-out seed")
    parser.add_argument(
        "--cutoff",
        type=float,
        default=None,
        help="equal wall time in seconds (default: the earlier contender's finish)",
    )
    parser.add_argument(
        "--heldout-jobs",
        type=int,
        default=cores(),
        help="rl-zoo3 held-out seeds trained at a time",
    )
    parser.add_argument(
        "--heldout-from",
        type=Path,
        default=None,
        help="only the held-out check again, of an earlier run's tune.json (its studies beside it)",
    )
    parser.add_argument("--quick", action="store_true", help=f"a smoke test: {QUICK}")
    lib.add_output_options(parser)
    args = parser.parse_args(argv)
    if args.quick:
        for key, value in QUICK.items():
            setattr(args, key, value)
    args.space = args.space or ["rl-zoo3"]
    unknown = set(args.only) - set(CONTENDERS)
    if unknown:
        parser.error(f"--only: unknown contender(s) {sorted(unknown)}; known: {CONTENDERS}")
    return args


def jaxcart_base(args) -> list[str]:
    """What every jaxcart trial and retrain shares: rl-zoo3's CartPole shape, the budget."""
    return [*JAXCART_BASE, "--total-timesteps", str(args.timesteps)]


def commands(args, out: Path) -> dict[str, list[str]]:
    """Each contender's command line, its study in ``out/NAME.db``."""
    space = [w for s in args.space for w in ("--space", s)]
    return {
        "jaxcart": [
            sys.executable,
            *("-m", "jaxcart.tune", "--score", "eval", "--quiet"),
            *("--trials", str(args.trials), "--batch-trials", str(args.batch_trials)),
            "--num-seeds",
            str(args.num_seeds),
            *jaxcart_base(args),
            *("--storage", f"sqlite:///{out / 'jaxcart.db'}", "--study-name", "jaxcart"),
            *("--out", str(out / "jaxcart-runs"), "--pruner", args.pruner),
            *("--sampler-seed", str(args.sampler_seed)),
            *("--heldout-top", "0"),  # the search alone: the harness runs its own check
            *([] if args.warm_cache else ["--no-compile-cache"]),
            *space,
        ],
        "rl-zoo3": [
            str(args.sb3_python),
            *("-m", "rl_zoo3.train", "--algo", "ppo", "--env", "CartPole-v1", "--optimize"),
            *("--n-trials", str(args.trials), "--n-jobs", str(args.zoo_n_jobs)),
            *("--sampler", "tpe", "--pruner", args.zoo_pruner),
            *("--storage", f"sqlite:///{out / 'rl-zoo3.db'}", "--study-name", "rl-zoo3"),
            *("--seed", str(args.sampler_seed), "--num-threads", str(args.zoo_num_threads)),
            *("--device", "cpu", "--no-optim-plots", "-f", str(out / "rl-zoo3-logs")),
            *(["-n", str(args.timesteps)] if args.timesteps != ZOO_TIMESTEPS else []),
        ],
    }


# -- the studies ------------------------------------------------------------------------------


def study_trials(storage: str, name: str, started: float) -> list[dict]:
    """The study's finished trials (complete or pruned) in the order they finished:
    ``{"seconds": since the process started, "number", "state", "value"}``."""
    import optuna

    states = optuna.trial.TrialState
    study = optuna.load_study(study_name=name, storage=storage)
    done = [
        {
            "seconds": round(t.datetime_complete.timestamp() - started, 2),
            "number": t.number,
            "state": t.state.name.lower(),
            "value": t.value,
        }
        for t in study.get_trials(deepcopy=False)
        if t.state in (states.COMPLETE, states.PRUNED) and t.datetime_complete is not None
    ]
    return sorted(done, key=lambda t: (t["seconds"], t["number"]))


def best_curve(trials: list[dict]) -> list[tuple[float, float, int]]:
    """``[(seconds, best score so far, its trial)]`` at each complete trial that raised the
    best (a pruned trial's value is its last report; neither tool counts it as its best)."""
    curve: list[tuple[float, float, int]] = []
    for t in trials:
        if t["state"] == "complete" and t["value"] is not None:
            if not curve or t["value"] > curve[-1][1]:
                curve.append((t["seconds"], t["value"], t["number"]))
    return curve


def study_curve(storage: str, name: str, started: float) -> list[tuple[float, float]]:
    """``[(seconds since the process started, best score so far)]`` at each complete trial."""
    trials = [t for t in study_trials(storage, name, started) if t["state"] == "complete"]
    curve, best = [], float("-inf")
    for t in trials:
        best = max(best, t["value"])
        curve.append((t["seconds"], best))
    return curve


def best_as_of(curve: list, seconds: float) -> dict | None:
    """The best complete trial finished by ``seconds``: ``{"trial", "score", "found_at"}``."""
    reached = [c for c in curve if c[0] <= seconds]
    if not reached:
        return None
    found_at, score, number = reached[-1]
    return {"trial": number, "score": score, "found_at": found_at}


ZOO_PACKAGES = ("rl_zoo3", "stable-baselines3", "torch", "optuna", "gymnasium", "pandas")
ZOO_CHECK = (
    "import json, importlib.metadata as m, rl_zoo3.train, pandas; "
    f"print(json.dumps({{p: m.version(p) for p in {ZOO_PACKAGES!r}}}))"
)


def zoo_versions(python: Path) -> dict | str:
    """The SB3 venv's package versions, or why it cannot run rl-zoo3's ``--optimize``
    (which ends by writing its report with pandas, rl_zoo3's ``plots`` extra)."""
    if not python.exists():
        return f"{python} not found (benchmarks/setup_venvs.sh)"
    done = subprocess.run([str(python), "-c", ZOO_CHECK], capture_output=True, text=True)
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["?"])[-1]
        return f"{python}: {last} (pip install 'rl_zoo3[plots]')"
    return json.loads(done.stdout)


def run_contender(name: str, command: list[str], out: Path) -> dict:
    db = out / f"{name}.db"
    db.unlink(missing_ok=True)  # a fresh study, and no earlier run directories or logs
    for folder in (f"{name}-runs", f"{name}-logs"):
        shutil.rmtree(out / folder, ignore_errors=True)
    if not Path(command[0]).exists():
        print(f"{name}: {command[0]} not found; skipped (benchmarks/setup_venvs.sh)", flush=True)
        return {"contender": name, "error": [f"{command[0]} not found"]}
    log = out / f"{name}.log"
    started = time.time()
    with log.open("w") as sink:
        done = subprocess.run(command, stdout=sink, stderr=subprocess.STDOUT, text=True)
    wall = time.time() - started
    if done.returncode != 0:
        tail = log.read_text().strip().splitlines()[-3:]
        print(f"{name}: exit {done.returncode}: {' | '.join(tail)}", flush=True)
        return {"contender": name, "error": tail, "command": shlex.join(command)}
    trials = study_trials(f"sqlite:///{db}", name, started)
    curve = best_curve(trials)
    result = {
        "contender": name,
        "command": shlex.join(command),
        "log": lib.display_path(log),
        "wall_seconds": round(wall, 2),
        "trials": len(trials),
        "complete": sum(t["state"] == "complete" for t in trials),
        "pruned": sum(t["state"] == "pruned" for t in trials),
        "trials_per_hour": round(3600 * len(trials) / wall, 1),
        "best": curve[-1][1] if curve else None,
        "best_trial": curve[-1][2] if curve else None,
        "curve": curve,
        "finished": trials,
    }
    print(
        f"{name}: {result['trials']} trials ({result['pruned']} pruned) in {wall:.1f} s, "
        f"{result['trials_per_hour']:,.0f} trials/hour, best {result['best']}",
        flush=True,
    )
    return result


# -- the held-out check -----------------------------------------------------------------------


def heldout_seeds(args) -> list[int]:
    return list(range(args.heldout_seed, args.heldout_seed + args.heldout_seeds))


def jaxcart_train_command(args, params: dict, out: Path) -> list[str]:
    """``python -m jaxcart.train`` at the trial's values (jaxcart's own ``retrain_command``)
    over the search's base, on the held-out seeds (``fold_in(--heldout-seed, i)``)."""
    from jaxcart import configfile, tune

    argv = [*jaxcart_base(args), *(w for s in args.space for w in ("--space", s))]
    opts = tune.TuneOptions.from_args(configfile.parse_with_config(tune.build_parser(), argv), argv)
    words = shlex.split(tune.retrain_command(opts, params, str(out), args.heldout_seed))
    words[words.index("--num-seeds") + 1] = str(args.heldout_seeds)
    return [sys.executable, *words[1:], "--eval-episodes", str(HELDOUT_EPISODES), "--quiet"]


def heldout_jaxcart(args, out: Path, number: int) -> dict:
    import optuna

    study = optuna.load_study(study_name="jaxcart", storage=f"sqlite:///{out / 'jaxcart.db'}")
    (trial,) = [t for t in study.get_trials(deepcopy=False) if t.number == number]
    run = out / "heldout" / f"jaxcart-trial-{number}"
    shutil.rmtree(run, ignore_errors=True)
    command = jaxcart_train_command(args, trial.params, run)
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"jaxcart.train exit {done.returncode}: {done.stderr[-1000:]}")
    seeds = json.loads((run / "evaluation.json").read_text())["seeds"]
    return {
        "commands": [shlex.join(command)],
        "seeds": [f"fold_in({args.heldout_seed}, {s['seed_index']})" for s in seeds],
        "scores": [s["gymnasium_mean"] for s in seeds],
    }


def heldout_zoo(args, out: Path, number: int) -> dict:
    storage = f"sqlite:///{out / 'rl-zoo3.db'}"
    folder = out / "heldout" / f"rl-zoo3-trial-{number}"
    shutil.rmtree(folder, ignore_errors=True)

    def one(seed: int) -> dict:
        command = [
            *lib.module_command("benchmarks.tune.zoo_heldout", args.sb3_python),
            *("--storage", storage, "--study-name", "rl-zoo3", "--trial", str(number)),
            *("--seed", str(seed), "--out", str(folder / f"seed-{seed}")),
            *("--timesteps", str(args.timesteps), "--episodes", str(HELDOUT_EPISODES)),
        ]
        done = subprocess.run(command, capture_output=True, text=True)
        if done.returncode != 0:
            raise RuntimeError(f"zoo_heldout exit {done.returncode}: {done.stderr[-1000:]}")
        return json.loads(done.stdout.strip().splitlines()[-1])

    with ThreadPoolExecutor(max(1, args.heldout_jobs)) as pool:
        lines = list(pool.map(one, heldout_seeds(args)))
    return {
        "commands": [shlex.join(line["command"]) for line in lines],
        "seeds": [line["seed"] for line in lines],
        "scores": [line["mean"] for line in lines],
    }


HELDOUT = {"jaxcart": heldout_jaxcart, "rl-zoo3": heldout_zoo}


def heldout_check(args, out: Path, results: list[dict]) -> float | None:
    """Trains each contender's best trial as of the cut-off and as of its finish again on
    the held-out seeds (each distinct trial once); returns the cut-off."""
    ran = [r for r in results if "curve" in r]
    if not ran or args.heldout_seeds <= 0:
        return None
    cutoff = args.cutoff if args.cutoff is not None else min(r["wall_seconds"] for r in ran)
    for r in ran:
        picks = {
            "cutoff": best_as_of(r["curve"], cutoff),
            "finish": best_as_of(r["curve"], float("inf")),
        }
        done: dict[int, dict] = {}
        r["heldout"] = {}
        for when, pick in picks.items():
            if pick is None:
                r["heldout"][when] = None
                continue
            number = pick["trial"]
            if number not in done:
                print(f"{r['contender']}: held-out seeds for trial {number}", flush=True)
                try:
                    scores = HELDOUT[r["contender"]](args, out, number)
                except (RuntimeError, OSError, ValueError) as exc:  # the searches stay reported
                    print(f"  failed: {exc}", flush=True)
                    done[number] = {"error": str(exc)}
                    r["heldout"][when] = {**pick, **done[number]}
                    continue
                s = scores["scores"]
                done[number] = {
                    **scores,
                    "mean": sum(s) / len(s),
                    "min": min(s),
                    "max": max(s),
                }
                print(f"  mean {done[number]['mean']:.1f} [{min(s):.1f}-{max(s):.1f}]", flush=True)
            r["heldout"][when] = {**pick, **done[number]}
    return cutoff


# -- the report -------------------------------------------------------------------------------


def _heldout_text(entry: dict | None) -> str:
    if entry is None:
        return "no complete trial"
    if "error" in entry:
        return f"failed (trial {entry['trial']}; see the JSON)"
    return (
        f"{entry['mean']:.1f} [{entry['min']:.1f}-{entry['max']:.1f}] "
        f"(trial {entry['trial']}, search {entry['score']:.1f} at {entry['found_at']:.0f} s)"
    )


def markdown(report: dict) -> str:
    s = report["settings"]
    rows = []
    for r in report["results"]:
        if "wall_seconds" not in r:
            rows.append([r["contender"], "failed", *["-"] * 6])
            continue
        heldout = r.get("heldout") or {}
        rows.append(
            [
                r["contender"],
                f"{r['trials']} ({r['pruned']} pruned)",
                str(s["num_seeds"] if r["contender"] == "jaxcart" else 1),
                f"{r['wall_seconds']:.1f}",
                f"{r['trials_per_hour']:,.0f}",
                f"{r['best']:.1f}" if r.get("best") is not None else "-",
                _heldout_text(heldout["cutoff"]) if "cutoff" in heldout else "-",
                _heldout_text(heldout["finish"]) if "finish" in heldout else "-",
            ]
        )
    cutoff = report.get("cutoff_seconds")
    packages = report.get("zoo_packages")
    zoo = [f"- SB3 venv: {', '.join(f'{k} {v}' for k, v in packages.items())}"] if packages else []
    table = lib.markdown_table(
        [
            "contender",
            "trials",
            "seeds per trial",
            "wall s",
            "trials/hour",
            "best search score",
            f"held-out, best at {cutoff:.0f} s" if cutoff is not None else "held-out at cut-off",
            "held-out, best at finish",
        ],
        rows,
    )
    lines = [
        "# Hyperparameter search: jaxcart tune against rl-zoo3's --optimize",
        "",
        f"{s['trials']} trials each; {s['timesteps']:,} env steps per seed and trial at rl-zoo3's "
        f"CartPole-v1 settings (8 envs x 32 steps); jaxcart's space {', '.join(s['space'])}, "
        f"{s['num_seeds']} seeds per trial, {s['batch_trials']} trials per batch, pruner "
        f"{s['pruner']}, score the IQM of each seed's greedy mean over 20 episodes; rl-zoo3's "
        f"sample_ppo_params, TPE, pruner {s['zoo_pruner']}, --n-jobs {s['zoo_n_jobs']}, "
        f"--num-threads {s['zoo_num_threads']}, score its 5-episode greedy evaluation at the "
        f"end of training; sampler seed {s['sampler_seed']}"
        + (
            f"; jaxcart's compilation cache {'on' if s['warm_cache'] else 'off'}"
            if "warm_cache" in s
            else ""
        )
        + ". Whole processes, timed from outside, one after the other.",
        "",
        f"Held-out: each contender's best complete trial as of the cut-off "
        f"({cutoff:.1f} s, the earlier finish unless --cutoff) and as of its own finish, "
        f"trained again by its own trainer on {s['heldout_seeds']} seeds from "
        f"{s['heldout_seed']}; each seed's greedy mean return over 20 Gymnasium CartPole-v1 "
        "episodes (reset seeds 1,000,000 + e); the mean over seeds [min-max]."
        if cutoff is not None
        else "Held-out check skipped.",
        "",
        table,
        "",
        *[f"- {r['contender']}: `{r['command']}`" for r in report["results"] if "command" in r],
        "",
        *lib.provenance_markdown(report, zoo),
    ]
    return "\n".join(lines) + "\n"


def plot(report: dict, path: Path) -> None:
    plt = lib.pyplot()
    fig, ax = plt.subplots(figsize=(6.5, 4))
    for r in report["results"]:
        if r.get("curve"):
            xs = [c[0] for c in r["curve"]] + [r["wall_seconds"]]
            ys = [c[1] for c in r["curve"]] + [r["curve"][-1][1]]
            (line,) = ax.step(xs, ys, where="post", label=f"{r['contender']} (search score)")
            heldout = r.get("heldout") or {}
            marks = {"cutoff": ("o", report.get("cutoff_seconds")), "finish": ("s", xs[-1])}
            for when, (marker, x) in marks.items():
                held = heldout.get(when)
                if held is None or x is None:
                    continue
                ax.errorbar(
                    [x],
                    [held["mean"]],
                    yerr=[[held["mean"] - held["min"]], [held["max"] - held["mean"]]],
                    fmt=marker,
                    mfc="white" if when == "finish" else line.get_color(),
                    color=line.get_color(),
                    capsize=3,
                    label=f"{r['contender']} held-out, best at {'cut-off' if when == 'cutoff' else 'finish'}",
                )
    if report.get("cutoff_seconds") is not None:
        ax.axvline(report["cutoff_seconds"], color="gray", linestyle=":", linewidth=1)
    ax.set_xlim(left=0)
    ax.set_ylim(0, 520)
    ax.set_xlabel("wall seconds (whole process)")
    ax.set_ylabel("greedy mean return")
    ax.set_title("best complete trial so far (lines); held-out mean [min-max]", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    args = parse_args()
    if args.from_json:
        lib.rerender(args.from_json, "tune", markdown, plot)
        return
    if args.heldout_from:
        heldout_again(args)
        return
    out = lib.output_dir(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    settings = {
        key: getattr(args, key)
        for key in (
            "trials",
            "batch_trials",
            "num_seeds",
            "timesteps",
            "space",
            "pruner",
            "sampler_seed",
            "zoo_n_jobs",
            "zoo_num_threads",
            "zoo_pruner",
            "warm_cache",
            "heldout_seeds",
            "heldout_seed",
            "cutoff",
        )
    }
    report = lib.new_report("tune", settings, args.only)
    every = commands(args, out)
    for name in args.only:
        if name == "rl-zoo3":
            versions = zoo_versions(args.sb3_python)
            if isinstance(versions, str):
                print(f"rl-zoo3: skipped: {versions}", flush=True)
                report["results"].append({"contender": name, "error": [versions]})
                continue
            report["zoo_packages"] = versions
        print(f"{name}: {shlex.join(every[name])}", flush=True)
        report["results"].append(run_contender(name, every[name], out))
    lib.write_json(out / "tune.json", report)  # the searches, should the held-out check fail
    report["cutoff_seconds"] = heldout_check(args, out, report["results"])
    lib.save_report(report, out, "tune", markdown, plot)


def heldout_again(args) -> None:
    """``--heldout-from OUT/tune.json``: the held-out check of an earlier run's searches
    again (its studies are read from the JSON's folder), with this command's held-out options."""
    path = args.heldout_from.resolve()
    report = json.loads(path.read_text())
    for key in ("timesteps", "space"):  # the retrains train what the searches trained
        setattr(args, key, report["settings"][key])
    report["settings"].update(
        {k: getattr(args, k) for k in ("heldout_seeds", "heldout_seed", "cutoff")}
    )
    report["heldout_command"] = lib.command_line()
    report["cutoff_seconds"] = heldout_check(args, path.parent, report["results"])
    lib.save_report(report, path.parent, "tune", markdown, plot)


if __name__ == "__main__":
    main()

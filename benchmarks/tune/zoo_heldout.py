"""rl-zoo3's side of the held-out check of ``python -m benchmarks.tune``, run in the SB3 venv:
one trial of an rl-zoo3 study trained again on one fresh seed through rl-zoo3's own
``train.py``, then played greedily in Gymnasium's CartPole-v1 as jaxcart's evaluation plays
its runs (episode ``e`` reset with seed ``EVAL_SEED + e``, the same 20 starts for every policy).

The trial's values go through rl-zoo3's own converter (``HYPERPARAMS_CONVERTER["ppo"]``, as
``--trial-id`` would load them) into ``-params``, over rl-zoo3's CartPole-v1 config, as its
objective gives them to PPO. (``--trial-id`` itself is not used: rl-zoo3 skips it for trial 0.)
Prints one JSON line: the seed, the command, the greedy returns and their mean::

    python -m benchmarks.tune.zoo_heldout --storage sqlite:///OUT/rl-zoo3.db \\
        --study-name rl-zoo3 --trial 7 --seed 10000 --out OUT/heldout/rl-zoo3-trial-7
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

EVAL_SEED = 1_000_000
"""jaxcart.core.solved.EVAL_SEED: episode ``e`` starts from ``reset(seed=EVAL_SEED + e)``."""
ZOO_TIMESTEPS = 100_000
"""rl-zoo3's CartPole-v1 ``n_timesteps`` (``-n`` is passed only for another budget)."""


def param_text(name: str, value) -> str:
    """One ``-params`` word, ``NAME:PYTHON``, that rl-zoo3's ``StoreDict`` evaluates back to
    ``value`` (``nn`` is ``torch.nn`` where it evaluates)."""
    if name == "policy_kwargs":
        inner = ", ".join(
            f"{k}=nn.{v.__name__}" if isinstance(v, type) else f"{k}={v!r}"
            for k, v in value.items()
        )
        return f"{name}:dict({inner})"
    return f"{name}:{value!r}"


def trial_params(storage: str, study_name: str, number: int) -> list[str]:
    """The ``-params`` words of trial ``number``: its values through rl-zoo3's converter."""
    import optuna
    from rl_zoo3.hyperparams_opt import HYPERPARAMS_CONVERTER

    study = optuna.load_study(study_name=study_name, storage=storage)
    (trial,) = [t for t in study.get_trials(deepcopy=False) if t.number == number]
    return [param_text(k, v) for k, v in HYPERPARAMS_CONVERTER["ppo"](trial.params).items()]


def train_command(params: list[str], seed: int, out: Path, timesteps: int, threads: int):
    """rl-zoo3's ``train.py`` training one PPO agent at its CartPole-v1 config and ``params``:
    no periodic evaluation, no log lines, on the CPU."""
    return [
        *(sys.executable, "-m", "rl_zoo3.train", "--algo", "ppo", "--env", "CartPole-v1"),
        *("--seed", str(seed), "-f", str(out), "--eval-freq", "-1", "--device", "cpu"),
        *("--num-threads", str(threads), "--verbose", "0"),
        *(["-n", str(timesteps)] if timesteps != ZOO_TIMESTEPS else []),
        "-params",
        *params,
    ]


def greedy_returns(model, episodes: int) -> list[float]:
    import gymnasium as gym

    env = gym.make("CartPole-v1")
    returns = []
    for e in range(episodes):
        obs, _ = env.reset(seed=EVAL_SEED + e)
        total, done = 0.0, False
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, reward, terminated, truncated, _ = env.step(int(action))
            total += float(reward)
            done = terminated or truncated
        returns.append(total)
    env.close()
    return returns


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--storage", required=True)
    parser.add_argument("--study-name", required=True)
    parser.add_argument("--trial", type=int, required=True)
    parser.add_argument("--seed", type=int, required=True)
    parser.add_argument("--out", type=Path, required=True, help="rl-zoo3's log folder (-f)")
    parser.add_argument("--timesteps", type=int, default=ZOO_TIMESTEPS)
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--threads", type=int, default=1, help="torch threads (--num-threads)")
    args = parser.parse_args()
    params = trial_params(args.storage, args.study_name, args.trial)
    command = train_command(params, args.seed, args.out, args.timesteps, args.threads)
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"rl_zoo3.train exit {done.returncode}: {done.stderr.strip()[-2000:]}")
    import torch
    from stable_baselines3 import PPO

    torch.set_num_threads(args.threads)
    (zip_path,) = sorted(args.out.glob("ppo/CartPole-v1_*/CartPole-v1.zip"))
    returns = greedy_returns(PPO.load(zip_path, device="cpu"), args.episodes)
    line = {
        "seed": args.seed,
        "command": command,
        "returns": returns,
        "mean": sum(returns) / len(returns),
    }
    print(json.dumps(line))


if __name__ == "__main__":
    main()

"""Stable-Baselines3 PPO trained, unchanged, on jaxcart's Gymnasium env.

Trains ``PPO("MlpPolicy", gym.make("jaxcart/CartPole-v1"))`` with SB3's defaults, then
evaluates the greedy policy on the same seeded episodes in jaxcart's env and in Gymnasium's own
``CartPole-v1`` (a seed starts the same episode in both)::

    pip install torch --index-url https://download.pytorch.org/whl/cpu
    pip install stable-baselines3
    python examples/sb3_on_jaxcart.py                 # 80,000 steps, 20 evaluation episodes
    python examples/sb3_on_jaxcart.py --timesteps 20000 --seed 1
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np

import jaxcart.gym.adapter  # registers "jaxcart/CartPole-v1"


def greedy_returns(model, env_id: str, seeds: list[int]) -> np.ndarray:
    """The return of one deterministic-policy episode per seed in ``gym.make(env_id)``."""
    env = gym.make(env_id)
    returns = []
    for seed in seeds:
        obs, _ = env.reset(seed=seed)
        total, done = 0.0, False
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, reward, terminated, truncated, _ = env.step(int(action))
            total += reward
            done = terminated or truncated
        returns.append(total)
    env.close()
    return np.array(returns)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--timesteps", type=int, default=80_000, help="training env steps")
    parser.add_argument("--seed", type=int, default=0, help="SB3 seed")
    parser.add_argument("--episodes", type=int, default=20, help="evaluation episodes per env")
    parser.add_argument("--eval-seed", type=int, default=10_000, help="first evaluation seed")
    parser.add_argument(
        "--torch-threads",
        type=int,
        default=1,
        help="torch CPU threads (SB3's 64-64 MLPs run fastest on one; more only contend)",
    )
    args = parser.parse_args(argv)

    import torch
    from stable_baselines3 import PPO

    torch.set_num_threads(args.torch_threads)

    env = gym.make(jaxcart.gym.adapter.ENV_ID)
    model = PPO("MlpPolicy", env, seed=args.seed, device="cpu", verbose=0)
    start = time.perf_counter()
    model.learn(args.timesteps)
    train_s = time.perf_counter() - start
    ep_rew_mean = np.mean([e["r"] for e in model.ep_info_buffer])
    print(
        f"SB3 PPO on {jaxcart.gym.adapter.ENV_ID}: {model.num_timesteps:,} steps in "
        f"{train_s:.1f} s ({model.num_timesteps / train_s:,.0f} steps/s), "
        f"final rollout/ep_rew_mean {ep_rew_mean:.1f}"
    )

    seeds = list(range(args.eval_seed, args.eval_seed + args.episodes))
    results = {
        env_id: greedy_returns(model, env_id, seeds)
        for env_id in (jaxcart.gym.adapter.ENV_ID, "CartPole-v1")
    }
    print(f"\nGreedy evaluation, {args.episodes} seeded episodes per env:")
    print(f"{'env':<22} {'mean':>7} {'min':>5} {'solved (all 500)':>17}")
    for env_id, returns in results.items():
        solved = "yes" if np.all(returns == 500) else "no"
        print(f"{env_id:<22} {returns.mean():>7.1f} {returns.min():>5.0f} {solved:>17}")
    same = int(np.sum(results[jaxcart.gym.adapter.ENV_ID] == results["CartPole-v1"]))
    print(f"episodes with identical returns in both envs: {same}/{args.episodes}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

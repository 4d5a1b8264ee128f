"""Whole-episode parity with Gymnasium in x64 (imported by the tests, also run as a script).

Run as a script it checks long (500-step) balanced episodes for bit-identity. That needs XLA
to round like NumPy: on CPU, XLA contracts ``a * b + c`` into fused multiply-adds, which round
once instead of twice; ``XLA_FLAGS=--xla_cpu_max_isa=AVX`` (no FMA instructions) makes every
step of jaxcart's x64 CartPole bit-identical to Gymnasium's. Without it each step still agrees
to ~1 ulp, but over hundreds of steps an unstable pendulum driven open-loop amplifies that.
"""

from __future__ import annotations

import sys

import gymnasium as gym
import jax
import numpy as np

from jaxcart.core import cartpole


def balancing_action(obs: np.ndarray) -> int:
    """A hand-written controller that keeps the pole up for the whole 500 steps."""
    return int(obs[2] + 0.5 * obs[3] > 0)


def run_episodes(integrator: str, policy: str, episodes: int, seed: int = 0):
    """Steps Gymnasium's CartPole-v1 and jaxcart (x64) side by side with the same actions.

    Returns:
        ``(max_abs_diff, lengths, mismatched_steps)``: the largest state difference over all
        steps, each episode's length, and the number of steps whose (terminated, truncated,
        reward) differed.
    """
    rng = np.random.default_rng(seed)
    params = cartpole.EnvParams(kinematics_integrator=integrator)
    worst, lengths, mismatched = 0.0, [], 0
    with jax.enable_x64(True):
        step = jax.jit(cartpole.step_env)  # params traced, as in training
        for episode in range(episodes):
            env = gym.make("CartPole-v1")
            env.unwrapped.kinematics_integrator = integrator
            g_obs, _ = env.reset(seed=seed + episode)
            state = cartpole.state_from_obs(env.unwrapped.state)
            for t in range(1, 501):
                a = int(rng.integers(0, 2)) if policy == "random" else balancing_action(g_obs)
                g_obs, g_r, g_term, g_trunc, _ = env.step(a)
                _, state, r, term, trunc = step(state, a, params)
                diff = np.abs(np.asarray(cartpole.get_obs(state)) - env.unwrapped.state).max()
                worst = max(worst, float(diff))
                mismatched += (bool(term), bool(trunc), float(r)) != (g_term, g_trunc, g_r)
                if g_term or g_trunc:
                    break
            lengths.append(t)
    return worst, lengths, mismatched


def main() -> int:
    for integrator in ("euler", "semi-implicit"):
        worst, lengths, mismatched = run_episodes(integrator, "balancing", episodes=3)
        print(
            f"{integrator}: max |diff| {worst:.3g}, lengths {lengths}, flag mismatches {mismatched}"
        )
        if worst != 0.0 or mismatched or lengths != [500, 500, 500]:
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

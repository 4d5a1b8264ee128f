"""End to end: several seeds of the ``fast`` preset solve CartPole in Gymnasium's own env
(the preset keeps each seed's best policy: those are the policies checked)."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest

import jaxcart
from jaxcart.train import main


@pytest.mark.slow
def test_fast_preset_solves_cartpole_in_gymnasium(tmp_path, capsys):
    out = tmp_path / "fast"
    assert (
        main(
            [
                "--preset",
                "fast",
                "--num-seeds",
                "4",
                "--seed",
                "0",
                "--quiet",
                "--no-compile-cache",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    text = capsys.readouterr().out
    assert "(best policies 4/4)" in text, text
    evaluation = json.loads((out / "evaluation.json").read_text())
    assert evaluation["best_solved_seeds"] == 4
    for seed in evaluation["seeds"]:
        assert seed["best"]["gymnasium_returns"] == [500.0] * 20

    # and independently of jaxcart's evaluation code: a plain Gymnasium loop with load_policy
    for seed_index in range(4):
        policy = jaxcart.load_policy(out, seed_index, policy="best")
        env = gym.make("CartPole-v1")
        returns = []
        for episode in range(5):
            obs, _ = env.reset(seed=123 + episode)
            total, done = 0.0, False
            while not done:
                obs, reward, terminated, truncated, _ = env.step(policy(obs))
                total += reward
                done = terminated or truncated
            returns.append(total)
        assert np.all(np.array(returns) == 500.0), (seed_index, returns)

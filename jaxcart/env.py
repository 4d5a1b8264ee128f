"""``python -m jaxcart.env``: CartPole-v1's spaces, thresholds, reward and limits, as jaxcart
implements them (:mod:`jaxcart.core.cartpole`)."""

from __future__ import annotations

import math

from jaxcart import cli
from jaxcart.core.cartpole import EnvParams, action_space, float_dtype, observation_space


def describe(params: EnvParams | None = None) -> str:
    """Human-readable summary of spaces, thresholds and limits (``python -m jaxcart.env``)."""
    p = params or EnvParams()
    obs_space = observation_space(p)
    names = ["cart position x", "cart velocity x_dot", "pole angle theta", "pole ang. vel."]
    reward = "+1 every step, terminating step included"
    if p.sutton_barto_reward:
        reward = "Sutton-Barto (0, -1 on failure)"
    physics = ("gravity", "masscart", "masspole", "length", "force_mag", "tau")
    lines = [
        "jaxcart CartPole-v1 (numerically matches gymnasium.make('CartPole-v1'))",
        "",
        f"observation space: {obs_space}",
        *(
            f"  [{i}] {name:<22} low {obs_space.low[i]: .4f}  high {obs_space.high[i]: .4f}"
            for i, name in enumerate(names)
        ),
        f"action space:      {action_space(p)}  (0 = push left, 1 = push right)",
        "",
        f"termination: |x| > {p.x_threshold} or |theta| > {p.theta_threshold_radians:.6f} rad "
        f"({math.degrees(p.theta_threshold_radians):.1f} degrees)",
        f"truncation:  after {p.max_episode_steps} steps (TimeLimit)",
        f"reward:      {reward}",
        f"reset:       each state variable uniform in [{p.reset_low}, {p.reset_high})",
        "",
        "physics: "
        + ", ".join(f"{k}={getattr(p, k)}" for k in physics)
        + f", kinematics_integrator={p.kinematics_integrator!r}",
        f"float dtype: {float_dtype()} (float64 when jax_enable_x64 is on)",
    ]
    return "\n".join(lines)


@cli.command()
def main(argv: list[str] | None = None) -> int:
    """Prints :func:`describe` for the default parameters, or with the integrator and reward
    given: a command like every other (:class:`jaxcart.cli.Parser`, one-line errors)."""
    parser = cli.Parser(
        prog="python -m jaxcart.env", description="Show CartPole's spaces, bounds and limits."
    )
    parser.add_argument(
        "--kinematics-integrator", choices=["euler", "semi-implicit"], default="euler"
    )
    parser.add_argument("--sutton-barto-reward", action="store_true")
    print(describe(EnvParams(**vars(parser.parse_args(argv)))))  # the two fields, by name
    return 0


if __name__ == "__main__":
    cli.command_main(main)

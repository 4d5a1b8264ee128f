"""What train_speed and its contender modules share: run lengths, contender names and
groups, the env each group trains and is evaluated on, the peers' published configurations,
and the child-side set-up common to the JAX contenders.

Imports nothing heavy: the child process sets JAX's device count before importing JAX.
"""

from __future__ import annotations

SB3_TIMESTEPS = 80_000
# Per seed, with --quick (whole iterations of each configuration; nothing gets solved).
QUICK_TIMESTEPS = {
    "sb3": 4096,
    "fast": 1024,
    "purejaxrl": 1024,
    "zoo": 2048,
    "cartpole": 1000,
    "acrobot": 1024,  # jaxcart's `acrobot` preset: one iteration of 16 envs x 64 steps
    "acrobot-rejax": 1000,  # rejax's Acrobot config: two iterations of 5 envs x 100 steps
}
EVAL_EPISODES = 20
DEFAULT_ENV = "CartPole-v1"

# rl-zoo3's tuned PPO for CartPole-v1 (DLR-RM/rl-baselines3-zoo, hyperparams/ppo.yml, the
# "# Tuned" CartPole-v1 entry). "lin_X" there is rl_zoo3.utils.linear_schedule(X): X times
# SB3's progress_remaining (1 at the start, 0 at the end). SB3 and sbx both run it.
ZOO_CARTPOLE = {
    "n_envs": 8,
    "n_timesteps": 100_000,
    "n_steps": 32,
    "batch_size": 256,
    "gae_lambda": 0.8,
    "gamma": 0.98,
    "n_epochs": 20,
    "ent_coef": 0.0,
    "learning_rate": "lin_1e-3",
    "clip_range": "lin_0.2",
}
ZOO_SOURCE = "rl-baselines3-zoo hyperparams/ppo.yml, CartPole-v1 (tuned)"

# Contender groups, in table order: "kind-config"; a contender is a group and a seed count,
# "kind-config-xS". Two names predate the groups: "sb3" (SB3's defaults, one seed, torch's
# default thread count) and "sb3-1thread" (the same with one torch thread).
GROUPS = (
    "sb3-default",
    "sb3-1thread",
    "sb3-zoo",
    "sbx-default",
    "sbx-zoo",
    "jaxcart-sb3",
    "jaxcart-fast",
    "jaxcart-purejaxrl",
    "rejax-sb3",
    "rejax-cartpole",
    "jaxcart-acrobot",
    "rejax-acrobot",
)
# Groups on another env than CartPole-v1 (trained there and evaluated in Gymnasium's env of
# the same id); every other group is CartPole-v1's.
TIME_TO_SOLVE_STEM = "time_to_solve"  # --time-to-solve's report (train_speed.* left as they are)
ENV_IDS = {"jaxcart-acrobot": "Acrobot-v1", "rejax-acrobot": "Acrobot-v1"}
# Groups that run only when asked for by name (``--only jaxcart-acrobot``, ``--seeds-for
# rejax-acrobot=64``), so the CartPole tables and ``--only jaxcart`` stay as they were.
OPT_IN_GROUPS = tuple(ENV_IDS)
# One-seed trainings run as separate processes, one per core, for S > 1 seeds (slow: SB3 at
# its defaults takes about 25 minutes for 64 seeds on 2 cores).
PROCESS_KINDS = ("sb3", "sbx")
# What each group runs, for the reports: (tool, configuration).
DESCRIPTIONS = {
    "sb3-default": ("SB3 (PyTorch)", "SB3 defaults, 80k steps"),
    "sb3-1thread": ("SB3 (PyTorch)", "SB3 defaults, 80k steps, 1 torch thread"),
    "sb3-zoo": ("SB3 (PyTorch)", "rl-zoo3 tuned: 8 envs, 100k steps, 1 torch thread"),
    "sbx-default": ("sbx (SB3's JAX port)", "sbx defaults, 80k steps"),
    "sbx-zoo": ("sbx (SB3's JAX port)", "rl-zoo3 tuned (SB3's): 8 envs, 100k steps"),
    "jaxcart-sb3": ("jaxcart", "`sb3` preset (SB3's defaults), 80k steps"),
    "jaxcart-fast": ("jaxcart", "`fast` preset, 100k steps, each seed's best policy kept"),
    "jaxcart-purejaxrl": (
        "jaxcart running PureJaxRL's configuration",
        "`purejaxrl` preset (PureJaxRL's CartPole hyperparameters), 500k steps",
    ),
    "rejax-sb3": ("rejax", "SB3's hyperparameters, 80k steps"),
    "rejax-cartpole": (
        "rejax",
        "rejax's CartPole config (configs/gymnax/cartpole.yaml), 100k steps",
    ),
    "jaxcart-acrobot": ("jaxcart", "Acrobot-v1: `acrobot` preset, 153,600 steps"),
    "rejax-acrobot": (
        "rejax",
        "Acrobot-v1: rejax's Acrobot config (configs/gymnax/acrobot.yaml), 100k steps",
    ),
}


class ChildUnavailable(Exception):
    """The contender's packages are missing in this interpreter."""


def env_of(name: str) -> str:
    """The Gymnasium id of the env contender ``name`` (or group) trains and is evaluated on."""
    group = name if name in GROUPS else group_of(name)
    return ENV_IDS.get(group, DEFAULT_ENV)


def opt_in_groups_named(only: list[str]) -> list[str]:
    """The opt-in groups that ``--only``'s words name: the group itself or one of its
    contenders (``rejax-acrobot``, ``rejax-acrobot-x64``), not a prefix (``rejax``)."""
    return [g for g in OPT_IN_GROUPS if any(w == g or w.startswith(g + "-") for w in only)]


def name_of(group: str, seeds: int) -> str:
    """``("jaxcart-fast", 8)`` -> ``"jaxcart-fast-x8"``; SB3's defaults with one seed keep
    their old name ``"sb3"``, and ``"sb3-1thread"`` is one seed only."""
    if group == "sb3-default" and seeds == 1:
        return "sb3"
    if group == "sb3-1thread":
        if seeds != 1:
            raise ValueError("sb3-1thread trains one seed; use sb3-default for more")
        return group
    return f"{group}-x{seeds}"


def contender_names(seeds_by_group: dict[str, list[int]]) -> list[str]:
    """Every contender of ``seeds_by_group`` (group -> seed counts), in table order."""
    return [
        name_of(group, s) for group in GROUPS for s in sorted(set(seeds_by_group.get(group, ())))
    ]


def default_groups(seeds: list[int], fast_seeds: list[int]) -> dict[str, list[int]]:
    """The training-speed table's contenders: SB3 (both thread settings), jaxcart's ``sb3``
    preset and rejax at SB3's settings at ``seeds``, the ``fast`` preset at ``fast_seeds``."""
    return {
        "sb3-default": [1],
        "sb3-1thread": [1],
        "jaxcart-sb3": seeds,
        "jaxcart-fast": fast_seeds,
        "rejax-sb3": seeds,
    }


def time_to_solve_groups(seeds: list[int], slow: bool) -> dict[str, list[int]]:
    """The time-to-solve table's contenders: every CartPole group at ``seeds``; SB3 and sbx (one
    process per seed) above one seed only when ``slow``. SB3's one-seed rows always run: they
    are the table's reference."""
    groups = {}
    for group in GROUPS:
        if group in OPT_IN_GROUPS:
            continue
        if group in ("sb3-default", "sb3-1thread"):
            counts = {1} | (set(seeds) if slow and group == "sb3-default" else set())
        elif group.split("-")[0] in PROCESS_KINDS and not slow:
            counts = {s for s in seeds if s == 1}
        else:
            counts = set(seeds)
        groups[group] = sorted(counts)
    return groups


def parse_name(name: str) -> tuple[str, str, int]:
    """``"jaxcart-sb3-x8"`` -> ``("jaxcart", "sb3", 8)``; ``"sb3"`` -> ``("sb3", "default", 1)``,
    ``"sb3-1thread"`` -> ``("sb3", "1thread", 1)``."""
    if name in ("sb3", "sb3-1thread"):
        return "sb3", name.removeprefix("sb3").removeprefix("-") or "default", 1
    kind, preset, seeds = name.split("-")
    return kind, preset, int(seeds.removeprefix("x"))


def group_of(name: str) -> str:
    kind, preset, _ = parse_name(name)
    return f"{kind}-{preset}"


def label(name: str) -> str:
    kind, preset, seeds = parse_name(name)
    if name == "sb3" or name == "sb3-1thread":
        threads = "1 torch thread" if preset == "1thread" else "default torch threads"
        return f"SB3 PPO ({threads})"
    if kind == "sb3":
        return f"SB3 PPO {preset} x{seeds}"
    return f"{kind} {preset} x{seeds}"


def configure_jax_cache(cache_dir: str | None) -> None:
    """Persistent compilation cache off (cold compile), or on in ``cache_dir``."""
    import jax

    if cache_dir:
        jax.config.update("jax_enable_compilation_cache", True)
        jax.config.update("jax_compilation_cache_dir", cache_dir)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    else:
        jax.config.update("jax_enable_compilation_cache", False)

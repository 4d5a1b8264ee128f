"""What train_speed.py and its contender modules share: run lengths, contender names, and the
child-side set-up common to the JAX contenders.

Imports nothing heavy: the child process sets JAX's device count before importing JAX.
"""

from __future__ import annotations

SB3_TIMESTEPS = 80_000
QUICK_TIMESTEPS = {"sb3": 4096, "fast": 1024}
EVAL_EPISODES = 20


class ChildUnavailable(Exception):
    """The contender's packages are missing in this interpreter."""


def contender_names(seeds: list[int], fast_seeds: list[int]) -> list[str]:
    """Every contender, in table order."""
    names = ["sb3", "sb3-1thread"]
    names += [f"jaxcart-sb3-x{s}" for s in seeds]
    names += [f"jaxcart-fast-x{s}" for s in fast_seeds]
    names += [f"rejax-sb3-x{s}" for s in seeds]
    return names


def parse_name(name: str) -> tuple[str, str, int]:
    """``"jaxcart-sb3-x8"`` -> ``("jaxcart", "sb3", 8)``; ``"sb3"`` -> ``("sb3", "default", 1)``,
    ``"sb3-1thread"`` -> ``("sb3", "1thread", 1)``."""
    if name.startswith("sb3"):
        return "sb3", name.removeprefix("sb3").removeprefix("-") or "default", 1
    kind, preset, seeds = name.split("-")
    return kind, preset, int(seeds.removeprefix("x"))


def label(name: str) -> str:
    kind, preset, seeds = parse_name(name)
    if kind == "sb3":
        threads = "1 torch thread" if preset == "1thread" else "default torch threads"
        return f"SB3 PPO ({threads})"
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

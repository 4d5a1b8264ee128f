"""train_speed's jaxcart contenders (``jaxcart-PRESET-xS``): S seeds of a jaxcart preset
trained together in one compiled program, sharded over the CPU devices, on the preset's env
(``acrobot``: gymnax's Acrobot-v1, as ``python -m jaxcart.train --env Acrobot-v1 --preset
acrobot`` trains it)."""

from __future__ import annotations

import time

from benchmarks.train_speed.common import QUICK_TIMESTEPS, configure_jax_cache


def run(
    preset_name: str,
    num_seeds: int,
    quick: bool,
    cache_dir: str | None,
    timesteps: int | None = None,
):
    """``jaxcart.engine.loop.train(preset(preset_name), num_seeds, seed=0)``, for
    ``timesteps`` env steps per seed when given (the preset's otherwise).

    Returns:
        ``(data, policy)``: the timings and settings, and the seeds' stacked greedy policy
        for the harness to evaluate.
    """
    from jaxcart.engine import devices

    devices.use_all_host_cores()
    import jax

    configure_jax_cache(cache_dir)
    from jaxcart.core.config import preset
    from jaxcart.engine.loop import train
    from jaxcart.rundir.policy import make_policy

    overrides = {"total_timesteps": QUICK_TIMESTEPS[preset_name]} if quick else {}
    if timesteps:
        overrides = {"total_timesteps": timesteps}
    config = preset(preset_name, **overrides)
    marks = {}

    def on_compiled(seconds: float) -> None:
        marks["compiled_cpu"] = time.process_time()

    t0 = time.perf_counter()
    result = train(config, num_runs=num_seeds, seed=0, on_compiled=on_compiled)
    t1, c1 = time.perf_counter(), time.process_time()
    # a preset that keeps each seed's best policy (keep_best) hands that one to the user
    # (params_best.npz, `evaluate --policy best`): it is the one judged
    kept = result.state.runners.best if config.keep_best else None
    params = jax.device_get(result.params if kept is None else kept.params)
    data = {
        "num_seeds": num_seeds,
        "env_steps": int(result.env_steps),
        "setup_seconds": (t1 - t0) - result.run_seconds,
        "compile_seconds": result.compile_seconds,
        "train_seconds": result.run_seconds,
        "train_cpu_seconds": c1 - marks["compiled_cpu"],
        "jax_devices": [str(d) for d in jax.devices()],
        "devices_used": result.num_devices,
        "config": config.to_dict(),
        "policy": "best" if config.keep_best else "final",
    }
    # make_policy: the NumPy actor, taking the observations of config.env (6 for Acrobot)
    return data, make_policy(params, config, stacked=True)

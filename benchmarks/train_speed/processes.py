"""What train_speed's SB3 and sbx contenders share: the two configurations built through
SB3's API (which sbx keeps), S one-seed trainings as parallel processes (one per core) inside
the contender's own process, and the seeds' greedy policies rebuilt from their weights so the
harness's one evaluator plays them all.

Child side only; imports nothing heavy at module level (the worker processes start with
``spawn`` and import the tool themselves).
"""

from __future__ import annotations

import multiprocessing
import os
import resource
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from itertools import repeat

import numpy as np

from benchmarks.train_speed.common import QUICK_TIMESTEPS, SB3_TIMESTEPS, ZOO_CARTPOLE

# Arguments of PPO(...) taken from the rl-zoo3 entry as they are; the schedules and the env
# count are translated in zoo_kwargs.
ZOO_PLAIN_KEYS = ("n_steps", "batch_size", "gae_lambda", "gamma", "n_epochs", "ent_coef")
CHECK_OBSERVATIONS = 512


def cores() -> int:
    return len(os.sched_getaffinity(0))


def linear_schedule(initial: float) -> Callable[[float], float]:
    """rl-zoo3's ``lin_X``: ``X * progress_remaining`` (1 at the start of training, 0 at the end)."""
    return lambda progress_remaining: progress_remaining * initial


def zoo_value(value):
    """A value of rl-zoo3's yml: ``"lin_1e-3"`` becomes a linear schedule from 1e-3."""
    if isinstance(value, str) and value.startswith("lin_"):
        return linear_schedule(float(value.removeprefix("lin_")))
    return value


def make_model(ppo_cls, config_name: str, seed: int, quick: bool, **extra):
    """``ppo_cls`` (SB3's or sbx's PPO) on CartPole-v1 at its defaults (``"default"``) or at
    rl-zoo3's tuned settings (``"zoo"``), as rl-zoo3 builds it: ``make_vec_env`` with n_envs
    envs and the seed.

    Returns:
        ``(model, timesteps to learn)``.
    """
    if config_name == "default":
        timesteps = QUICK_TIMESTEPS["sb3"] if quick else SB3_TIMESTEPS
        return ppo_cls("MlpPolicy", "CartPole-v1", seed=seed, **extra), timesteps
    if config_name != "zoo":
        raise ValueError(f"unknown configuration {config_name!r}")
    from stable_baselines3.common.env_util import make_vec_env

    env = make_vec_env("CartPole-v1", n_envs=ZOO_CARTPOLE["n_envs"], seed=seed)
    kwargs = {key: ZOO_CARTPOLE[key] for key in ZOO_PLAIN_KEYS}
    kwargs["learning_rate"] = zoo_value(ZOO_CARTPOLE["learning_rate"])
    kwargs["clip_range"] = zoo_value(ZOO_CARTPOLE["clip_range"])
    timesteps = QUICK_TIMESTEPS["zoo"] if quick else ZOO_CARTPOLE["n_timesteps"]
    return ppo_cls("MlpPolicy", env, seed=seed, **kwargs, **extra), timesteps


def hyperparameters(model, config_name: str, timesteps: int) -> dict:
    """The settings a model trains with, for the report (schedules as rl-zoo3 writes them)."""
    keys = ("n_envs", "n_steps", "batch_size", "n_epochs", "gamma", "gae_lambda", "ent_coef")
    out = {key: getattr(model, key) for key in keys}
    out["total_timesteps"] = timesteps
    for key in ("learning_rate", "clip_range"):
        value = getattr(model, key)  # SB3 turns clip_range into a constant schedule
        constant = value(1.0) if callable(value) else value
        out[key] = ZOO_CARTPOLE[key] if config_name == "zoo" else float(constant)
    return out


def timed_learn(model, timesteps: int) -> tuple[float, float]:
    """``model.learn(timesteps)``; returns its wall and CPU seconds."""
    t0, c0 = time.perf_counter(), time.process_time()
    model.learn(timesteps)
    return time.perf_counter() - t0, time.process_time() - c0


def check_policy(actor: dict, predict: Callable[[np.ndarray], np.ndarray]) -> float:
    """Checks that the weights taken out of a model act as the model does: the greedy actions
    of ``actor`` (jaxcart's NumPy forward pass) against ``predict`` (the tool's own
    deterministic ``predict``) on random CartPole states. Returns the fraction that agree."""
    from jaxcart.rundir.policy import Policy

    scale = np.array([2.4, 3.0, 0.21, 3.0], np.float32)
    obs = np.random.default_rng(0).uniform(-1, 1, (CHECK_OBSERVATIONS, 4)).astype(np.float32)
    obs *= scale
    ours = Policy(actor, activation="tanh")(obs)
    agree = float(np.mean(ours == np.asarray(predict(obs)).reshape(-1)))
    if agree < 0.99:  # an exact tie in the logits may break either way; nothing else may
        raise RuntimeError(f"extracted policy agrees with the model on only {agree:.1%} of states")
    return agree


def train_model(
    ppo_cls, config_name: str, seed: int, quick: bool, actor_layers, info: dict
) -> dict:
    """One seed with ``ppo_cls`` (SB3's or sbx's PPO): builds the model (timed), trains it
    (timed), and returns :func:`worker_result` with ``info`` and the model's settings;
    ``actor_layers(model)`` takes the actor's weights out as jaxcart's layers."""
    t0 = time.perf_counter()
    model, timesteps = make_model(ppo_cls, config_name, seed, quick, device="cpu")
    setup = time.perf_counter() - t0
    train, train_cpu = timed_learn(model, timesteps)
    info = {**info, "hyperparameters": hyperparameters(model, config_name, timesteps)}
    return worker_result(model, actor_layers(model), (setup, train, train_cpu), info)


def worker_result(model, actor: dict, seconds: tuple[float, float, float], info: dict) -> dict:
    """What one seed's training returns: its weights, steps, timings, memory and ``info``
    (settings for the report)."""
    setup, train, train_cpu = seconds
    agree = check_policy(actor, lambda obs: model.predict(obs, deterministic=True)[0])
    return {
        "actor": actor,
        "env_steps": int(model.num_timesteps),
        "setup_seconds": setup,
        "train_seconds": train,
        "train_cpu_seconds": train_cpu,
        "policy_check_agreement": agree,
        "pid": os.getpid(),
        "max_rss_kib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss,
        "info": info,
    }


def stacked_policy(actors: list[dict]):
    """One stacked :class:`jaxcart.rundir.policy.Policy` (NumPy) over the seeds' actors."""
    from jaxcart.rundir.policy import Policy

    stacked = {
        name: {k: np.stack([a[name][k] for a in actors]) for k in ("kernel", "bias")}
        for name in actors[0]
    }
    return Policy(stacked, activation="tanh", stacked=True)


def cpu_seconds_with_children() -> float:
    """CPU time of this process and of its children that have been waited for."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def in_processes(worker: Callable, config_name: str, num_seeds: int, quick: bool, cache_dir):
    """Seeds 0 ... S-1 of ``worker`` in a pool of one ``spawn``-ed process per core, each
    limited to one thread. Returns the per-seed results and the pool's measurements."""
    jobs = min(num_seeds, cores())
    start, cpu = time.perf_counter(), cpu_seconds_with_children()
    context = multiprocessing.get_context("spawn")
    args = (repeat(config_name), range(num_seeds), repeat(quick), repeat(cache_dir), repeat(1))
    with ProcessPoolExecutor(jobs, mp_context=context) as pool:
        results = list(pool.map(worker, *args))
    # The pool has joined its workers here, so their CPU time is in RUSAGE_CHILDREN.
    wall, cpu = time.perf_counter() - start, cpu_seconds_with_children() - cpu
    peaks = {}
    for r in results:
        peaks[r["pid"]] = max(peaks.get(r["pid"], 0), r["max_rss_kib"])
    own_peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    pool_data = {
        # Every seed's set-up happens inside the pool: it is all "train" here.
        "setup_seconds": 0.0,
        "train_seconds": wall,
        "train_cpu_seconds": cpu,
        "jobs": jobs,
        "processes_peak_rss_mib": (own_peak + sum(peaks.values())) / 1024,
    }
    return results, pool_data


def run_seeds(
    worker: Callable, config_name: str, num_seeds: int, quick: bool, cache_dir, threads
) -> tuple[dict, object]:
    """``num_seeds`` one-seed trainings by ``worker(config_name, seed, quick, cache_dir,
    threads)``: in this process for one seed (with ``threads``, None = the tool's default),
    else in parallel processes (:func:`in_processes`).

    Returns:
        ``(data, policy)``: the timings and settings, and the seeds' stacked greedy policy
        for the harness to evaluate.
    """
    if num_seeds == 1:
        results = [worker(config_name, 0, quick, cache_dir, threads)]
        keys = ("setup_seconds", "train_seconds", "train_cpu_seconds")
        data = {key: results[0][key] for key in keys} | {"jobs": 1}
    else:
        results, data = in_processes(worker, config_name, num_seeds, quick, cache_dir)
    data.update(
        num_seeds=num_seeds,
        env_steps=sum(r["env_steps"] for r in results),
        per_seed_setup_seconds=[r["setup_seconds"] for r in results],
        per_seed_train_seconds=[r["train_seconds"] for r in results],
        policy_check_agreement=min(r["policy_check_agreement"] for r in results),
    )
    data.update(results[0]["info"])
    return data, stacked_policy([r["actor"] for r in results])

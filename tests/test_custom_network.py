"""Your own network: a flax actor-critic passed as ``PPOConfig(network=...)`` trains, is
recorded in its run directory, and is rebuilt by a fresh process; the compiled-program cache
tells networks apart."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest
from custom_networks import GeluLayerNorm, ReluMLP
from helpers import TINY, assert_same_run_dirs, fresh_python

from jaxcart.core.config import (
    BUILTIN_NETWORK_FIELDS,
    ConfigError,
    PPOConfig,
    RecordedNetwork,
    UntrustedCodeError,
    network_spec,
    resolve_code,
)
from jaxcart.engine import loop
from jaxcart.engine.loop import train
from jaxcart.run.lifecycle import run_new
from jaxcart.run.spec import RunOptions, RunSpec
from jaxcart.rundir.policy import Policy

TESTS = Path(__file__).resolve().parent
OBS = np.random.default_rng(3).normal(size=(16, 4)).astype(np.float32)


def test_a_network_is_recorded_by_class_and_changed_fields():
    spec = network_spec(GeluLayerNorm(width=64))
    assert spec == {"class": "custom_networks:GeluLayerNorm", "fields": {"width": 64}}
    assert RecordedNetwork.from_spec(spec).build() == GeluLayerNorm(width=64)
    assert RecordedNetwork.from_spec(spec).build(GeluLayerNorm) == GeluLayerNorm(width=64)
    config = dataclasses.replace(TINY, network=GeluLayerNorm(width=64))
    recorded = json.loads(json.dumps(config.to_dict()))
    read = PPOConfig.from_dict(recorded)
    assert isinstance(read.network, RecordedNetwork)  # read back as data: nothing imported
    assert read.to_dict() == config.to_dict()
    with pytest.raises(UntrustedCodeError, match="--trust-code"):
        resolve_code(read)
    assert resolve_code(read, network=GeluLayerNorm) == config
    assert resolve_code(read, trust_code=True) == config
    # the built-in MLP's fields describe a network the run does not use: not recorded, but a
    # config.json written before (with them) reads as ever
    assert not set(BUILTIN_NETWORK_FIELDS) & set(recorded)
    builtin = {name: TINY.to_dict()[name] for name in BUILTIN_NETWORK_FIELDS}
    older = PPOConfig.from_dict({**recorded, **builtin})
    assert resolve_code(older, network=GeluLayerNorm) == config
    assert "network" not in TINY.to_dict()  # the built-in network's config.json is unchanged
    assert set(BUILTIN_NETWORK_FIELDS) <= set(TINY.to_dict())
    with pytest.raises(ConfigError, match="cannot rebuild the run's network nowhere:Net"):
        RecordedNetwork.from_spec({"class": "nowhere:Net", "fields": {}}).build()
    with pytest.raises(ConfigError, match="network must be a flax module"):
        PPOConfig(network="mlp")


@pytest.mark.slow
def test_a_custom_network_trains_and_a_fresh_process_rebuilds_it(tmp_path):
    out = tmp_path / "gelu"
    config = dataclasses.replace(TINY, network=GeluLayerNorm(width=32))
    options = RunOptions(eval_episodes=3, compile_cache=False)
    outcome = run_new(RunSpec(config=config, num_seeds=2), out=out, options=options)
    params = jax.tree.map(lambda x: np.asarray(x)[1], outcome.result.params)
    assert "params/Dense_0/kernel" in {  # flax's own names, not the built-in MLP's
        "/".join(str(k.key) for k in path)
        for path, _ in jax.tree_util.tree_leaves_with_path(params)
    }
    expected = np.asarray(GeluLayerNorm(width=32).apply(params, OBS)[0]).argmax(-1)
    trained = json.loads((out / "evaluation.json").read_text())
    code = (
        "import json, sys, numpy as np, jaxcart\n"
        f"policy = jaxcart.load_policy({str(out)!r}, seed_index=1, trust_code=True)\n"
        "assert policy.network is not None  # through JAX\n"
        f"obs = np.random.default_rng(3).normal(size=(16, 4)).astype(np.float32)\n"
        "print(json.dumps(policy(obs).tolist()))\n"
        "from jaxcart.run.greedy import evaluate_params\n"
        "from jaxcart.rundir.policy import run_params\n"
        f"returns = evaluate_params(run_params({str(out)!r}, trust_code=True), 3)\n"
        "print(json.dumps(returns.tolist()))\n"
    )
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "PYTHONPATH": str(TESTS)}
    actions, returns = fresh_python(code, env).splitlines()
    assert json.loads(actions) == expected.tolist()
    assert json.loads(returns) == [seed["gymnasium_returns"] for seed in trained["seeds"]]

    # where the network's module cannot be imported, the readers say so in one line, and how
    # to reach it: the run directory itself is sound
    unreachable = {**env, "PYTHONPATH": str(TESTS.parent)}  # jaxcart, not tests/
    done = subprocess.run(
        [sys.executable, "-m", "jaxcart.evaluate", str(out), "--episodes", "1", "--trust-code"],
        env=unreachable,
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2, done.stderr
    (line,) = done.stderr.strip().splitlines()
    assert "cannot rebuild the run's network custom_networks:GeluLayerNorm" in line
    assert "ModuleNotFoundError" in line and "PYTHONPATH" in line
    assert "corrupted" not in line


@pytest.mark.slow
def test_two_networks_in_one_process_get_their_own_programs():
    """Training one network, then another of the same config shapes, compiles the second's
    own program: its results equal those of training it first in a clean process state."""
    gelu = dataclasses.replace(TINY, network=GeluLayerNorm(width=32, depth=1))
    relu = dataclasses.replace(TINY, network=ReluMLP(width=32))
    first = train(gelu, 2, seed=4, chunk_size=8)
    second = train(relu, 2, seed=4, chunk_size=8)
    assert second.compiled
    loop._COMPILED.clear()
    jax.clear_caches()
    alone = train(relu, 2, seed=4, chunk_size=8)
    assert set(jax.tree.leaves(jax.tree.map(np.shape, first.params))) != set(
        jax.tree.leaves(jax.tree.map(np.shape, second.params))
    ) or not np.array_equal(first.metrics["train/value_loss"], second.metrics["train/value_loss"])
    for name in ("train/value_loss", "rollout/ep_rew_mean"):
        np.testing.assert_array_equal(second.metrics[name], alone.metrics[name])
    for a, b in zip(jax.tree.leaves(second.params), jax.tree.leaves(alone.params)):
        np.testing.assert_array_equal(a, b)


@pytest.mark.slow
def test_the_policy_of_a_custom_network_is_its_logits_argmax():
    network = ReluMLP(width=8)
    params = network.init(jax.random.PRNGKey(0), OBS[:1])
    policy = Policy(params, network)
    np.testing.assert_array_equal(policy(OBS), np.asarray(network.apply(params, OBS)[0]).argmax(-1))
    assert policy(OBS[0]) in (0, 1)


@pytest.mark.slow
def test_a_stopped_run_of_a_custom_network_resumes_bit_identically(tmp_path):
    """Resume rebuilds the network from config.json and finishes as an uninterrupted run."""
    from helpers import stopped_run

    from jaxcart.run.lifecycle import resume_run

    config = dataclasses.replace(TINY, network=ReluMLP(width=16))
    options = RunOptions(eval_episodes=2, compile_cache=False, chunk_size=4)
    spec = RunSpec(config=config, num_seeds=2)
    run_new(spec, out=tmp_path / "whole", options=options)
    run, _ = stopped_run(spec, tmp_path / "part", options, chunks=2)
    run.close()
    with pytest.raises(UntrustedCodeError):  # the run's code runs only when asked
        resume_run(tmp_path / "part", options)
    resumed = resume_run(tmp_path / "part", options, network=ReluMLP)
    assert resumed.run.config.network == ReluMLP(width=16) and resumed.run.resumed_from == 8
    assert_same_run_dirs(tmp_path / "whole", tmp_path / "part")

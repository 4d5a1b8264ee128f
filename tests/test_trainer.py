"""The training engine: resume bit-identity, traced hyperparameters compile once, the
divergence guard, chunking, run r's seed index, and the update in groups of runs."""

from __future__ import annotations

import dataclasses
import functools

import jax
import numpy as np
import pytest
from helpers import TINY, assert_same_results

from jaxcart.core.cartpole import EnvParams
from jaxcart.core.config import TRACED_FIELDS, PPOConfig
from jaxcart.core.ppo import prepare_update
from jaxcart.engine.chunk import group_layout, train_chunk
from jaxcart.engine.loop import (
    compiled_chunk,
    init_runners,
    initial_state,
    train,
)
from jaxcart.rundir.directory import save_checkpoint
from jaxcart.rundir.reader import load_checkpoint


@pytest.mark.slow
def test_resume_from_checkpoint_is_bit_identical(tmp_path):
    full = train(TINY, num_runs=2, seed=3, chunk_size=2)
    assert not full.stopped and full.state.iteration == TINY.num_iterations == 32

    chunks = []
    part = train(
        TINY,
        num_runs=2,
        seed=3,
        chunk_size=2,
        on_chunk=chunks.append,
        should_stop=lambda: len(chunks) == 5,
    )
    assert part.stopped and part.state.iteration == 10

    path = tmp_path / "checkpoint.npz"
    save_checkpoint(path, part.state, {"note": "test"})
    resumed_state = load_checkpoint(path, initial_state(TINY, 2, 3, chunk_size=2))
    assert resumed_state.iteration == 10 and resumed_state.chunk_size == 2
    resumed = train(TINY, num_runs=2, seed=3, resume=resumed_state)
    assert resumed.state.iteration == 32 and not resumed.stopped
    # the checkpoint holds no metrics (a run directory streams them): the resumed state's
    # are those of iterations 11 to 32, the uninterrupted run's bit for bit
    tail = {k: v[10:] for k, v in full.metrics.items()}
    assert len(resumed.metrics["train/approx_kl"]) == 22
    assert_same_results(tail, resumed.metrics, full.params, resumed.params)


@pytest.mark.slow
def test_new_hyperparameter_values_do_not_recompile():
    """Float hyperparameters are traced: a second run with other values compiles nothing and
    the new values take effect."""
    compiles = []

    def listener(event, duration, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            compiles.append(duration)

    jax.monitoring.register_event_duration_secs_listener(listener)
    other = dataclasses.replace(
        TINY,
        learning_rate=TINY.learning_rate * 3,
        clip_coef=TINY.clip_coef * 0.5,
        ent_coef=TINY.ent_coef + 0.01,
    )
    first = train(TINY, 4, seed=1)
    mid = len(compiles)
    second = train(other, 4, seed=1)
    assert first.compiled and not second.compiled
    assert len(compiles) == mid, "new hyperparameter values triggered a compilation"
    np.testing.assert_allclose(second.metrics["train/learning_rate"][0], 3e-3, rtol=1e-6)
    assert not np.allclose(first.metrics["train/value_loss"], second.metrics["train/value_loss"])


def test_divergence_freezes_only_that_seed(tmp_path):
    """A seed whose update goes non-finite is rolled back to its state at the start of that
    chunk and marked; the other seed trains exactly as it would have, checkpoints stay finite,
    and the rolled-back seed is left untouched by later chunks."""
    bad = dataclasses.replace(TINY, learning_rate=np.array([TINY.learning_rate, 1e35]))
    good = train(TINY, 2, seed=5)
    mixed = train(bad, 2, seed=5)
    diverged = np.asarray(mixed.runners.diverged_at)
    assert diverged[0] == -1 and diverged[1] >= 1
    for leaf in jax.tree.leaves(mixed.params):
        assert np.isfinite(np.asarray(leaf)).all()
    # seed 0 is untouched by seed 1's divergence
    for x, y in zip(jax.tree.leaves(good.params), jax.tree.leaves(mixed.params)):
        np.testing.assert_array_equal(np.asarray(x)[0], np.asarray(y)[0])
    # after the divergence seed 1 reports NaN metrics
    assert np.isnan(mixed.metrics["train/value_loss"][diverged[1] :, 1]).all()
    # ... and holds the parameters it had at the start of the chunk it diverged in
    chunk = mixed.state.chunk_size
    restart = (diverged[1] - 1) // chunk * chunk  # iterations done when that chunk began
    if restart == 0:
        before = init_runners(TINY, 5, np.arange(2)).params
    else:
        shorter = dataclasses.replace(bad, total_timesteps=int(restart) * TINY.batch_size)
        before = train(shorter, 2, seed=5, chunk_size=chunk).params
    for x, y in zip(jax.tree.leaves(before), jax.tree.leaves(mixed.params)):
        np.testing.assert_array_equal(np.asarray(x)[1], np.asarray(y)[1])


@pytest.mark.slow
def test_chunks_that_do_not_tile_the_run():
    """A chunk size that does not divide the iterations: the guarded program skips the
    overhang, and the run matches the tiled one (same per-iteration computation)."""
    tiled = train(TINY, 2, seed=9, chunk_size=2)
    ragged = train(TINY, 2, seed=9, chunk_size=5)  # 32 iterations = 6 chunks of 5 + 2
    assert ragged.state.iteration == 32 and ragged.metrics["train/value_loss"].shape == (32, 2)
    assert np.isfinite(ragged.metrics["train/value_loss"]).all()
    np.testing.assert_allclose(
        ragged.metrics["train/value_loss"], tiled.metrics["train/value_loss"], rtol=1e-4
    )


@pytest.mark.slow
def test_configs_differing_only_in_traced_fields_compile_once():
    """The compiled-step cache keys on the static part of the config: a config with other
    learning rate, clip range, gamma, ... reuses the executable; a new shape does not."""
    a = dataclasses.replace(TINY, total_timesteps=2048)  # a shape no other test compiles
    b = dataclasses.replace(a, learning_rate=7e-3, clip_coef=0.3, gamma=0.9, ent_coef=0.01)
    first, second = train(a, 2, seed=0), train(b, 2, seed=0)
    assert first.compiled and not second.compiled
    np.testing.assert_allclose(second.metrics["train/learning_rate"][0], 7e-3, rtol=1e-6)
    third = train(dataclasses.replace(a, num_steps=64, total_timesteps=2048), 2, seed=0)
    assert third.compiled


@pytest.mark.slow
def test_compiled_chunk_key_ignores_traced_config_values():
    state = initial_state(TINY, 2, 0)
    runners = jax.device_put(state.runners)
    configs = jax.device_put(state.config)
    other = jax.device_put(dataclasses.replace(TINY, vf_coef=2.0).per_run(2))
    env = EnvParams()
    exe_a, _ = compiled_chunk(env, 4, runners, configs)
    exe_b, fresh = compiled_chunk(env, 4, runners, other)
    assert exe_a is exe_b and not fresh
    wider = jax.device_put(dataclasses.replace(TINY, update_epochs=3).per_run(2))
    assert compiled_chunk(env, 4, runners, wider)[0] is not exe_a  # a static field: recompiled


@pytest.mark.slow
def test_a_swept_value_reaches_the_compiled_update():
    """Two runs with other learning rates and clip ranges in one program: each run trains
    bit for bit as the same values do when every run has them, and the update's logged
    learning rate is each run's own."""
    sweep = dataclasses.replace(
        TINY, learning_rate=np.array([1e-3, 5e-3]), clip_coef=np.array([0.1, 0.3])
    )
    both = train(sweep, 2, seed=3, chunk_size=8)
    np.testing.assert_allclose(both.metrics["train/learning_rate"][0], [1e-3, 5e-3], rtol=1e-6)
    for run, (lr, clip) in enumerate([(1e-3, 0.1), (5e-3, 0.3)]):
        alone = train(
            dataclasses.replace(TINY, learning_rate=lr, clip_coef=clip), 2, 3, chunk_size=8
        )
        for name in ("train/clip_fraction", "train/value_loss"):
            np.testing.assert_array_equal(both.metrics[name][:, run], alone.metrics[name][:, run])


def test_the_program_reads_one_config_with_no_default_copy(monkeypatch):
    """While the chunk program is traced, the config each iteration reads holds tracers in
    every traced field (the values it was given), never a float left at a default."""
    from jaxcart.engine import chunk

    seen = []

    def spy(runner, config, iteration, env_params):
        seen.append({name: getattr(config, name) for name in TRACED_FIELDS})
        return prepare_update(runner, config, iteration, env_params)

    monkeypatch.setattr(chunk, "prepare_update", spy)
    state = initial_state(TINY, 2, 0)
    program = functools.partial(train_chunk, env_params=EnvParams(), chunk_size=2)
    jax.eval_shape(program, state.runners, state.config, np.int32(0))
    assert seen and all(
        isinstance(value, jax.core.Tracer) for fields in seen for value in fields.values()
    )
    assert not hasattr(PPOConfig, "static")


def test_seed_index_not_run_position_picks_the_random_stream():
    """Initial state of run r depends on its seed index only (sweeps repeat seed indices)."""
    a = initial_state(TINY, 3, 7, seed_indices=np.array([0, 1, 2]))
    b = initial_state(TINY, 2, 7, seed_indices=np.array([2, 0]))
    for x, y in zip(jax.tree.leaves(a.runners), jax.tree.leaves(b.runners)):
        np.testing.assert_array_equal(np.asarray(x)[[2, 0]], np.asarray(y))


@pytest.mark.slow
def test_runs_that_do_not_divide_over_devices_are_padded_not_squeezed():
    """3 runs on 2 devices use both (padded to 4, the padding discarded); the real runs are
    bit-identical to the first 3 of a 4-run training, which has the same per-device batch."""
    import jax as _jax

    assert len(_jax.devices()) == 2  # conftest gives the tests two CPU devices
    three = train(TINY, 3, seed=2, chunk_size=8)
    four = train(TINY, 4, seed=2, chunk_size=8)
    assert three.num_devices == 2 and three.num_runs == 3
    assert three.metrics["train/value_loss"].shape == (32, 3)
    for name in ("train/value_loss", "rollout/ep_rew_mean"):
        np.testing.assert_array_equal(three.metrics[name], four.metrics[name][:, :3])
    for x, y in zip(jax.tree.leaves(three.params), jax.tree.leaves(four.params)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y)[:3])


@pytest.mark.slow
def test_fewer_runs_than_devices_use_one_device_each():
    one = train(TINY, 1, seed=4, chunk_size=8)
    assert one.num_devices == 1 and one.metrics["train/value_loss"].shape == (32, 1)


@pytest.mark.slow
def test_update_in_groups_computes_what_one_vmap_computes():
    """The grouped update (5 runs as 3 groups of width 2, the last padded by a copy) trains
    the same runs as the plain vmap, up to rounding (XLA compiles another width)."""
    state = initial_state(TINY, 5, 6)
    runners, configs = jax.device_put(state.runners), jax.device_put(state.config)
    results = {}
    for group in (None, 2):
        chunk = functools.partial(
            train_chunk, env_params=EnvParams(), chunk_size=3, update_group=group
        )
        results[group] = jax.jit(chunk)(runners, configs, np.int32(0))
    assert group_layout(5, 2) == (3, 2) and group_layout(32, 8) == (4, 8)
    assert group_layout(10, 8) == (2, 5) and group_layout(8, 8) == (1, 8)
    (plain, plain_metrics), (grouped, grouped_metrics) = results[None], results[2]
    for name in ("train/value_loss", "train/approx_kl", "rollout/ep_rew_mean"):
        assert grouped_metrics[name].shape == (3, 5)
        np.testing.assert_allclose(grouped_metrics[name], plain_metrics[name], rtol=1e-4)
    for x, y in zip(jax.tree.leaves(plain.params), jax.tree.leaves(grouped.params)):
        np.testing.assert_allclose(np.asarray(y), np.asarray(x), rtol=1e-4, atol=1e-6)
    assert not np.array_equal(
        np.asarray(plain.params["params"]["actor"]["out"]["kernel"]),
        np.asarray(state.runners.params["params"]["actor"]["out"]["kernel"]),
    )


@pytest.mark.slow
def test_adaptive_chunks_change_no_number(monkeypatch):
    """Chunks whose length follows the wall clock (here forced to grow 1, 3, 9, ... by a
    stub) give metrics and parameters bit-identical to fixed chunks of 4, and to chunks
    of 5 that do not tile the run."""
    from jaxcart.engine import loop as trainer

    lengths = []

    def grow(capacity: int, previous: int, seconds: float, target: float) -> int:
        lengths.append(previous)
        return min(capacity, 3 * previous)

    monkeypatch.setattr(trainer, "next_chunk_length", grow)
    adaptive = train(TINY, 2, seed=11)
    assert adaptive.state.chunk_seconds and lengths[:3] == [1, 3, 9]
    for fixed in (train(TINY, 2, seed=11, chunk_size=4), train(TINY, 2, seed=11, chunk_size=5)):
        for name, values in fixed.metrics.items():
            if not name.startswith("time/"):
                np.testing.assert_array_equal(adaptive.metrics[name], values, err_msg=name)
        for a, b in zip(jax.tree.leaves(adaptive.params), jax.tree.leaves(fixed.params)):
            np.testing.assert_array_equal(a, b)


def test_default_chunk_size_is_constant_time():
    """The chunk capacity of a run of 10^15 iterations is a formula (it used to scan a range
    proportional to the run for divisors, which would not return here), and bounds the
    chunk's metrics buffer."""
    from jaxcart.core.metrics import METRIC_NAMES
    from jaxcart.engine.loop import CHUNK_METRICS_BYTES, default_chunk_size

    assert default_chunk_size(10**15) == 1024
    assert default_chunk_size(10**15, num_runs=10**6) == 1
    assert default_chunk_size(7) == 7
    chunk = default_chunk_size(10**6, num_runs=6652)
    assert 100 < chunk and chunk * 6652 * len(METRIC_NAMES) * 4 <= CHUNK_METRICS_BYTES

"""PPOConfig: SB3's defaults, presets, validation with messages, traced fields declared once."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest

from jaxcart import cli
from jaxcart.core.config import (
    PRESETS,
    STATIC_FIELDS,
    TRACED_FIELDS,
    ConfigError,
    PPOConfig,
    preset,
)


def test_sb3_defaults():
    c = PPOConfig()
    assert (c.num_envs, c.num_steps, c.minibatch_size, c.update_epochs) == (1, 2048, 64, 10)
    assert (c.learning_rate, c.adam_eps, c.gamma, c.gae_lambda, c.clip_coef) == (
        3e-4,
        1e-5,
        0.99,
        0.95,
        0.2,
    )
    assert (c.ent_coef, c.vf_coef, c.max_grad_norm) == (0.0, 0.5, 0.5)
    assert c.num_iterations == 40 and c.env_steps_per_seed == 81_920
    assert c.hidden_sizes == (64, 64) and c.activation == "tanh" and c.norm_adv and not c.anneal_lr
    assert preset("sb3") == c


def test_purejaxrl_preset():
    c = preset("purejaxrl")
    assert (c.num_envs, c.num_steps, c.update_epochs, c.num_minibatches) == (4, 128, 4, 4)
    assert (c.learning_rate, c.anneal_lr, c.ent_coef) == (2.5e-4, True, 0.01)
    # PureJaxRL: NUM_UPDATES = TOTAL_TIMESTEPS // NUM_STEPS // NUM_ENVS with 5e5 steps
    assert c.num_iterations == 500_000 // 128 // 4 == 976


def test_every_field_documented():
    docs = cli.field_docs(PPOConfig)
    for f in PPOConfig.__dataclass_fields__:
        assert docs.get(f), f"{f} has no docstring"


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"minibatch_size": 100}, "does not divide"),
        ({"learning_rate": 0.0}, "learning_rate"),
        ({"learning_rate": -1e-3}, "learning_rate"),
        ({"total_timesteps": 0}, "total_timesteps"),
        ({"gamma": 0.0}, "gamma"),
        ({"gamma": 1.5}, "gamma"),
        ({"gae_lambda": -0.1}, "gae_lambda"),
        ({"ent_coef": -0.01}, "ent_coef"),
        ({"vf_coef": -1.0}, "vf_coef"),
        ({"activation": "gelu"}, "activation"),
        ({"hidden_sizes": ()}, "hidden_sizes"),
        ({"num_envs": 2.5}, "num_envs"),
        ({"learning_rate": float("nan")}, "learning_rate"),
    ],
)
def test_config_validation(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        PPOConfig(**kwargs)


def test_unknown_preset():
    with pytest.raises(ConfigError, match="unknown preset"):
        preset("nope")
    assert set(PRESETS) == {"sb3", "purejaxrl", "fast", "acrobot"}


def test_config_is_frozen_and_round_trips():
    c = preset("purejaxrl")
    with pytest.raises(AttributeError):
        c.num_envs = 3
    assert PPOConfig.from_dict(c.to_dict()) == c
    # the schedule options at their defaults leave config.json as it was before them
    assert not {"anneal_clip", "anneal_progress"} & set(c.to_dict())
    sb3 = dataclasses.replace(c, anneal_clip=True, anneal_progress="sb3")
    assert PPOConfig.from_dict(sb3.to_dict()) == sb3


def test_traced_fields_are_declared_once_on_the_config():
    """The traced float hyperparameters come from field metadata: they are the config's pytree
    leaves, named by field; everything else is its static structure."""
    traced = [f.name for f in dataclasses.fields(PPOConfig) if f.metadata.get("traced")]
    assert list(TRACED_FIELDS) == traced
    assert set(traced) == {
        "learning_rate",
        "adam_eps",
        "gamma",
        "gae_lambda",
        "clip_coef",
        "clip_range_vf",
        "ent_coef",
        "vf_coef",
        "max_grad_norm",
    }
    config = PPOConfig(clip_coef=0.3)
    leaves = jax.tree_util.tree_flatten_with_path(config)[0]
    assert [path[0].name for path, _ in leaves] == list(TRACED_FIELDS)
    assert dict((path[0].name, v) for path, v in leaves)["clip_coef"] == 0.3
    assert set(STATIC_FIELDS) == {f.name for f in dataclasses.fields(PPOConfig)} - set(traced)
    rebuilt = jax.tree.unflatten(jax.tree.structure(config), [0.5] * len(TRACED_FIELDS))
    assert rebuilt.clip_coef == 0.5 and rebuilt.hidden_sizes == config.hidden_sizes


def test_structure_is_the_static_fields_only():
    """Two configs that differ only in traced fields share one pytree structure (one compiled
    program); a static field changes it."""
    a = preset("fast", learning_rate=1e-3, clip_coef=0.1, gamma=0.9)
    b = preset("fast")
    assert a != b and jax.tree.structure(a) == jax.tree.structure(b)
    assert jax.tree.structure(preset("fast", num_envs=8)) != jax.tree.structure(b)
    assert jax.tree.structure(preset("fast", anneal_lr=False)) != jax.tree.structure(b)


def test_per_run_values_are_validated_and_sized():
    sweep = PPOConfig(learning_rate=np.array([1e-3, 3e-3]))
    assert sweep.is_per_run and not PPOConfig().is_per_run
    runs = sweep.per_run(2)
    assert runs.learning_rate.dtype == np.float32
    np.testing.assert_array_equal(runs.clip_coef, np.full(2, 0.2, np.float32))
    with pytest.raises(ConfigError, match="learning_rate holds 2 values, one per run"):
        sweep.per_run(3)
    with pytest.raises(ConfigError, match="learning_rate must be > 0"):
        PPOConfig(learning_rate=np.array([1e-3, -1.0]))
    with pytest.raises(ConfigError, match="gamma must be in"):
        PPOConfig(gamma=np.array([0.9, 1.5]))
    with pytest.raises(ConfigError, match="finite"):
        PPOConfig(clip_coef=np.array([0.1, np.nan]))

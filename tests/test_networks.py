"""The actor-critic: SB3's initialisation (orthogonal, gains sqrt(2) / 0.01 / 1, zero biases),
its parameter names, and the JAX and NumPy forward passes agreeing."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxcart.core import networks
from jaxcart.core.networks import ActorCritic, actor_params, mlp, orthogonal
from jaxcart.rundir.policy import Policy


def _gram(w: np.ndarray) -> np.ndarray:
    return w.T @ w if w.shape[0] >= w.shape[1] else w @ w.T


@pytest.mark.parametrize("hidden_sizes", [(64, 64), (32,), (16, 8, 4)])
def test_init_is_sb3s_orthogonal_init(hidden_sizes):
    network = ActorCritic(hidden_sizes=hidden_sizes)
    params = network.host_init(np.random.default_rng(0))
    sizes = (4, *hidden_sizes)
    for head, out_dim, out_gain in (("actor", 2, 0.01), ("critic", 1, 1.0)):
        layers = params["params"][head]
        names = [f"hidden_{i}" for i in range(len(hidden_sizes))] + ["out"]
        assert list(layers) == names
        for i, name in enumerate(names):
            kernel, bias = layers[name]["kernel"], layers[name]["bias"]
            fan_out = out_dim if name == "out" else sizes[i + 1]
            assert kernel.shape == (sizes[i], fan_out) and kernel.dtype == np.float32
            gain = out_gain if name == "out" else math.sqrt(2.0)
            # rows or columns orthonormal, scaled by the gain
            np.testing.assert_allclose(
                _gram(kernel.astype(np.float64)), gain**2 * np.eye(min(kernel.shape)), atol=1e-6
            )
            np.testing.assert_array_equal(bias, np.zeros(fan_out, np.float32))


@pytest.mark.quick
def test_init_is_haar_random_and_seeded():
    draws = np.stack([orthogonal(np.random.default_rng(s), (64, 64), 1.0) for s in range(20)])
    # entries of Haar-random orthogonal matrices: mean 0, variance 1/n
    assert abs(draws.mean()) < 0.01 and abs(draws.var() - 1 / 64) < 0.002
    assert not np.allclose(draws[0], draws[1])
    a, b = (
        ActorCritic().host_init(np.random.default_rng(5)),
        ActorCritic().host_init(np.random.default_rng(5)),
    )
    np.testing.assert_array_equal(
        a["params"]["critic"]["hidden_1"]["kernel"], b["params"]["critic"]["hidden_1"]["kernel"]
    )


@pytest.mark.quick
def test_shapes_match_init():
    network = ActorCritic(hidden_sizes=(8, 4), activation="relu")
    params = network.host_init(np.random.default_rng(1))
    shapes = network.shapes()
    for head in ("actor", "critic"):
        for name, layer in params["params"][head].items():
            assert layer["kernel"].shape == shapes["params"][head][name]["kernel"]
            assert layer["bias"].shape == shapes["params"][head][name]["bias"]


@pytest.mark.parametrize("activation", ["tanh", "relu"])
def test_jax_forward_matches_a_hand_written_mlp(activation):
    network = ActorCritic(hidden_sizes=(8, 8), activation=activation)
    params = network.host_init(np.random.default_rng(2))
    for head in ("actor", "critic"):  # non-zero biases so that they are exercised
        for layer in params["params"][head].values():
            layer["bias"] = (
                np.random.default_rng(3).normal(size=layer["bias"].shape).astype(np.float32)
            )
    obs = np.random.default_rng(4).normal(size=(10, 4)).astype(np.float32)
    act = np.tanh if activation == "tanh" else (lambda x: np.maximum(x, 0))

    def by_hand(layers):
        x = obs.astype(np.float64)
        for name in ("hidden_0", "hidden_1"):
            x = act(x @ layers[name]["kernel"] + layers[name]["bias"])
        return x @ layers["out"]["kernel"] + layers["out"]["bias"]

    logits, value = network.apply(params, jnp.asarray(obs))
    np.testing.assert_allclose(logits, by_hand(params["params"]["actor"]), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(
        value, by_hand(params["params"]["critic"])[:, 0], rtol=1e-5, atol=1e-5
    )
    assert logits.shape == (10, 2) and value.shape == (10,)


@pytest.mark.parametrize(
    "network",
    [
        pytest.param(ActorCritic(), marks=pytest.mark.slow),
        pytest.param(
            ActorCritic(hidden_sizes=(16, 8, 4), activation="relu"), marks=pytest.mark.slow
        ),
        ActorCritic(linear_actor=True, num_actions=3),
    ],
    ids=["sb3", "relu-3-layers", "linear-actor-3-actions"],
)
def test_the_training_programs_forward_pass_is_flaxs_bit_for_bit(network):
    """networks.apply computes the built-in network as plain functions; the same bits as
    flax's apply, jitted and vmapped over runs as the training program calls it."""
    rng = np.random.default_rng(5)
    params = jax.vmap(lambda k: network.init(k, jnp.zeros((1, 6))))(
        jax.random.split(jax.random.PRNGKey(0), 3)
    )
    params = jax.tree.map(lambda p: p + rng.normal(size=p.shape).astype(p.dtype), params)
    obs = jnp.asarray(rng.normal(size=(3, 32, 6)).astype(np.float32))
    ours = jax.jit(jax.vmap(lambda p, o: networks.apply(network, p, o)))(params, obs)
    flaxs = jax.jit(jax.vmap(network.apply))(params, obs)
    assert ours[0].shape == (3, 32, network.num_actions) and ours[1].shape == (3, 32)
    for a, b in zip(ours, flaxs, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_numpy_policy_matches_jax_logits_single_and_stacked():
    network = ActorCritic()
    seeds = [network.host_init(np.random.default_rng(s)) for s in range(3)]
    obs = np.random.default_rng(0).normal(size=(3, 7, 4)).astype(np.float32)
    stacked_actor = {
        name: {k: np.stack([actor_params(p)[name][k] for p in seeds]) for k in ("kernel", "bias")}
        for name in actor_params(seeds[0])
    }
    stacked = Policy(stacked_actor, activation="tanh", stacked=True)
    assert stacked(obs).shape == (3, 7)
    for s, params in enumerate(seeds):
        expected = np.asarray(network.logits(params, jnp.asarray(obs[s])))
        single = Policy(actor_params(params), activation="tanh")
        np.testing.assert_allclose(single.logits(obs[s]), expected, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(stacked.logits(obs)[s], expected, rtol=1e-5, atol=1e-6)
        assert isinstance(single(obs[s, 0]), int)
    assert mlp(actor_params(seeds[0]), np.zeros(4, np.float32), "tanh", xp=np).shape == (2,)


def test_bad_activation_rejected():
    with pytest.raises(ValueError, match="activation"):
        ActorCritic(activation="gelu")


def test_linear_actor_is_one_layer_and_the_critic_keeps_its_hidden_layers():
    network = ActorCritic(hidden_sizes=(64, 64), linear_actor=True)
    params = network.host_init(np.random.default_rng(0))
    assert list(params["params"]["actor"]) == ["out"]
    assert params["params"]["actor"]["out"]["kernel"].shape == (4, 2)
    assert list(params["params"]["critic"]) == ["hidden_0", "hidden_1", "out"]
    obs = np.random.default_rng(1).normal(size=(6, 4)).astype(np.float32)
    w, b = params["params"]["actor"]["out"]["kernel"], params["params"]["actor"]["out"]["bias"]
    np.testing.assert_allclose(network.logits(params, jnp.asarray(obs)), obs @ w + b, rtol=1e-5)
    policy = Policy(actor_params(params), activation="tanh")
    np.testing.assert_array_equal(policy(obs), (obs @ w + b).argmax(-1))


def test_default_init_is_pytorchs_uniform_fan_in():
    network = ActorCritic(hidden_sizes=(64, 64), weight_init="default")
    draws = [network.host_init(np.random.default_rng(s)) for s in range(10)]
    for head in ("actor", "critic"):
        for name in ("hidden_0", "hidden_1", "out"):
            kernel = np.stack([d["params"][head][name]["kernel"] for d in draws])
            bias = np.stack([d["params"][head][name]["bias"] for d in draws])
            bound = 1 / math.sqrt(kernel.shape[1])
            assert np.abs(kernel).max() <= bound and np.abs(bias).max() <= bound
            # uniform on [-b, b]: variance b^2 / 3
            assert abs(kernel.var() / (bound**2 / 3) - 1) < 0.15
            assert np.abs(bias).max() > 0  # not zero, unlike the orthogonal scheme

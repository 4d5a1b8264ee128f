"""The actor-critic: a flax module mapping observations to policy logits and a value.

Any ``flax.linen`` module with ``__call__(obs [..., obs_dim]) -> (logits [..., num_actions],
value [...])`` trains (``PPOConfig(network=...)``). The built-in one, :class:`ActorCritic`, is
Stable-Baselines3's: separate actor and critic MLPs with SB3's initialisation, drawn on the host
(:meth:`ActorCritic.host_init`); its forward pass also exists in NumPy (:func:`mlp`) for the
policies that :mod:`jaxcart.rundir.policy` hands to Gymnasium loops.

Parameters are a plain nested dict, ``{"params": {"actor": LAYERS, "critic": LAYERS}}`` with
``LAYERS = {"hidden_0": {"kernel", "bias"}, ..., "out": {"kernel", "bias"}}``; kernels are
``[in, out]`` and a layer computes ``x @ kernel + bias``. Run directories store the same names
(``params/actor/hidden_0/kernel``, ...).
"""

from __future__ import annotations

import math
from types import ModuleType
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from jaxcart.core import envs

ROOT = "params"
ACTOR = "actor"
CRITIC = "critic"
OUT = "out"
HIDDEN_GAIN = math.sqrt(2.0)
"""Gain of every hidden kernel (SB3's ``ortho_init``)."""
POLICY_GAIN = 0.01
"""Gain of the policy head: a near-uniform initial policy."""
VALUE_GAIN = 1.0
"""Gain of the value head."""
ACTIVATIONS = ("tanh", "relu")
INITS = ("orthogonal", "default")


def layer_names(num_hidden: int) -> list[str]:
    """``["hidden_0", ..., "hidden_{n-1}", "out"]``: one MLP's layers, input first."""
    return [f"hidden_{i}" for i in range(num_hidden)] + [OUT]


def sb3_layers(actor_hidden: int, critic_hidden: int) -> list[tuple[str, str, str]]:
    """``(head, layer, SB3 module)`` of each ``Linear`` of Stable-Baselines3's
    ``ActorCriticPolicy`` with ``actor_hidden`` and ``critic_hidden`` hidden layers, in its
    ``state_dict`` order: ``mlp_extractor.policy_net.{2i}`` and ``mlp_extractor.value_net.{2i}``
    (``Linear`` at even indices, activations between), then the heads ``action_net`` and
    ``value_net``. SB3's ``weight [out, in]`` is the transpose of jaxcart's ``kernel``."""
    bodies = ((ACTOR, "policy_net", actor_hidden), (CRITIC, "value_net", critic_hidden))
    layers = [
        (head, name, f"mlp_extractor.{net}.{2 * i}")
        for head, net, hidden in bodies
        for i, name in enumerate(layer_names(hidden)[:-1])
    ]
    return [*layers, (ACTOR, OUT, "action_net"), (CRITIC, OUT, "value_net")]


def orthogonal(rng: np.random.Generator, shape: tuple[int, int], gain: float) -> np.ndarray:
    """``gain`` times a Haar-random matrix with orthonormal rows or columns (QR of a Gaussian
    matrix with R's diagonal made positive), float64."""
    rows, cols = max(shape), min(shape)
    q, r = np.linalg.qr(rng.standard_normal((rows, cols)))
    q = q * np.sign(np.diag(r))
    return gain * (q if shape[0] >= shape[1] else q.T)


def activate(x: Any, activation: str, xp: ModuleType) -> Any:
    """The hidden activation, for NumPy (``xp=np``) or JAX (``xp=jnp``) arrays."""
    return xp.tanh(x) if activation == "tanh" else xp.maximum(x, 0.0)


def mlp(layers: dict, x: Any, activation: str, xp: ModuleType = jnp) -> Any:
    """One MLP's forward pass: ``x [..., in] -> [..., out]``.

    With a leading run axis on every kernel ``[R, in, out]`` and bias ``[R, 1, out]``, ``x
    [R, N, in]`` maps to ``[R, N, out]`` (one policy per run, batched).
    """
    names = layer_names(len(layers) - 1)
    for name in names:
        x = x @ layers[name]["kernel"] + layers[name]["bias"]
        if name != OUT:
            x = activate(x, activation, xp)
    return x


class MLP(nn.Module):
    """One MLP as flax layers named ``hidden_0, ..., out``: ``[..., in] -> [..., out_dim]``,
    each layer ``x @ kernel + bias``, the hidden ones followed by the activation."""

    hidden_sizes: tuple[int, ...]
    out_dim: int
    activation: str = "tanh"

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        for i, width in enumerate(self.hidden_sizes):
            x = activate(nn.Dense(width, name=f"hidden_{i}")(x), self.activation, jnp)
        return nn.Dense(self.out_dim, name=OUT)(x)


class ActorCritic(nn.Module):
    """Stable-Baselines3's actor-critic: policy logits and state value from two independent
    MLPs, ``obs [..., obs_dim] -> (logits [..., num_actions], value [...])``.

    A flax module like any other network a user passes (``PPOConfig(network=...)``); what sets
    it apart is :meth:`host_init`, SB3's initialisation drawn on the host with NumPy, which
    training uses for it (so its runs do not depend on JAX's random numbers).
    """

    hidden_sizes: tuple[int, ...] = (64, 64)
    activation: str = "tanh"
    num_actions: int = 2
    linear_actor: bool = False  # the actor is one linear layer (logits = obs @ W + b)
    weight_init: str = "orthogonal"  # or "default": PyTorch's nn.Linear initialisation

    def __post_init__(self) -> None:
        if self.activation not in ACTIVATIONS:
            raise ValueError(f"activation must be one of {ACTIVATIONS}, got {self.activation!r}")
        if self.weight_init not in INITS:
            raise ValueError(f"weight_init must be one of {INITS}, got {self.weight_init!r}")
        super().__post_init__()

    @classmethod
    def from_config(cls, config: Any) -> ActorCritic:
        """The built-in network a :class:`~jaxcart.core.config.PPOConfig` describes, with as
        many logits as its env has actions."""
        return cls(
            hidden_sizes=tuple(int(h) for h in config.hidden_sizes),
            num_actions=envs.make(config.env).num_actions,
            activation=config.activation,
            linear_actor=config.linear_actor,
            weight_init=config.weight_init,
        )

    @nn.compact
    def __call__(self, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        actor_hidden = () if self.linear_actor else tuple(self.hidden_sizes)
        logits = MLP(actor_hidden, self.num_actions, self.activation, name=ACTOR)(obs)
        value = MLP(tuple(self.hidden_sizes), 1, self.activation, name=CRITIC)(obs)
        return logits, value[..., 0]

    def shapes(self, obs_dim: int = 4) -> dict:
        """The kernel and bias shapes of every layer, as the parameter tree (tuples as leaves)."""

        def head(hidden: tuple[int, ...], out_dim: int) -> dict:
            sizes = (obs_dim, *hidden, out_dim)
            return {
                n: {"kernel": (sizes[i], sizes[i + 1]), "bias": (sizes[i + 1],)}
                for i, n in enumerate(layer_names(len(hidden)))
            }

        actor = head(() if self.linear_actor else tuple(self.hidden_sizes), self.num_actions)
        return {ROOT: {ACTOR: actor, CRITIC: head(tuple(self.hidden_sizes), 1)}}

    def host_init(
        self, rng: np.random.Generator, obs_dim: int = 4, dtype: Any = np.float32
    ) -> dict:
        """Fresh parameters (NumPy). ``weight_init="orthogonal"``: orthogonal kernels with gain
        sqrt(2) in hidden layers, 0.01 for the policy head and 1 for the value head, zero
        biases (SB3's ``ortho_init``). ``weight_init="default"``: PyTorch's ``nn.Linear`` default,
        weights and biases uniform in +-1/sqrt(fan_in).

        Drawn on the host: no initialisation program to compile, and the same numbers on
        every device count.
        """
        params: dict = {ROOT: {}}
        for head, out_gain in ((ACTOR, POLICY_GAIN), (CRITIC, VALUE_GAIN)):
            layers = {}
            for name, shape in self.shapes(obs_dim)[ROOT][head].items():
                if self.weight_init == "default":
                    bound = 1.0 / math.sqrt(shape["kernel"][0])
                    kernel = rng.uniform(-bound, bound, shape["kernel"])
                    bias = rng.uniform(-bound, bound, shape["bias"])
                else:
                    gain = out_gain if name == OUT else HIDDEN_GAIN
                    kernel, bias = orthogonal(rng, shape["kernel"], gain), np.zeros(shape["bias"])
                layers[name] = {"kernel": kernel.astype(dtype), "bias": bias.astype(dtype)}
            params[ROOT][head] = layers
        return params

    def logits(self, params: dict, obs: jax.Array) -> jax.Array:
        """Policy logits only, ``[..., num_actions]`` (JAX)."""
        return self.apply(params, obs)[0]

    def value(self, params: dict, obs: jax.Array) -> jax.Array:
        """State value only, ``obs.shape[:-1]`` (JAX)."""
        return self.apply(params, obs)[1]


def apply(network: nn.Module, params: dict, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``network.apply(params, obs)``: ``(logits [..., num_actions], value [...])`` for ``obs
    [..., obs_dim]``, the way the training program calls every network.

    The built-in :class:`ActorCritic` is computed as the plain functions of its NumPy twin
    (:func:`mlp`): the same operations on the same parameter tree, so the same bits
    (tests/test_networks.py), which JAX traces without flax's module machinery, about 0.05 s
    less per compiled program (``benchmarks/RESULTS.md``, "Default path"). Any other module
    runs through flax's ``apply``.
    """
    if type(network) is not ActorCritic:
        return network.apply(params, obs)
    layers = params[ROOT]
    value = mlp(layers[CRITIC], obs, network.activation)[..., 0]
    return mlp(layers[ACTOR], obs, network.activation), value


def param_shapes(network: nn.Module, obs_dim: int) -> dict:
    """A flax network's parameter tree with ``(shape, dtype)`` leaves, as its ``init`` makes
    them, without computing anything (the built-in network's: :meth:`ActorCritic.shapes`)."""
    shaped = jax.eval_shape(
        network.init, jax.random.PRNGKey(0), jax.ShapeDtypeStruct((1, obs_dim), jnp.float32)
    )
    return jax.tree.map(lambda a: (tuple(a.shape), np.dtype(a.dtype)), dict(shaped))


def actor_params(params: dict) -> dict:
    """The actor's layers ``{"hidden_0": {"kernel", "bias"}, ..., "out": ...}``."""
    return params[ROOT][ACTOR]

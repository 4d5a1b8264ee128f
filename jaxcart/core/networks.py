"""The actor-critic: separate actor and critic MLPs with Stable-Baselines3's initialisation.

Everything about the network lives here: its parameter names, its initialisation (the one
training uses) and its forward pass (in JAX for training, in NumPy for the policies that
:mod:`jaxcart.rundir.policy` hands to Gymnasium loops).

Parameters are a plain nested dict, ``{"params": {"actor": LAYERS, "critic": LAYERS}}`` with
``LAYERS = {"hidden_0": {"kernel", "bias"}, ..., "out": {"kernel", "bias"}}``; kernels are
``[in, out]`` and a layer computes ``x @ kernel + bias``. Run directories store the same names
(``params/actor/hidden_0/kernel``, ...).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import jax.numpy as jnp
import numpy as np

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


@dataclass(frozen=True)
class ActorCritic:
    """Policy logits and state value from two independent MLPs.

    Maps observations ``[..., obs_dim]`` to ``(logits [..., num_actions], value [...])``.
    Hashable, so it can be a static argument of a jitted function.
    """

    hidden_sizes: tuple[int, ...] = (64, 64)
    activation: str = "tanh"
    obs_dim: int = 4
    num_actions: int = 2
    linear_actor: bool = False  # the actor is one linear layer (logits = obs @ W + b)
    weight_init: str = "orthogonal"  # or "default": PyTorch's nn.Linear initialisation

    def __post_init__(self) -> None:
        if self.activation not in ACTIVATIONS:
            raise ValueError(f"activation must be one of {ACTIVATIONS}, got {self.activation!r}")
        if self.weight_init not in INITS:
            raise ValueError(f"weight_init must be one of {INITS}, got {self.weight_init!r}")
        object.__setattr__(self, "hidden_sizes", tuple(int(h) for h in self.hidden_sizes))

    @classmethod
    def from_config(cls, config: Any) -> ActorCritic:
        """The network a :class:`~jaxcart.core.config.PPOConfig` describes."""
        return cls(
            hidden_sizes=config.hidden_sizes,
            activation=config.activation,
            linear_actor=config.linear_actor,
            weight_init=config.weight_init,
        )

    def shapes(self) -> dict:
        """The kernel and bias shapes of every layer, as the parameter tree (tuples as leaves)."""

        def head(hidden: tuple[int, ...], out_dim: int) -> dict:
            sizes = (self.obs_dim, *hidden, out_dim)
            names = layer_names(len(hidden))
            return {
                n: {"kernel": (sizes[i], sizes[i + 1]), "bias": (sizes[i + 1],)}
                for i, n in enumerate(names)
            }

        actor_hidden = () if self.linear_actor else self.hidden_sizes
        return {
            ROOT: {
                ACTOR: head(actor_hidden, self.num_actions),
                CRITIC: head(self.hidden_sizes, 1),
            }
        }

    def init(self, rng: np.random.Generator, dtype: Any = np.float32) -> dict:
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
            for name, shape in self.shapes()[ROOT][head].items():
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

    def apply(self, params: dict, obs: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
        """``(logits [..., num_actions], value [...])`` for ``obs [..., obs_dim]`` (JAX)."""
        return self.logits(params, obs), self.value(params, obs)

    def logits(self, params: dict, obs: jnp.ndarray) -> jnp.ndarray:
        """Policy logits only, ``[..., num_actions]``."""
        return mlp(params[ROOT][ACTOR], obs, self.activation)

    def value(self, params: dict, obs: jnp.ndarray) -> jnp.ndarray:
        """State value only, ``obs.shape[:-1]``."""
        return mlp(params[ROOT][CRITIC], obs, self.activation)[..., 0]


def actor_params(params: dict) -> dict:
    """The actor's layers ``{"hidden_0": {"kernel", "bias"}, ..., "out": ...}``."""
    return params[ROOT][ACTOR]

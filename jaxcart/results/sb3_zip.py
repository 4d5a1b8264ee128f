"""A trained jaxcart network as a Stable-Baselines3 ``PPO`` zip, written without PyTorch.

``stable_baselines3.PPO.load`` reads a zip holding ``data`` (JSON; the values that are Python
objects are pickles in base64), ``policy.pth`` and ``policy.optimizer.pth`` (each a
``torch.save`` archive: a zip of ``data.pkl`` naming the tensors and one raw little-endian
record per tensor) and ``_stable_baselines3_version``. This module writes that format itself,
so an export needs neither torch nor SB3; the pickles name only what SB3's own loader allows
(``torch.load(weights_only=True)``: ``collections.OrderedDict``,
``torch._utils._rebuild_tensor_v2``, ``torch.FloatStorage``).

The network maps onto SB3's ``ActorCriticPolicy`` with ``net_arch=dict(pi=H, vf=H)``:
jaxcart's ``actor/hidden_i`` is ``mlp_extractor.policy_net.{2i}``, ``actor/out`` is
``action_net``, the critic likewise with ``value_net``; SB3's ``Linear`` stores
``weight [out, in]``, the transpose of jaxcart's kernel ``[in, out]``.
"""

from __future__ import annotations

import base64
import io
import json
import math
import pickle
import struct
import zipfile
from collections import OrderedDict
from typing import ClassVar, NamedTuple

import numpy as np

from jaxcart.core import networks
from jaxcart.core.config import PPOConfig

SB3_FORMAT_VERSION = "2.9.2"
"""Written as ``_stable_baselines3_version``: the SB3 release the zips were checked against
(``PPO.load``, ``predict``, ``evaluate_policy``, ``learn``); SB3 reads it only to print it."""
ACTIVATION_CLASSES = {"tanh": "Tanh", "relu": "ReLU"}
"""jaxcart's activation -> its ``torch.nn`` class (in ``torch.nn.modules.activation``)."""
ADAM_DEFAULTS = {"betas": (0.9, 0.999), "weight_decay": 0}
"""``torch.optim.Adam``'s settings besides ``lr`` and ``eps`` (SB3's PPO optimizer) that its
``load_state_dict`` needs; it fills in the flags (``amsgrad``, ``maximize``, ``foreach``,
``fused``, ...) with their defaults itself."""
_TORCH_ALIGNMENT = 64  # torch.save aligns each record so it can be memory-mapped


class Global(NamedTuple):
    """A class or function, named by module and attribute: pickled without importing it."""

    module: str
    name: str


class TensorRef(NamedTuple):
    """A float32 tensor of ``shape`` whose bytes are the archive's record ``data/{key}``."""

    key: str
    shape: tuple[int, ...]


class _Pickler(pickle._Pickler):
    """Python's own (pure-Python) pickler that also writes a :class:`Global` by name, without
    importing it (torch and SB3 need not be installed), and a :class:`TensorRef` as
    ``torch.save`` writes a tensor: ``_rebuild_tensor_v2`` of a persistent ``FloatStorage``,
    whose bytes ``torch.load`` reads from the record ``data/{key}``."""

    dispatch: ClassVar[dict] = dict(pickle._Pickler.dispatch)

    def save_global_name(self, obj: Global) -> None:
        self.write(pickle.GLOBAL + f"{obj.module}\n{obj.name}\n".encode())

    def save_tensor(self, obj: TensorRef) -> None:
        shape = tuple(obj.shape)
        strides = tuple(math.prod(shape[i + 1 :]) for i in range(len(shape)))
        self.save(Global("torch._utils", "_rebuild_tensor_v2"))
        # (storage, offset, size, stride, requires_grad, backward hooks), the storage as
        # torch.save names it (BINPERSID)
        self.write(pickle.MARK)
        storage = Global("torch", "FloatStorage")
        self.save_pers(("storage", storage, obj.key, "cpu", math.prod(shape)))
        for item in (0, shape, strides, False, OrderedDict()):
            self.save(item)
        self.write(pickle.TUPLE + pickle.REDUCE)

    dispatch[Global] = save_global_name
    dispatch[TensorRef] = save_tensor


def write_pickle(obj: object) -> bytes:
    """``obj`` as a protocol-2 pickle (what ``torch.load(weights_only=True)`` and SB3 read),
    its :class:`Global` and :class:`TensorRef` values written by name (:class:`_Pickler`)."""
    buffer = io.BytesIO()
    _Pickler(buffer, protocol=2).dump(obj)
    return buffer.getvalue()


def torch_save_bytes(obj: object, tensors: dict[str, np.ndarray]) -> bytes:
    """What ``torch.save(obj)`` writes, for ``obj`` made of :func:`write_pickle`'s types whose
    :class:`TensorRef` keys name the float32 arrays in ``tensors``.

    Each record is stored uncompressed, its data starting on a multiple of 64 bytes, padded as
    torch pads (an extra field ``FB`` in the local header), so that it can be memory-mapped.
    """
    records = {"data.pkl": write_pickle(obj), "byteorder": b"little"}
    for key, array in tensors.items():
        records[f"data/{key}"] = np.ascontiguousarray(array, dtype="<f4").tobytes()
    records["version"] = b"3\n"
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_STORED) as archive:
        for name, data in records.items():
            info = zipfile.ZipInfo(f"archive/{name}", date_time=(1980, 1, 1, 0, 0, 0))
            # the data follows the local header (30 bytes), the name and the extra's head
            start = archive.fp.tell() + 30 + len(info.filename.encode()) + 4
            pad = -start % _TORCH_ALIGNMENT
            info.extra = b"FB" + struct.pack("<H", pad) + b"Z" * pad
            archive.writestr(info, data, compress_type=zipfile.ZIP_STORED)
    return buffer.getvalue()


def policy_state_dict(params: dict) -> OrderedDict[str, np.ndarray]:
    """SB3's ``ActorCriticPolicy.state_dict()`` for one seed's jaxcart parameters, in SB3's
    order: ``mlp_extractor.policy_net.*``, ``mlp_extractor.value_net.*``, ``action_net.*``,
    ``value_net.*`` (weights ``[out, in]``, biases ``[out]``, float32)."""
    root = params[networks.ROOT]
    state: OrderedDict[str, np.ndarray] = OrderedDict()
    hidden = (len(root[networks.ACTOR]) - 1, len(root[networks.CRITIC]) - 1)
    for head, layer, module in networks.sb3_layers(*hidden):
        state[f"{module}.weight"] = np.ascontiguousarray(root[head][layer]["kernel"].T, np.float32)
        state[f"{module}.bias"] = np.ascontiguousarray(root[head][layer]["bias"], np.float32)
    return state


def net_arch(config: PPOConfig) -> dict[str, list[int]]:
    """SB3's ``net_arch`` for the config's network (``pi=[]`` for a linear actor)."""
    hidden = list(config.hidden_sizes)
    return {"pi": [] if config.linear_actor else hidden, "vf": hidden}


def sb3_zip_bytes(params: dict, config: PPOConfig) -> bytes:
    """One seed's parameters (``params``, no seed axis) as the zip ``PPO.load`` reads.

    The hyperparameters recorded are the config's (an annealed learning rate as its initial
    value: SB3 would need a schedule function); the optimizer state is empty (Adam's moments
    are not kept), so ``PPO.load(...).learn()`` continues with a fresh Adam. What ``data``
    leaves out (``seed``, ``target_kl``, ``use_sde``, the step and episode counters, ...) is
    SB3's default: ``PPO.load`` builds the model with its defaults, then sets what ``data``
    holds.
    """
    import gymnasium  # noqa: F401  (the spaces' pickles name gymnasium's classes)

    from jaxcart.core import cartpole

    state = policy_state_dict(params)
    tensors = {str(i): array for i, array in enumerate(state.values())}
    policy = OrderedDict(
        (name, TensorRef(str(i), a.shape)) for i, (name, a) in enumerate(state.items())
    )
    adam = {"lr": float(config.learning_rate), "eps": float(config.adam_eps), **ADAM_DEFAULTS}
    optimizer = {"state": {}, "param_groups": [adam | {"params": list(range(len(state)))}]}
    activation = Global("torch.nn.modules.activation", ACTIVATION_CLASSES[config.activation])
    spaces = {"observation_space": cartpole.observation_space()}
    spaces["action_space"] = cartpole.action_space()
    data = {k: _serialized(pickle.dumps(v, protocol=4), str(type(v))) for k, v in spaces.items()}
    policy_class = Global("stable_baselines3.common.policies", "ActorCriticPolicy")
    data["policy_class"] = _serialized(write_pickle(policy_class), "<class 'abc.ABCMeta'>")
    kwargs = {"net_arch": net_arch(config), "activation_fn": activation}
    data["policy_kwargs"] = _serialized(write_pickle(kwargs), "<class 'dict'>")
    data |= {
        "n_envs": config.num_envs,
        "_total_timesteps": int(config.env_steps_per_seed),
        "verbose": 0,  # PPO.load reads it when given an env
        "learning_rate": float(config.learning_rate),
        "n_steps": config.num_steps,
        "batch_size": config.minibatch_size,
        "n_epochs": config.update_epochs,
        "gamma": float(config.gamma),
        "gae_lambda": float(config.gae_lambda),
        "clip_range": float(config.clip_coef),
        "normalize_advantage": bool(config.norm_adv),
        "ent_coef": float(config.ent_coef),
        "vf_coef": float(config.vf_coef),
        "max_grad_norm": float(config.max_grad_norm),
    }
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr("data", json.dumps(data, indent=4))
        archive.writestr("policy.optimizer.pth", torch_save_bytes(optimizer, {}))
        archive.writestr("policy.pth", torch_save_bytes(policy, tensors))
        archive.writestr("_stable_baselines3_version", SB3_FORMAT_VERSION)
        about = "- Written by jaxcart (jaxcart.results.sb3_zip), without PyTorch\n"
        archive.writestr("system_info.txt", about)
    return buffer.getvalue()


def _serialized(pickled: bytes, type_text: str) -> dict[str, str]:
    """A ``data`` entry SB3 unpickles on load (``:serialized:``, base64)."""
    return {":type:": type_text, ":serialized:": base64.b64encode(pickled).decode()}

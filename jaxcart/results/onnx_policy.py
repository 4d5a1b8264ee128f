"""A trained jaxcart actor as an ONNX model, built with the ``onnx`` package (no PyTorch).

The graph is the actor's MLP as ``MatMul``, ``Add`` and ``Tanh``/``Relu`` nodes over float32
observations ``obs [N, 4]`` (``N`` free), with two outputs: ``logits [N, 2]`` and the greedy
``action [N]`` (int64, ``ArgMax``), the actions :func:`jaxcart.load_policy` returns.
"""

from __future__ import annotations

import numpy as np

from jaxcart.core import networks

OPSET = 17
"""ONNX operator set of the model (every node used exists unchanged since opset 13)."""
IR_VERSION = 8
"""The model's IR version: the one that introduced opset 17, so that onnxruntime releases
from 1.13 on run it."""
ONNX_NODES = {"tanh": "Tanh", "relu": "Relu"}


def onnx_model_bytes(actor: dict, activation: str) -> bytes:
    """The actor (:func:`jaxcart.core.networks.actor_params` of one seed, kernels ``[in, out]``)
    as a checked ONNX model, serialized as written to a ``.onnx`` file.

    Raises:
        ImportError: the ``onnx`` package is missing (``pip install 'jaxcart[export]'``).
    """
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    nodes, weights, x = [], [], "obs"
    for layer in networks.layer_names(len(actor) - 1):
        for part in ("kernel", "bias"):
            array = np.asarray(actor[layer][part], np.float32)
            weights.append(numpy_helper.from_array(array, f"{layer}.{part}"))
        pre = "logits" if layer == networks.OUT else f"{layer}.pre"
        nodes += [
            helper.make_node("MatMul", [x, f"{layer}.kernel"], [f"{layer}.matmul"]),
            helper.make_node("Add", [f"{layer}.matmul", f"{layer}.bias"], [pre]),
        ]
        if layer != networks.OUT:
            x = f"{layer}.out"
            nodes.append(helper.make_node(ONNX_NODES[activation], [pre], [x]))
    nodes.append(helper.make_node("ArgMax", ["logits"], ["action"], axis=-1, keepdims=0))
    num_actions = int(np.shape(actor[networks.OUT]["bias"])[-1])
    graph = helper.make_graph(
        nodes,
        "jaxcart_actor",
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["N", 4])],
        [
            helper.make_tensor_value_info("logits", TensorProto.FLOAT, ["N", num_actions]),
            helper.make_tensor_value_info("action", TensorProto.INT64, ["N"]),
        ],
        initializer=weights,
    )
    model = helper.make_model(
        graph,
        opset_imports=[helper.make_opsetid("", OPSET)],
        ir_version=IR_VERSION,
        producer_name="jaxcart",
    )
    onnx.checker.check_model(model, full_check=True)
    return model.SerializeToString()

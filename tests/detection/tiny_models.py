"""Tiny ONNX graphs whose outputs are known exactly, for decoding tests.

Each graph takes an image input ``[1, 3, H, W]`` and returns constant tensors we write
(plus ``0 * sum(input)``, so the input is used and onnxruntime runs a real graph).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

onnx = pytest.importorskip("onnx")
from onnx import TensorProto, helper, numpy_helper  # noqa: E402


def write_constant_model(
    path: Path,
    outputs: dict[str, np.ndarray],
    input_shape=(1, 3, 64, 64),
    input_name: str = "images",
    symbolic: bool = False,
    symbolic_batch: bool = False,
) -> Path:
    """Write a model returning ``outputs`` (name -> float32 array) whatever the image.

    ``symbolic`` declares the input's height/width and every output dim as symbolic
    strings, like an export with ``dynamic=True``; ``symbolic_batch`` only the batch dims.
    """
    nodes = [
        helper.make_node("ReduceSum", [input_name], ["s"], keepdims=0),
        helper.make_node("Constant", [], ["zero"], value=numpy_helper.from_array(np.array(0.0, np.float32))),
        helper.make_node("Mul", ["s", "zero"], ["z"]),
    ]
    inits, outs = [], []
    for k, (name, arr) in enumerate(outputs.items()):
        arr = np.asarray(arr, dtype=np.float32)
        inits.append(numpy_helper.from_array(arr, f"c{k}"))
        nodes.append(helper.make_node("Add", [f"c{k}", "z"], [name]))
        shape = [f"{name}_d{i}" for i in range(arr.ndim)] if symbolic else list(arr.shape)
        if symbolic_batch:
            shape[0] = "batch"
        outs.append(helper.make_tensor_value_info(name, TensorProto.FLOAT, shape))
    in_shape = [1, 3, "height", "width"] if symbolic else list(input_shape)
    if symbolic_batch:
        in_shape[0] = "batch"
    graph = helper.make_graph(
        nodes, "tiny", [helper.make_tensor_value_info(input_name, TensorProto.FLOAT, in_shape)], outs, inits
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path

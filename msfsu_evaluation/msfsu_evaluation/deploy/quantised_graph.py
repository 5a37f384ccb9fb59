"""The OpenVINO graph work of the int8 recipe search (deploy.recipe): which layers a FakeQuantize feeds, putting
layers back in float in a quantised model, and each layer's multiply-accumulates.

Layers are named as msfsu_perception.int8_recipe names them (`layer_of`: OpenVINO friendly name -> layer). A model
quantised with its weights left as float constants behind their FakeQuantize (nncf_quantize, compress_weights=False)
puts any layer back in float by bypassing the quantisers on its inputs.
"""

from __future__ import annotations

import math
from collections.abc import Collection
from typing import Any


def quantised_layers(model: Any, layer_of: dict[str, str]) -> dict[str, str]:
    """{layer name: OpenVINO op type} of the ops with a FakeQuantize on an input."""
    found = {}
    for op in model.get_ordered_ops():
        name = layer_of.get(op.get_friendly_name())
        if name is None or op.get_type_name() == "FakeQuantize":
            continue
        if any(port.get_source_output().get_node().get_type_name() == "FakeQuantize" for port in op.inputs()):
            found[name] = op.get_type_name()
    return found


def revert_to_float(quantised: Any, layer_of: dict[str, str], layers: Collection[str]) -> Any:
    """A copy of `quantised` with the quantisers on the inputs of `layers` bypassed (weights back to float)."""
    model = quantised.clone()
    layers = set(layers)
    for op in model.get_ordered_ops():
        if layer_of.get(op.get_friendly_name()) not in layers:
            continue
        for port in op.inputs():
            source = port.get_source_output().get_node()
            if source.get_type_name() == "FakeQuantize":
                port.replace_source_output(source.input_value(0))
    return model


def layer_macs(model: Any, layer_of: dict[str, str]) -> dict[str, int]:
    """Multiply-accumulates per weighted layer at batch 1."""
    from msfsu_perception.backends.openvino_runner import input_shapes

    model = model.clone()
    model.reshape({name: [1, *shape[1:]] for name, shape in input_shapes(model).items()})
    macs = {}
    for op in model.get_ordered_ops():
        name, kind = layer_of.get(op.get_friendly_name()), op.get_type_name()
        if name is None or kind not in ("Convolution", "ConvolutionBackpropData", "MatMul"):
            continue
        weight = [int(d) for d in op.input(1).get_partial_shape().to_shape()]
        out = [int(d) for d in op.output(0).get_partial_shape().to_shape()]
        if kind == "Convolution":  # weight (Cout, Cin, kh, kw)
            macs[name] = math.prod(out) * math.prod(weight[1:])
        elif kind == "ConvolutionBackpropData":  # weight (Cin, Cout, kh, kw): every input element scatters
            inputs = [int(d) for d in op.input(0).get_partial_shape().to_shape()]
            macs[name] = math.prod(inputs) * math.prod(weight[1:])
        else:  # MatMul: (B, K) x (K, N) or transposed
            macs[name] = math.prod(out) * min(weight)
    return macs


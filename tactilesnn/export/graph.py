"""torch -> ONNX conversion and graph composition shared by every exported component."""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from pathlib import Path

import onnx
import torch
from torch import nn

OPSET = 17


def torch_to_onnx(
    module: nn.Module,
    args: tuple,
    path: Path,
    inputs: Sequence[str],
    outputs: Sequence[str],
    scripted: bool = False,
    opset: int = OPSET,
) -> None:
    """Export ``module`` (scripted first if ``scripted``: time loops become ONNX ``Loop``s) with
    a dynamic batch axis on every input and output."""
    if scripted:
        module = torch.jit.script(module)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            module,
            args,
            str(path),
            input_names=list(inputs),
            output_names=list(outputs),
            dynamic_axes={k: {0: "batch"} for k in [*inputs, *outputs]},
            opset_version=opset,
            dynamo=False,
        )


def chain(
    first: onnx.ModelProto,
    second: onnx.ModelProto,
    io: Sequence[tuple[str, str]],
    tags: tuple[str, str] = ("a/", "b/"),
) -> onnx.ModelProto:
    """Feed outputs of ``first`` into inputs of ``second`` (``io`` pairs); names stay unprefixed
    on the graph boundary, internal names get ``tags``."""
    a = onnx.compose.add_prefix(first, tags[0], rename_inputs=False, rename_outputs=False)
    b = onnx.compose.add_prefix(second, tags[1], rename_inputs=False, rename_outputs=False)
    merged = onnx.compose.merge_models(a, b, io_map=list(io))
    # merge_models lists the default domain once per input model; tools that look it up
    # (onnxruntime's quantizer) need one entry per domain
    versions: dict[str, int] = {}
    for op in merged.opset_import:
        versions[op.domain] = max(versions.get(op.domain, 0), op.version)
    del merged.opset_import[:]
    merged.opset_import.extend(onnx.helper.make_opsetid(d, v) for d, v in versions.items())
    return merged

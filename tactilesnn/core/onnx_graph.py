"""torch -> ONNX conversion and graph composition shared by every exported component."""

from __future__ import annotations

import hashlib
import logging
import warnings
from collections.abc import Sequence
from pathlib import Path

import onnx
import torch
from torch import nn

from .onnx_shapes import fold_static_shapes

OPSET = 17


def torch_to_onnx(
    module: nn.Module,
    args: tuple,
    path: Path,
    inputs: Sequence[str],
    outputs: Sequence[str],
    scripted: bool = False,
    opset: int = OPSET,
) -> onnx.ModelProto:
    """Export ``module`` (scripted first if ``scripted``: time loops become ONNX ``Loop``s) with
    a dynamic batch axis on every input and output; returns the graph as written to ``path``,
    its static sizes folded into constants (:func:`~.shapes.fold_static_shapes`) and the
    reshapes still sized at run time made literal (:func:`literal_zero_reshapes`)."""
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
    model = onnx.load(str(path))
    if fold_static_shapes(model) + literal_zero_reshapes(model) + merge_constants(model):
        onnx.save(model, str(path))
    return model


def exported_to_onnx(
    module: nn.Module,
    args: tuple,
    inputs: Sequence[str],
    outputs: Sequence[str],
    opset: int = OPSET,
) -> onnx.ModelProto:
    """Export ``module`` with the ``torch.export``-based exporter (``dynamo=True``, the
    supported path; needs ``onnxscript``) with a dynamic batch axis on every input
    (``module.forward(first, *rest)``), optimised, its static sizes folded as
    :func:`torch_to_onnx` does. For graphs without data-dependent loops."""
    batch = torch.export.Dim("batch")
    shapes = ({0: batch}, tuple({0: batch} for _ in args[1:]))
    # its registry logs a warning per torchvision op it cannot register (no torchvision here)
    quiet = logging.getLogger("torch.onnx._internal.exporter._registration")
    level = quiet.level
    quiet.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            program = torch.onnx.export(module, args, input_names=list(inputs),
                                        output_names=list(outputs), dynamic_shapes=shapes,
                                        dynamo=True, opset_version=max(opset, 18), verbose=False)  # fmt: skip
            program.optimize()
    finally:
        quiet.setLevel(level)
    model = program.model_proto
    fold_static_shapes(model)
    literal_zero_reshapes(model)
    merge_constants(model)
    return model


#: Constant tensors at least this large are merged when identical (:func:`merge_constants`)
MERGE_BYTES = 1024


def merge_constants(model: onnx.ModelProto) -> int:
    """Keeps one of each set of identical large ``Constant`` nodes of the main graph: the
    tracer copies a tensor into the graph at every use (a block matrix read by 49 blocks became
    49 copies, 127 MB). Returns how many were removed."""
    g = model.graph
    first: dict[tuple, str] = {}
    rename: dict[str, str] = {}
    keep = []
    for node in g.node:
        if (
            node.op_type == "Constant"
            and len(node.attribute) == 1
            and node.attribute[0].name == "value"
        ):
            t = node.attribute[0].t
            raw = t.raw_data
            if len(raw) >= MERGE_BYTES:
                key = (t.data_type, tuple(t.dims), hashlib.sha256(raw).digest())
                if key in first:
                    rename[node.output[0]] = first[key]
                    continue
                first[key] = node.output[0]
        keep.append(node)
    if not rename:
        return 0
    for node in keep:
        for i, name in enumerate(node.input):
            if name in rename:
                node.input[i] = rename[name]
    outputs = {o.name for o in g.output}
    if outputs & set(rename):  # a graph output that is a merged constant: keep it (rare)
        return 0
    del g.node[:]
    g.node.extend(keep)
    return len(rename)


def literal_zero_reshapes(model: onnx.ModelProto) -> int:
    """Set ``allowzero=1`` on every ``Reshape`` whose shape is computed from sizes at run time;
    returns how many changed.

    ONNX reads a 0 in a shape as "copy this axis from the input" unless ``allowzero`` is set, so
    a traced ``reshape(rows, ...)`` breaks when ``rows`` is 0 at run time (the activity gate
    passes zero rows when every taxel is silent). Constant shapes keep the exporter's meaning.
    """
    constant = {i.name for i in model.graph.initializer}
    constant |= {n.output[0] for n in model.graph.node if n.op_type == "Constant"}
    changed = 0
    for node in model.graph.node:
        if node.op_type != "Reshape" or node.input[1] in constant:
            continue
        attrs = [a for a in node.attribute if a.name == "allowzero"]
        if attrs and attrs[0].i == 1:
            continue
        for a in attrs:
            node.attribute.remove(a)
        node.attribute.append(onnx.helper.make_attribute("allowzero", 1))
        changed += 1
    return changed


def chain(
    first: onnx.ModelProto,
    second: onnx.ModelProto,
    io: Sequence[tuple[str, str]],
    tags: tuple[str, str] = ("a/", "b/"),
) -> onnx.ModelProto:
    """Feed outputs of ``first`` into inputs of ``second`` (``io`` pairs); names stay unprefixed
    on the graph boundary, internal names get ``tags``."""
    a = prefixed(first, tags[0])
    b = prefixed(second, tags[1])
    merged = onnx.compose.merge_models(a, b, io_map=list(io))
    # merge_models lists the default domain once per input model; tools that look it up
    # (onnxruntime's quantizer) need one entry per domain
    versions: dict[str, int] = {}
    for op in merged.opset_import:
        versions[op.domain] = max(versions.get(op.domain, 0), op.version)
    del merged.opset_import[:]
    merged.opset_import.extend(onnx.helper.make_opsetid(d, v) for d, v in versions.items())
    return merged


def prefixed(model: onnx.ModelProto, prefix: str) -> onnx.ModelProto:
    """A copy of ``model`` with every internal value and node name prefixed, subgraphs included.

    ``onnx.compose.add_prefix`` leaves a ``Loop`` body's references to outer-scope values
    unrenamed (the recurrent SNN's ``W_rec`` inside its time loop), which breaks the graph.
    """
    out = onnx.ModelProto()
    out.CopyFrom(model)
    g = out.graph
    keep = {v.name for v in g.input} | {v.name for v in g.output}
    names: set[str] = set()
    _collect(g, names)
    mapping = {n: prefix + n for n in names if n and n not in keep}
    _rename(g, mapping, prefix)
    return out


def _subgraphs(graph: onnx.GraphProto):
    for node in graph.node:
        for attr in node.attribute:
            if attr.HasField("g"):
                yield attr.g
            yield from attr.graphs


def _collect(graph: onnx.GraphProto, names: set[str]) -> None:
    for node in graph.node:
        names.update(node.input)
        names.update(node.output)
    names.update(v.name for v in [*graph.input, *graph.output, *graph.value_info])
    names.update(t.name for t in graph.initializer)
    for sub in _subgraphs(graph):
        _collect(sub, names)


def _rename(graph: onnx.GraphProto, mapping: dict[str, str], prefix: str) -> None:
    for node in graph.node:
        node.name = prefix + node.name if node.name else node.name
        ins, outs = (
            [mapping.get(x, x) for x in node.input],
            [mapping.get(x, x) for x in node.output],
        )
        del node.input[:]
        node.input.extend(ins)
        del node.output[:]
        node.output.extend(outs)
    for v in [*graph.input, *graph.output, *graph.value_info]:
        v.name = mapping.get(v.name, v.name)
    for t in graph.initializer:
        t.name = mapping.get(t.name, t.name)
    for sub in _subgraphs(graph):
        _rename(sub, mapping, prefix)

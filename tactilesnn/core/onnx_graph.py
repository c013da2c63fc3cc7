"""torch -> ONNX conversion and graph composition shared by every exported component."""

from __future__ import annotations

import hashlib
import inspect
import logging
import os
import tempfile
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch
from torch import nn

OPSET = 17

#: custom torch ops (``namespace::name``) -> their ONNX translation for the ``torch.export``-based
#: exporter (onnxscript nodes), registered by the component that defines the op
if TYPE_CHECKING:  # onnx is imported where a graph is built or read (~1.4 s)
    import onnx

_TRANSLATIONS: dict[str, Callable] = {}


def register_translation(op_name: str, translation: Callable) -> None:
    """Export the custom torch op ``op_name`` (``namespace::name``, its default overload) with
    ``translation`` in :func:`exported_to_onnx`."""
    _TRANSLATIONS[op_name] = translation


def _translation_table() -> dict:
    table = {}
    for name, fn in _TRANSLATIONS.items():
        ns, op = name.split("::")
        table[getattr(getattr(torch.ops, ns), op).default] = fn
    return table


#: the environment variable that chooses the exporter (:func:`chosen_exporter`)
EXPORTER_ENV = "TACTILESNN_ONNX_EXPORTER"
#: ``torch.export``: the supported ``torch.export``-based exporter (the default); ``torchscript``:
#: the deprecated TorchScript-based one, 5-15x faster to export (the test suite's choice, where
#: dedicated tests cover both); a component marked ``onnx_exportable = False`` (none is now)
#: or one that torch.export refuses takes the TorchScript-based one
EXPORTERS = ("torch.export", "torchscript")

log = logging.getLogger(__name__)


def chosen_exporter(exporter: str | None = None) -> str:
    """``exporter``, else :data:`EXPORTER_ENV`'s value, else ``torch.export``; checked."""
    name = exporter or os.environ.get(EXPORTER_ENV) or EXPORTERS[0]
    if name not in EXPORTERS:
        source = "" if exporter else f" (from {EXPORTER_ENV})"
        raise ValueError(
            f"unknown ONNX exporter {name!r}{source}; choose one of: {', '.join(EXPORTERS)}"
        )
    return name


def component_to_onnx(
    module: nn.Module,
    args: tuple,
    inputs: Sequence[str],
    outputs: Sequence[str],
    scripted: bool = False,
    exporter: str | None = None,
    opset: int = OPSET,
    exportable: bool = True,
) -> onnx.ModelProto:
    """One component's graph (dynamic batch axis 0 on every input): :func:`exported_to_onnx`
    (opset at least 18) unless the component is not ``exportable`` (traces only as a scripted
    module), :func:`chosen_exporter` is ``torchscript``, ``onnxscript`` is not installed or
    torch.export fails on it (logged), then :func:`torch_to_onnx` (``scripted``: scripted
    first)."""
    if exportable and chosen_exporter(exporter) == "torch.export":
        with torch.no_grad():  # builds cached tensors: torch.export refuses tensors assigned
            module(*args)  # while it traces
        try:
            return exported_to_onnx(module, args, inputs, outputs, opset)
        except ImportError as e:
            log.warning("onnxscript is not installed (%s): the TorchScript-based exporter", e)
        except Exception as e:  # a component torch.export cannot trace (a user's own, say)
            first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
            log.warning("torch.export could not export %s (%s): the TorchScript-based exporter "
                        "writes it; the export is verified against torch either way",
                        type(module).__name__, first[:200])  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        return torch_to_onnx(
            module, args, Path(tmp) / "part.onnx", inputs, outputs, scripted, opset
        )


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
    import onnx

    from .onnx_shapes import fold_static_shapes

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
    batch_axes: Sequence[int] | None = None,
) -> onnx.ModelProto:
    """Export ``module`` with the ``torch.export``-based exporter (``dynamo=True``, the
    supported path; needs ``onnxscript``) with a dynamic batch axis on every input (axis 0, or
    ``batch_axes[i]`` of input ``i``), optimised, its static sizes folded as
    :func:`torch_to_onnx` does; custom ops through their :func:`register_translation`. For graphs
    without data-dependent loops."""
    batch = torch.export.Dim("batch")
    axes = list(batch_axes) if batch_axes is not None else [0] * len(args)
    shapes = _grouped_like_forward(module, [{a: batch} for a in axes])
    # its registry logs a warning per torchvision op it cannot register (no torchvision here),
    # its optimiser a line per pass at INFO (the CLI logs at INFO), the tracer an error line
    # for a scan's unsupported classification that it then handles
    quiet = [logging.getLogger(n) for n in QUIET_LOGGERS]
    levels = [q.level for q in quiet]
    for q in quiet:
        q.setLevel(logging.CRITICAL)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            program = torch.onnx.export(module, tuple(args), input_names=list(inputs),
                                        output_names=list(outputs), dynamic_shapes=shapes,
                                        dynamo=True, opset_version=max(opset, 18), verbose=False,
                                        optimize=False,
                                        custom_translation_table=_translation_table())  # fmt: skip
            # optimised once, here: the exporter's own pass folds only inputs up to 8,192
            # values (a slice of a 100-step decay matrix, 10,000, stayed three nodes); running
            # both cost 0.2 s more per default-task export
            program.model = optimize_exactly(program.model)
    finally:
        for q, level in zip(quiet, levels, strict=True):
            q.setLevel(level)
    from .onnx_shapes import fold_static_shapes

    model = program.model_proto
    _strip_trace_metadata(model.graph)
    fold_static_shapes(model)
    literal_zero_reshapes(model)
    merge_constants(model)
    return model


def optimize_exactly(model: Any) -> Any:
    """``onnxscript.optimizer.optimize`` (constant folding up to :data:`FOLD_INPUT_VALUES` /
    :data:`FOLD_OUTPUT_VALUES` values, its rewrite rules) with its no-op rules made exact.

    Its rules ``x + 0``, ``x - 0``, ``x * 1``, ``x / 1`` match a scalar constant within an
    absolute tolerance of 1e-8 (``math.isclose(..., abs_tol=1e-8)``): ``x + 1e-30``, a floor
    that keeps ``0 / (0 + floor)`` finite, was removed and a constant window's level code
    became NaN in onnxruntime (and ``x * (1 + 1e-9)`` would become ``x``). Here those four
    rules fire only where the constant is exactly 0 or 1; every other rule is the library's."""
    import onnxscript.optimizer
    from onnxscript import rewriter
    from onnxscript.rewriter.rules.common import _no_op

    default = rewriter._DEFAULT_REWRITE_RULES
    tolerant = set(_no_op.rules) - {_no_op.dropout_zero_rule, _no_op.dropout_inference_rule}
    rules = tuple(r for r in default if r not in tolerant) + _exact_no_op_rules()
    rewriter._DEFAULT_REWRITE_RULES = rules  # read by the optimiser when it runs
    try:
        return onnxscript.optimizer.optimize(model, input_size_limit=FOLD_INPUT_VALUES,
                                             output_size_limit=FOLD_OUTPUT_VALUES)  # fmt: skip
    finally:
        rewriter._DEFAULT_REWRITE_RULES = default


def _exact_no_op_rules() -> tuple:
    """``x + 0``, ``0 + x``, ``x - 0``, ``x * 1``, ``1 * x``, ``x / 1`` -> ``x`` where the scalar
    constant is exactly 0 or 1 (see :func:`optimize_exactly`)."""
    from onnxscript.rewriter import _ir_utils
    from onnxscript.rewriter._rewrite_rule import RewriteRule

    def exactly(target: float):
        def condition(context: object, x: object, c: object, **_: object) -> bool:
            return _ir_utils.get_singleton_value(c, rank=0) == target

        return condition

    def identity(op: Any, x: Any, **_: object) -> Any:
        return op.Identity(x)

    pairs = [(lambda op, x, c: op.Add(x, c), 0.0), (lambda op, x, c: op.Add(c, x), 0.0),
             (lambda op, x, c: op.Sub(x, c), 0.0), (lambda op, x, c: op.Mul(x, c), 1.0),
             (lambda op, x, c: op.Mul(c, x), 1.0), (lambda op, x, c: op.Div(x, c), 1.0)]  # fmt: skip
    return tuple(RewriteRule(target, identity, exactly(value)) for target, value in pairs)


#: loggers silenced while the torch.export-based exporter runs (its failures still raise)
QUIET_LOGGERS = ("torch.onnx._internal.exporter._registration", "onnxscript", "onnx_ir",
                 "torch.export._trace")  # fmt: skip

#: constant folding limits (values) of the torch.export-based path's optimiser
FOLD_INPUT_VALUES = 1 << 20
FOLD_OUTPUT_VALUES = 1 << 20


def _strip_trace_metadata(graph: onnx.GraphProto) -> None:
    """Drops the tracer's per-node and per-value records (source lines, module paths): nearly
    half of a small graph's bytes (a small GWT + tempotron graph: 294 kB -> 153 kB)."""
    import onnx

    for node in graph.node:
        del node.metadata_props[:]
        node.doc_string = ""
        for attr in node.attribute:
            if attr.type == onnx.AttributeProto.GRAPH:
                _strip_trace_metadata(attr.g)
    for v in (*graph.input, *graph.output, *graph.value_info):
        del v.metadata_props[:]
        v.doc_string = ""
    for t in graph.initializer:
        del t.metadata_props[:]


def _grouped_like_forward(module: nn.Module, specs: list) -> tuple:
    """Per-argument ``specs`` grouped as ``module.forward``'s signature takes them (a ``*args``
    parameter takes the rest as one tuple), the structure ``torch.export`` matches."""
    params = list(inspect.signature(module.forward).parameters.values())
    for i, p in enumerate(params):
        if p.kind is inspect.Parameter.VAR_POSITIONAL:
            return (*specs[:i], tuple(specs[i:]))
    return tuple(specs)


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
    import onnx

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


def operator_nodes(model: onnx.ModelProto) -> int:
    """Nodes of the main graph that compute (``Constant`` nodes, which one exporter writes for
    what the other stores as initializers, not counted)."""
    return sum(n.op_type != "Constant" for n in model.graph.node)


def chain(
    first: onnx.ModelProto,
    second: onnx.ModelProto,
    io: Sequence[tuple[str, str]],
    tags: tuple[str, str] = ("a/", "b/"),
) -> onnx.ModelProto:
    """Feed outputs of ``first`` into inputs of ``second`` (``io`` pairs); names stay unprefixed
    on the graph boundary, internal names get ``tags``."""
    import onnx

    a, b = _same_versions(prefixed(first, tags[0]), prefixed(second, tags[1]))
    merged = onnx.compose.merge_models(a, b, io_map=list(io))
    # merge_models lists the default domain once per input model; tools that look it up
    # (onnxruntime's quantizer) need one entry per domain
    versions: dict[str, int] = {}
    for op in merged.opset_import:
        versions[op.domain] = max(versions.get(op.domain, 0), op.version)
    del merged.opset_import[:]
    merged.opset_import.extend(onnx.helper.make_opsetid(d, v) for d, v in versions.items())
    return merged


def _same_versions(
    a: onnx.ModelProto, b: onnx.ModelProto
) -> tuple[onnx.ModelProto, onnx.ModelProto]:
    """``a`` and ``b`` at the higher of their default-domain opsets and IR versions (parts from
    the two exporters: 17 and 18), converted where lower, so that they merge into one graph."""
    import onnx.version_converter

    def opset(m: onnx.ModelProto) -> int:
        return {o.domain: o.version for o in m.opset_import}.get("", 0)

    want, ir = max(opset(a), opset(b)), max(a.ir_version, b.ir_version)
    out = []
    for m in (a, b):
        if opset(m) < want:
            m = onnx.version_converter.convert_version(m, want)
        m.ir_version = ir
        out.append(m)
    return out[0], out[1]


def prefixed(model: onnx.ModelProto, prefix: str) -> onnx.ModelProto:
    """A copy of ``model`` with every internal value and node name prefixed, subgraphs included.

    ``onnx.compose.add_prefix`` leaves a ``Loop`` body's references to outer-scope values
    unrenamed (the recurrent SNN's ``W_rec`` inside its time loop), which breaks the graph.
    """
    import onnx

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

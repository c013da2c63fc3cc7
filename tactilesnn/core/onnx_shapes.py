"""Fold the run-time size arithmetic of a traced graph into constants.

A traced ``x.reshape(b, c, n)`` becomes ``Shape -> Gather -> Unsqueeze -> Concat -> Reshape``
even where only the batch axis is dynamic. onnxruntime folds nodes of constant inputs only, so
each such chain runs on every call (~0.35 us a node on one thread; the gated GWT + SNN graph had
~130 of them). With ONNX shape inference (symbolic batch, value propagation):

* ``Shape``, and ``Gather`` / ``Slice`` of a ``Shape``, that select static axes only become
  constants, and so do small nodes whose inputs are all constant (evaluated by
  ``onnx.reference``): the size arithmetic between a static size and the node using it;
* a ``Reshape`` whose output has at most one non-static axis gets a constant target, ``-1``
  on that axis (the same result: the element count fixes it; every static axis is > 0, so
  ``-1`` is never ambiguous, also for zero rows);

then nodes whose outputs nothing reads are dropped. The graph's inputs, outputs and results
are unchanged (every export is still checked against torch by ``export.onnx.verify``).
"""

from __future__ import annotations

import numpy as np
import onnx
from onnx import helper, numpy_helper

from .onnx_prune import prune_to_outputs

#: fixpoint rounds: each makes more shapes static for the next inference
MAX_ROUNDS = 4


def fold_static_shapes(model: onnx.ModelProto) -> int:
    """Rewrite ``model`` in place as described in the module docstring; returns how many nodes
    were made constant or given a constant target (0 when shape inference fails: unchanged)."""
    total = 0
    for _ in range(MAX_ROUNDS):
        try:
            inferred = onnx.shape_inference.infer_shapes(model, data_prop=True)
        except Exception:  # an op the inference does not know: leave the graph as it is
            return total
        shapes = _static_dims(inferred.graph)
        consts = _constants(model.graph)
        changed = _fold_constant_nodes(model.graph, consts)
        sizes = {n.output[0]: _shape_dims(n, shapes) for n in model.graph.node
                 if n.op_type == "Shape"}  # fmt: skip
        producers = {o: n for n in model.graph.node for o in n.output}
        for node in model.graph.node:
            value = _folded_shape_value(node, sizes, consts)
            if value is not None:
                _make_constant(node, value)
                consts[node.output[0]] = value
                changed += 1
            elif node.op_type == "Reshape" and node.input[1] not in consts:
                target = _reshape_target(shapes.get(node.output[0]))
                if target is None:
                    target = _concat_target(producers.get(node.input[1]), consts, shapes)
                if target is not None:
                    name = node.output[0] + "__target"
                    model.graph.initializer.append(numpy_helper.from_array(target, name))
                    consts[name] = target
                    node.input[1] = name
                    changed += 1
        prune_to_outputs(model.graph)  # drop what nothing reads any more
        total += changed
        if not changed:
            break
    return total


def _static_dims(graph: onnx.GraphProto) -> dict[str, list[int | None]]:
    """Every value's inferred shape, ``None`` for an axis of unknown size."""
    out: dict[str, list[int | None]] = {}
    for v in [*graph.input, *graph.value_info, *graph.output]:
        t = v.type.tensor_type
        if t.HasField("shape"):
            out[v.name] = [d.dim_value if d.HasField("dim_value") else None for d in t.shape.dim]
    for init in graph.initializer:
        out[init.name] = list(init.dims)
    return out


def _constants(graph: onnx.GraphProto) -> dict[str, np.ndarray]:
    """Initializers (not those also listed as graph inputs: a caller may override them) and
    ``Constant`` nodes' values, by name."""
    inputs = {i.name for i in graph.input}
    out = {i.name: numpy_helper.to_array(i) for i in graph.initializer if i.name not in inputs}
    for node in graph.node:
        if node.op_type == "Constant":
            for a in node.attribute:
                if a.name == "value":
                    out[node.output[0]] = numpy_helper.to_array(a.t)
    return out


#: size arithmetic is folded, not weights: nodes reading more elements than this stay
MAX_FOLD_ELEMENTS = 4096
#: ops never folded (random, or sized by their data)
NO_FOLD = {"RandomNormal", "RandomUniform", "RandomNormalLike", "RandomUniformLike",
           "Multinomial", "Bernoulli", "NonZero"}  # fmt: skip


def _fold_constant_nodes(graph: onnx.GraphProto, consts: dict[str, np.ndarray]) -> int:
    """Replace each small node of the default domain whose inputs are all constant by its value
    (computed by ``onnx.reference``, the specification's own implementation); returns how
    many. Such chains are what tracing leaves between a folded size and the node using it."""
    from onnx.reference import ReferenceEvaluator

    changed = 0
    for node in graph.node:
        if node.op_type == "Constant" or node.domain not in ("", "ai.onnx"):
            continue
        inputs = [i for i in node.input if i]
        if (node.op_type in NO_FOLD or len(node.output) != 1 or not inputs
                or any(i not in consts for i in inputs)
                or sum(consts[i].size for i in inputs) > MAX_FOLD_ELEMENTS
                or any(a.HasField("g") or a.graphs for a in node.attribute)):  # fmt: skip
            continue
        try:
            (value,) = ReferenceEvaluator(node).run(None, {i: consts[i] for i in inputs})
        except Exception:  # an op the reference does not implement: leave it to run
            continue
        value = np.asarray(value)
        if value.size > MAX_FOLD_ELEMENTS:
            continue
        _make_constant(node, value)
        consts[node.output[0]] = value
        changed += 1
    return changed


def _shape_dims(
    node: onnx.NodeProto, shapes: dict[str, list[int | None]]
) -> list[int | None] | None:
    """The sizes a ``Shape`` node returns (``None`` where unknown), its ``start`` / ``end``
    applied; None when its input's rank is unknown."""
    dims = shapes.get(node.input[0])
    if dims is None:
        return None
    attrs = {a.name: a.i for a in node.attribute}
    return dims[slice(attrs.get("start", 0), attrs.get("end", len(dims)))]


def _folded_shape_value(
    node: onnx.NodeProto,
    sizes: dict[str, list[int | None] | None],
    consts: dict[str, np.ndarray],
) -> np.ndarray | None:
    """The constant value of a ``Shape`` node, or of a ``Gather`` / ``Slice`` (constant
    indices) of a ``Shape`` node's output, when every size it selects is static; else None.
    ``sizes``: each ``Shape`` node's output, by name (:func:`_shape_dims`)."""
    if node.op_type == "Shape":
        sel = sizes.get(node.output[0])
    elif node.op_type in ("Gather", "Slice") and node.input[0] in sizes:
        dims = sizes[node.input[0]]
        if dims is None or any(i and i not in consts for i in node.input[1:]):
            return None
        if node.op_type == "Gather":
            sel = np.asarray(dims, dtype=object)[consts[node.input[1]]]
            sel = sel.tolist() if isinstance(sel, np.ndarray) else sel
        else:
            sel = _slice_1d(dims, [consts.get(i) if i else None for i in node.input[1:]])
    else:
        return None
    known = sel is not None and all(d is not None for d in np.atleast_1d(np.asarray(sel, object)))
    return np.asarray(sel, dtype=np.int64) if known else None


def _slice_1d(dims: list[int | None], args: list[np.ndarray | None]) -> list[int | None] | None:
    """``dims[start:end:step]`` for a ``Slice`` on axis 0 with constant arguments, else None."""
    starts, ends, axes, steps = (args + [None] * 4)[:4]
    if axes is not None and [int(a) for a in axes.reshape(-1)] not in ([0], [-1]):
        return None
    if starts is None or ends is None or starts.size != 1 or ends.size != 1:
        return None
    step = 1 if steps is None else int(steps.reshape(-1)[0])
    if step < 1:  # ONNX clamps reversed slices differently from Python: left to run
        return None
    end = int(ends.reshape(-1)[0])
    end = min(end, len(dims)) if end >= 0 else end
    return dims[int(starts.reshape(-1)[0]) : end : step]


def _reshape_target(dims: list[int | None] | None) -> np.ndarray | None:
    """A constant ``Reshape`` target for an output of shape ``dims`` (``-1`` on its one unknown
    axis), or None when two axes are unknown or a static axis is 0."""
    if dims is None or sum(d is None for d in dims) > 1:
        return None
    if any(d is not None and d <= 0 for d in dims):
        return None
    return np.asarray([-1 if d is None else d for d in dims], dtype=np.int64)


def _concat_target(
    node: onnx.NodeProto | None,
    consts: dict[str, np.ndarray],
    shapes: dict[str, list[int | None]],
) -> np.ndarray | None:
    """A constant target for a ``Reshape`` whose target is ``Concat`` of constant pieces (all
    entries > 0) and one run-time size (one element): that size becomes ``-1``. Else None."""
    if node is None or node.op_type != "Concat":
        return None
    pieces: list[np.ndarray] = []
    dynamic = 0
    for name in node.input:
        if name in consts:
            piece = consts[name].reshape(-1).astype(np.int64)
            if (piece <= 0).any():  # a -1 or 0 of its own
                return None
            pieces.append(piece)
        elif shapes.get(name) == [1]:
            pieces.append(np.array([-1], dtype=np.int64))
            dynamic += 1
        else:
            return None
    return np.concatenate(pieces) if dynamic == 1 else None


def _make_constant(node: onnx.NodeProto, value: np.ndarray) -> None:
    out = node.output[0]
    del node.input[:]
    del node.output[:]
    del node.attribute[:]
    node.op_type, node.domain = "Constant", ""
    node.output.append(out)
    node.attribute.append(helper.make_attribute("value", numpy_helper.from_array(value)))

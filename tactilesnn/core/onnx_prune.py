"""Cut an ONNX graph down to what some of its outputs need (no torch: the service uses it)."""

from __future__ import annotations


def prune_to_outputs(graph, outputs: list[str] | None = None) -> int:
    """Keep only the nodes and initializers that ``outputs`` (default: the graph's own outputs)
    need, and only those graph outputs; ``graph`` is an ``onnx.GraphProto``, changed in place.
    Returns how many nodes were removed."""
    wanted = {o.name for o in graph.output} if outputs is None else set(outputs)
    needed, kept = set(wanted), []
    for node in reversed(graph.node):
        if any(o in needed for o in node.output if o):
            kept.append(node)
            needed.update(names_read(node))
    removed = len(graph.node) - len(kept)
    if removed:
        kept.reverse()
        del graph.node[:]
        graph.node.extend(kept)
    outs = [o for o in graph.output if o.name in wanted]
    if len(outs) != len(graph.output):
        del graph.output[:]
        graph.output.extend(outs)
    inits = [i for i in graph.initializer if i.name in needed]
    if len(inits) != len(graph.initializer):
        del graph.initializer[:]
        graph.initializer.extend(inits)
    return removed


def names_read(node) -> set[str]:
    """The value names ``node`` reads: its inputs and, for a node with subgraphs (``Loop``,
    ``If``, ``Scan``), every name their nodes read, at any depth (a body may read the outer
    graph's values)."""
    names = {i for i in node.input if i}
    for attr in node.attribute:
        for g in [attr.g] if attr.HasField("g") else list(attr.graphs):
            for inner in g.node:
                names |= names_read(inner)
    return names

"""The graph a Tensor remembers, made visible: which ops made it, from which inputs, with
which shapes, and which inputs will receive a gradient.

    nodes = graph(loss, names=dict(net.named_parameters()))   # inputs first
    print(graph_text(loss, names))                            # one line per tensor
    open("g.dot", "w").write(graph_dot(loss, names))          # Graphviz: dot -Tpng g.dot

Every tensor ``y`` made by an op on inputs that need gradients keeps its ``op`` name and
its parents (``Tensor.from_op``); ``backward`` walks exactly this graph from ``y`` back to
the leaves. Three kinds of node:

    leaf      made by you with requires_grad=True (a weight): backward fills its .grad
    constant  an input that needs no gradient (data, a zero state): backward stops there
    op        the output of an op: it passes the gradient on to its parents

Under ``no_grad()`` no graph is recorded, so there is nothing to walk: the output is
a lone constant. (The Pillow picture of a graph is ``minid3rqn.diagrams.graph_image``.)
"""
from __future__ import annotations

from dataclasses import dataclass

from .engine import Tensor


@dataclass
class Node:
    index: int                   # position in the walk: parents come before children
    kind: str                    # "leaf", "constant" or "op"
    op: str                      # the op that made it ("" for an input)
    name: str                    # its name in ``names`` ("" if unnamed)
    shape: tuple
    dtype: str
    parents: list                # indices of the inputs of an op (empty for inputs)

    def title(self) -> str:
        """"c' = add(#16, #21)" or "matmul(#3, #4)" for an op; an input's name (or
        "weight" / "input")."""
        if self.kind == "op":
            call = f"{self.op}({', '.join(f'#{p}' for p in self.parents)})"
            return f"{self.name} = {call}" if self.name else call
        return self.name or ("weight" if self.kind == "leaf" else "input")


def _names(names) -> dict:
    """{id(tensor): name} from a {name: tensor} mapping (e.g. ``net.named_parameters()``)."""
    if names is None:
        return {}
    items = names.items() if hasattr(names, "items") else names
    return {id(t): name for name, t in items if isinstance(t, Tensor)}


def graph(root: Tensor, names=None) -> list[Node]:
    """Every tensor ``root`` was computed from, parents before children, ``root`` last.

    ``names``: {name: tensor} for the inputs (and any op output) to label; the others are
    numbered. Unlike ``backward``'s walk this one also lists the constants (inputs that
    need no gradient), so the picture shows everything the op read.
    """
    if not isinstance(root, Tensor):
        raise TypeError(f"graph: root must be a Tensor; got {type(root).__name__}")
    label = _names(names)
    order, index, stack = [], {}, [(root, False)]
    while stack:                           # an explicit stack: graphs can be deep
        node, parents_done = stack.pop()
        if id(node) in index:
            continue
        if parents_done:
            index[id(node)] = len(order)
            order.append(node)
            continue
        stack.append((node, True))
        for parent in reversed(node._parents):
            if id(parent) not in index:
                stack.append((parent, False))
    nodes = []
    for t in order:
        kind = "op" if t._parents else ("leaf" if t.requires_grad else "constant")
        nodes.append(Node(index[id(t)], kind, t.op if kind == "op" else "",
                          label.get(id(t), ""), tuple(t.shape), str(t.dtype),
                          [index[id(p)] for p in t._parents]))
    return nodes


KIND_TEXT = {"leaf": "needs a gradient (.grad)", "constant": "no gradient", "op": ""}


def graph_text(root: Tensor, names=None) -> str:
    """The graph of ``root`` as text, one line per tensor, inputs first::

        #0  x                    (2, 3)    float64  no gradient
        #1  weight_ih            (16, 3)   float64  needs a gradient (.grad)
        #2  transpose(#1)        (3, 16)   float64
        #3  matmul(#0, #2)       (2, 16)   float64
    """
    nodes = graph(root, names)
    width = max(len(n.title()) for n in nodes)
    shapes = max(len(str(n.shape)) for n in nodes)
    lines = [f"#{n.index:<3d} {n.title():<{width}}  {str(n.shape):<{shapes}}  {n.dtype}  "
             f"{KIND_TEXT[n.kind]}".rstrip() for n in nodes]
    ops = sum(n.kind == "op" for n in nodes)
    leaves = sum(n.kind == "leaf" for n in nodes)
    rest = len(nodes) - ops - leaves
    return "\n".join(lines + [f"({ops} ops; {leaves} of the inputs need a gradient, "
                              f"{rest} {'does' if rest == 1 else 'do'} not)"])


def graph_dot(root: Tensor, names=None) -> str:
    """The graph of ``root`` in Graphviz's DOT language (``dot -Tpng g.dot -o g.png``):
    ops as blue boxes, inputs that need a gradient orange, the others grey."""
    colour = {"op": "#e8f0fc", "leaf": "#fde3c8", "constant": "#eeeeee"}
    lines = ["digraph autograd {", "  rankdir=TB;",
             '  node [shape=box, style="rounded,filled", fontname="Helvetica"];']
    for n in graph(root, names):
        text = n.title() if n.kind != "op" else " = ".join(filter(None, (n.name, n.op)))
        lines.append(f'  n{n.index} [label="{text}\\n{n.shape}", fillcolor="{colour[n.kind]}"];')
        lines += [f"  n{p} -> n{n.index};" for p in n.parents]
    return "\n".join(lines + ["}"])

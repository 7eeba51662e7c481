"""The graph walker: what it lists is what ``backward`` walks, plus the constants."""
import numpy as np
import pytest

from minid3rqn import autograd as ag
from minid3rqn.autograd import Tensor

pytestmark = pytest.mark.autograd


def small():
    x = Tensor(np.ones((2, 3)))                              # data: no gradient
    w = Tensor(np.full((3, 4), 0.5), requires_grad=True)
    b = Tensor(np.zeros(4), requires_grad=True)
    h = ag.relu(x @ w + b)
    return ag.sum(h * h), {"x": x, "w": w, "b": b, "h": h}


def test_the_walk_lists_every_tensor_once_parents_first():
    loss, names = small()
    nodes = ag.graph(loss, names)
    assert [n.op or n.name for n in nodes] == ["x", "w", "matmul", "b", "add", "relu", "mul",
                                               "sum"]
    assert [n.kind for n in nodes[:2]] == ["constant", "leaf"] and nodes[-1].kind == "op"
    for n in nodes:
        assert all(p < n.index for p in n.parents)
    assert nodes[5].name == "h" and nodes[5].title() == "h = relu(#4)"
    assert nodes[6].parents == [5, 5]                         # h * h reads h twice
    assert nodes[2].shape == (2, 4) and nodes[-1].shape == ()


def test_what_the_walk_calls_a_leaf_is_what_backward_fills():
    loss, names = small()
    leaves = {n.name for n in ag.graph(loss, names) if n.kind == "leaf"}
    loss.backward()
    assert leaves == {k for k, t in names.items() if t.grad is not None} == {"w", "b"}


def test_text_and_dot_show_every_node_and_edge():
    loss, names = small()
    text = ag.graph_text(loss, names)
    assert len(text.split("\n")) == 8 + 1
    assert "needs a gradient" in text.split("\n")[1] and "no gradient" in text.split("\n")[0]
    assert text.endswith("(5 ops; 2 of the inputs need a gradient, 1 does not)")
    dot = ag.graph_dot(loss, names)
    assert dot.startswith("digraph") and dot.count("->") == 8 and dot.count("[label=") == 8


def test_a_deep_graph_does_not_recurse_and_no_grad_records_nothing():
    x = Tensor(np.ones(2), requires_grad=True)
    y = x
    for _ in range(5000):
        y = y * 1.0
    assert len(ag.graph(y)) == 5000 + 5000 + 1              # each step: a constant and a mul
    with ag.no_grad():
        z = x * 2.0
    assert [n.kind for n in ag.graph(z)] == ["constant"]
    with pytest.raises(TypeError, match="root must be a Tensor"):
        ag.graph(np.ones(2))

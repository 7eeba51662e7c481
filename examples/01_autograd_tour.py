# %% [markdown]
# # 01: A tour of the autograd engine
#
# Four steps, in seconds:
#
# 1. Build a small graph by hand and read its gradients.
# 2. Check a backward pass with gradcheck, and watch it catch a wrong one.
# 3. Train a tiny network to fit a curve with Adam.
# 4. See the graph autograd records for two real pieces of the D3RQN: one LSTM step
#    and the dueling head (text, a picture and Graphviz DOT in ``--out``).
#
#     python examples/01_autograd_tour.py [--smoke] [--out runs/examples/01_autograd_tour]

# %%
"""A tour of the autograd engine in four steps (runs in seconds)."""
import argparse
import sys
import textwrap
from pathlib import Path

import numpy as np

from minid3rqn import autograd as ag
from minid3rqn import diagrams
from minid3rqn.autograd import GradcheckError, Tensor, gradcheck
from minid3rqn.autograd.losses import mse_loss
from minid3rqn.autograd.optim import Adam
from minid3rqn.nets import Linear, Sequential, Tanh


# %% [markdown]
# ## 1. A graph by hand
# Every op remembers its inputs; `backward` walks that graph from the loss to the leaves.
# `ag.graph_text` prints the graph: which op made each tensor, from which inputs, and
# which inputs will receive a gradient.

# %%
def step1_a_graph_by_hand():
    print("1. y = tanh(w * x + b), L = y^2, at x = 2, w = 0.5, b = -0.3")
    x = Tensor(np.array(2.0))
    w = Tensor(np.array(0.5), requires_grad=True)
    b = Tensor(np.array(-0.3), requires_grad=True)
    y = ag.tanh(w * x + b)
    loss = y * y
    loss.backward()
    # By hand: dL/dw = 2y (1 - y^2) x and dL/db = 2y (1 - y^2)
    yv = np.tanh(0.5 * 2.0 - 0.3)
    print(f"   dL/dw = {w.grad:.6f}   (by hand: {2 * yv * (1 - yv**2) * 2.0:.6f})")
    print(f"   dL/db = {b.grad:.6f}   (by hand: {2 * yv * (1 - yv**2):.6f})")
    print(textwrap.indent(ag.graph_text(loss, {"x": x, "w": w, "b": b, "y": y, "L": loss}),
                          "   "))


# %% [markdown]
# ## 2. gradcheck
# A backward pass against central differences, in float64: it passes for a right
# backward and names the wrong one.

# %%
def step2_gradcheck():
    print("2. gradcheck compares backward with central differences (float64)")
    rng = np.random.default_rng(0)
    gradcheck(lambda a, m: ag.sigmoid(a @ m).sum(axis=1), [rng.standard_normal((3, 4)),
                                                            rng.standard_normal((4, 2))])
    print("   sigmoid(a @ m).sum(axis=1): gradients agree")

    def bad_square(x):  # forward x^2, backward claims x (should be 2x)
        return Tensor.from_op(x.data ** 2, (x,), lambda g: (g * x.data,), "bad_square")
    try:
        gradcheck(bad_square, [rng.standard_normal(5)])
    except GradcheckError as e:
        print(f"   a wrong backward is caught: {e}")


# %% [markdown]
# ## 3. Training
# A 1-32-32-1 tanh network fits a curve with Adam: the same loop, in miniature, as every
# training in the project.

# %%
def step3_train(steps: int):
    print(f"3. a 1-32-32-1 tanh network fits y = sin(2x) + x/2 with Adam ({steps} steps)")
    rng = np.random.default_rng(0)
    x = rng.uniform(-2, 2, (256, 1)).astype(np.float32)
    y = (np.sin(2 * x) + 0.5 * x).astype(np.float32)
    net = Sequential(Linear(1, 32, rng=1), Tanh(), Linear(32, 32, rng=2), Tanh(),
                     Linear(32, 1, rng=3))
    opt = Adam(net.parameters(), lr=1e-2)
    for step in range(steps + 1):
        loss = mse_loss(net(Tensor(x)), y)
        opt.zero_grad()
        loss.backward()
        opt.step()
        if step % max(steps // 5, 1) == 0:
            print(f"   step {step:4d}  mse {loss.item():.5f}")


# %% [markdown]
# ## 4. The graph of two real pieces of the D3RQN
# One step of its LSTM, written with basic ops (the library computes the same in one
# fused op with a hand-derived backward: `autograd/lstm.py`), and its dueling head,
# `QNet.head`, as it is. The weights are leaves that need a gradient; the features, the
# zero state and the LSTM output here are inputs that need none.

# %%
def step4_see_the_graph(out: Path):
    print("4. the graphs autograd records for two pieces of the shipped D3RQN")
    out.mkdir(parents=True, exist_ok=True)
    for title, build, name in (
            ("one LSTM step, written with basic ops", diagrams.lstm_step_graph, "lstm_step"),
            ("the dueling head, QNet.head", diagrams.dueling_head_graph, "dueling_head")):
        root, names = build()
        print(f"   {title}:")
        print(textwrap.indent(ag.graph_text(root, names), "   "))
        (out / f"graph_{name}.dot").write_text(ag.graph_dot(root, names))
        diagrams.graph_image(ag.graph(root, names), title).save(out / f"graph_{name}.png")
    print(f"   pictures and Graphviz DOT: {out}/graph_*.png, graph_*.dot")


# %%
if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--smoke", action="store_true", help="a few steps only (tests)")
    parser.add_argument("--out", default="runs/examples/01_autograd_tour",
                        help="folder for the graph pictures")
    args = parser.parse_args([] if "ipykernel" in sys.modules else None)   # a notebook: defaults
    step1_a_graph_by_hand()
    step2_gradcheck()
    step3_train(20 if args.smoke else 500)
    step4_see_the_graph(Path(args.out))

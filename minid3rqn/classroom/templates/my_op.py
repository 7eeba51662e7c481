"""Exercise 6: a new autograd op, with its backward pass. This file is the one place to change.

Implement leaky ReLU:

    y = x            if x > 0
    y = slope * x    otherwise            dy/dx = 1 if x > 0 else slope

Follow the pattern of every op in minid3rqn/autograd/engine.py (look at `relu`):
compute the forward with NumPy on ``x.data``, then return
``Tensor.from_op(y, (x,), vjp, "leaky_relu")`` where ``vjp(g)`` returns a tuple with
dL/dx given g = dL/dy. Do not build it from other Tensor ops (ag.where, ag.maximum...):
the point is to write the backward yourself.

    python -m minid3rqn check op      (forward values, dtypes, and gradcheck)
"""
import numpy as np

from minid3rqn.autograd import Tensor, as_tensor


def leaky_relu(x, slope=0.01):
    """y = x if x > 0 else slope * x;  dy/dx = 1 if x > 0 else slope."""
    x = as_tensor(x)
    raise NotImplementedError("exercise 6: write the forward and the backward of leaky_relu")

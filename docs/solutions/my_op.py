"""Reference solution, exercise 6 (autograd op): leaky ReLU with its own backward."""
import numpy as np

from minid3rqn.autograd import Tensor, as_tensor


def leaky_relu(x, slope=0.01):
    """y = x if x > 0 else slope * x;  dy/dx = 1 if x > 0 else slope."""
    x = as_tensor(x)
    pos = x.data > 0
    scale = np.where(pos, 1.0, slope).astype(x.dtype)      # dy/dx, elementwise
    y = x.data * scale
    return Tensor.from_op(y, (x,), lambda g: (g * scale,), "leaky_relu")

"""A tiny reverse-mode autograd on NumPy arrays.

``from minid3rqn import autograd as ag`` gives one flat namespace, named after
PyTorch's functional API where it has an equivalent (``ag.conv2d(x, weight, bias,
stride, padding)``, ``ag.grid_sample``-style ``ag.bilinear_sample``, ...).
"""
from .engine import (Tensor, no_grad, is_grad_enabled, as_tensor, unbroadcast, add, sub,
                     mul, div, neg, pow, exp, log, relu, matmul, sum, mean, reshape,
                     transpose, getitem)
from .elementwise import sqrt, abs, elu, sigmoid, tanh, clip, where, maximum, minimum
from .reduce import log_softmax
from .shape import concat, stack, pad, crop, flatten
from .gradcheck import gradcheck, GradcheckError
from .graph import graph, graph_text, graph_dot
from .lstm import lstm
from .sample import bilinear_sample
from .losses import mse_loss, huber_loss
from .optim import Adam, clip_grad_norm
from .conv import conv2d, upsample

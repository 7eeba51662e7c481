"""A tiny reverse-mode autograd on NumPy arrays.

``from minid3rqn import autograd as ag`` gives one flat namespace, named after
PyTorch's functional API where it has an equivalent (``ag.conv2d(x, weight, bias,
stride, padding)``, ``ag.grid_sample``-style ``ag.bilinear_sample``, ...).
"""
from .engine import (Tensor, no_grad, is_grad_enabled, as_tensor, unbroadcast, add, sub,
                     mul, div, neg, pow, exp, log, relu, astype, matmul, sum, mean, max,
                     reshape, transpose, getitem)
from .elementwise import (sqrt, abs, elu, sigmoid, tanh, softplus, clip, where, maximum,
                          minimum)
from .reduce import log_softmax
from .shape import concat, stack, pad, flatten
from .gradcheck import gradcheck, GradcheckError
from .lstm import lstm_cell, lstm, lstm_cell_reference
from .sample import bilinear_sample, pixel_grid
from .losses import l1_loss, mse_loss, huber_loss
from .optim import SGD, Adam, clip_grad_norm
from .conv import conv2d, conv_transpose2d, upsample, avg_pool2d, max_pool2d

"""Adam and gradient clipping by global norm.

The optimizer holds references to parameter Tensors and updates ``p.data`` in place
from ``p.grad``; its state (step count, moments) can be saved and restored for exact
resumption.
"""
from __future__ import annotations

from typing import Iterable

import numpy as np

from .engine import Tensor


class Adam:
    """Adam (Kingma & Ba 2015), at step t:

        m <- b1 m + (1 - b1) g,   v <- b2 v + (1 - b2) g^2,
        p <- p - lr * (m / (1 - b1^t)) / (sqrt(v / (1 - b2^t)) + eps).
    """

    def __init__(self, params: Iterable[Tensor], lr: float = 1e-3, betas=(0.9, 0.999),
                 eps: float = 1e-8):
        self.params = list(params)
        if not self.params:
            raise ValueError("optimizer: params is empty; pass model.parameters()")
        for i, p in enumerate(self.params):
            if not isinstance(p, Tensor):
                raise TypeError(f"optimizer: params[{i}] must be a Tensor; got "
                                f"{type(p).__name__}")
        if not lr > 0:
            raise ValueError(f"optimizer: lr must be positive; got {lr}")
        b1, b2 = betas
        if not (0 <= b1 < 1 and 0 <= b2 < 1):
            raise ValueError(f"Adam: betas must be in [0, 1); got {betas}")
        self.lr, self.b1, self.b2, self.eps = lr, b1, b2, eps
        self.step_count = 0
        self.m = [np.zeros_like(p.data) for p in self.params]
        self.v = [np.zeros_like(p.data) for p in self.params]

    def zero_grad(self) -> None:
        for p in self.params:
            p.grad = None

    def step(self) -> None:
        self.step_count += 1
        t = self.step_count
        for p, m, v in zip(self.params, self.m, self.v):
            if p.grad is None:
                continue
            g = p.grad
            m *= self.b1
            m += (1 - self.b1) * g
            v *= self.b2
            v += (1 - self.b2) * (g * g)
            m_hat_scale = 1 / (1 - self.b1 ** t)
            v_hat_scale = 1 / (1 - self.b2 ** t)
            p.data -= (self.lr * m_hat_scale) * m / (np.sqrt(v * v_hat_scale) + self.eps)

    # Saving and restoring (arrays only, so it fits in an .npz).
    def state_dict(self) -> dict[str, np.ndarray]:
        state = {"step_count": np.asarray(self.step_count)}
        state.update({f"m.{i}": m for i, m in enumerate(self.m)})
        state.update({f"v.{i}": v for i, v in enumerate(self.v)})
        return state

    def load_state_dict(self, state: dict[str, np.ndarray]) -> None:
        self.step_count = int(state["step_count"])
        for i in range(len(self.params)):
            self.m[i][...] = state[f"m.{i}"]
            self.v[i][...] = state[f"v.{i}"]


def clip_grad_norm(params: Iterable[Tensor], max_norm: float) -> float:
    """Scale all gradients by min(1, max_norm / ||g||), ||g|| over all of them at once.

    Returns the norm before clipping (useful to log). Raises on a non-finite norm, so
    a NaN is reported where it appears instead of silently poisoning the weights.
    """
    if not max_norm > 0:
        raise ValueError(f"clip_grad_norm: max_norm must be positive; got {max_norm}")
    grads = [p.grad for p in params if p.grad is not None]
    total = float(np.sqrt(sum(float(np.sum(g.astype(np.float64) ** 2)) for g in grads)))
    if not np.isfinite(total):
        raise FloatingPointError(f"clip_grad_norm: the gradient norm is {total}; a NaN or "
                                 f"inf reached the gradients")
    if total > max_norm:
        scale = max_norm / (total + 1e-12)
        for g in grads:
            g *= scale
    return total

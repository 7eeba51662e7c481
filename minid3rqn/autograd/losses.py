"""Losses: MSE and Huber, each reducing to a mean (or per-element with reduction="none").

Composed from the basic ops, so their gradients come for free and are checked through
those ops:  MSE = mean (p - t)^2,
Huber_delta(r) = r^2 / 2 if |r| <= delta else delta (|r| - delta / 2).
"""
from __future__ import annotations

from .elementwise import abs, clip
from .engine import Tensor, as_tensor, mean, mul, sub

_REDUCTIONS = ("mean", "none")


def _reduce(loss: Tensor, reduction: str) -> Tensor:
    return mean(loss) if reduction == "mean" else loss


def _residual(prediction, target, name: str, reduction: str) -> Tensor:
    if reduction not in _REDUCTIONS:
        raise ValueError(f"{name}: reduction must be one of {_REDUCTIONS}; got {reduction!r}")
    prediction = as_tensor(prediction)
    target = as_tensor(target, like=prediction)
    if prediction.shape != target.shape:
        raise ValueError(f"{name}: prediction has shape {prediction.shape} but target has "
                         f"shape {target.shape}; they must match")
    return sub(prediction, target)


def mse_loss(prediction, target, reduction: str = "mean") -> Tensor:
    """mean (prediction - target)^2."""
    r = _residual(prediction, target, "mse_loss", reduction)
    return _reduce(mul(r, r), reduction)


def huber_loss(prediction, target, delta: float = 1.0, reduction: str = "mean") -> Tensor:
    """Quadratic near zero, linear beyond ``delta`` (PyTorch's ``huber_loss``).

    Written as ``q = clip(|r|, 0, delta)``, ``loss = q (|r| - q / 2)``: for |r| <= delta
    that is r^2/2, beyond it delta (|r| - delta/2); the gradient is r clipped to
    [-delta, delta], which is why DQN uses it: one wrong target cannot explode a step.
    """
    if delta <= 0:
        raise ValueError(f"huber_loss: delta must be positive; got {delta}")
    r = abs(_residual(prediction, target, "huber_loss", reduction))
    q = clip(r, 0.0, delta)
    return _reduce(mul(q, sub(r, mul(q, 0.5))), reduction)

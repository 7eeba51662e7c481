"""Weight initialisers. Each takes a shape and a seed or ``np.random.Generator``."""
from __future__ import annotations

import numpy as np


def as_rng(rng) -> np.random.Generator:
    """An ``np.random.Generator`` from a seed (int), a Generator, or None (seed 0)."""
    if isinstance(rng, np.random.Generator):
        return rng
    if rng is None:
        return np.random.default_rng(0)
    if isinstance(rng, (int, np.integer)):
        return np.random.default_rng(int(rng))
    raise TypeError(f"rng must be an int seed or np.random.Generator; got {type(rng).__name__}")


def uniform_fan_in(shape, fan_in: int, rng, dtype=np.float32) -> np.ndarray:
    """U(-1/sqrt(fan_in), 1/sqrt(fan_in)): PyTorch's default for Linear, Conv and LSTM."""
    bound = 1.0 / np.sqrt(fan_in)
    return as_rng(rng).uniform(-bound, bound, size=shape).astype(dtype)


def kaiming_uniform(shape, fan_in: int, rng, dtype=np.float32) -> np.ndarray:
    """U(-b, b) with b = sqrt(6 / fan_in): keeps activations' variance through ReLUs."""
    bound = np.sqrt(6.0 / fan_in)
    return as_rng(rng).uniform(-bound, bound, size=shape).astype(dtype)

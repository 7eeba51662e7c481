"""``Module``: a container that finds its own parameters, as in PyTorch.

A parameter is any ``Tensor`` attribute with ``requires_grad=True``; sub-modules are
``Module`` attributes or lists of modules. Names are dotted paths
(``encoder.0.weight``), which is what ``state_dict`` and the ``.npz`` files use.
"""
from __future__ import annotations

from pathlib import Path
from typing import Iterator

import numpy as np

from ..autograd import Tensor
from ..io import load_npz, save_npz


def check_finite(arrays: dict[str, np.ndarray], path) -> None:
    """ValueError if a weight read from ``path`` is not floating point or holds NaN or
    inf."""
    for name, value in arrays.items():
        if value.dtype.kind != "f":
            raise ValueError(f"{str(path)!r}: weight {name!r} is {value.dtype}, not floating "
                             f"point; a model file holds float weights")
        if not np.all(np.isfinite(value)):
            raise ValueError(f"{str(path)!r}: weight {name!r} holds NaN or inf; a model "
                             f"with non-finite weights cannot fly")


class Module:
    def __call__(self, *args, **kwargs):
        return self.forward(*args, **kwargs)

    def forward(self, *args, **kwargs):
        raise NotImplementedError(f"{type(self).__name__} must define forward()")

    # -- discovery ---------------------------------------------------------------
    def named_parameters(self, prefix: str = "") -> Iterator[tuple[str, Tensor]]:
        for name, value in vars(self).items():
            full = f"{prefix}{name}"
            if isinstance(value, Tensor) and value.requires_grad:
                yield full, value
            elif isinstance(value, Module):
                yield from value.named_parameters(full + ".")
            elif isinstance(value, (list, tuple)):
                for i, item in enumerate(value):
                    if isinstance(item, Module):
                        yield from item.named_parameters(f"{full}.{i}.")

    def parameters(self) -> list[Tensor]:
        return [p for _, p in self.named_parameters()]

    def zero_grad(self) -> None:
        for p in self.parameters():
            p.grad = None

    # -- saving and loading --------------------------------------------------------
    def state_dict(self) -> dict[str, np.ndarray]:
        """Parameter name -> a copy of its array."""
        return {name: p.data.copy() for name, p in self.named_parameters()}

    def load_state_dict(self, state: dict[str, np.ndarray]) -> None:
        """Copy arrays into the parameters; names and shapes must match exactly."""
        own = dict(self.named_parameters())
        missing = sorted(set(own) - set(state))
        unexpected = sorted(set(state) - set(own))
        if missing or unexpected:
            raise KeyError(f"load_state_dict into {type(self).__name__}: missing "
                           f"{missing or 'none'}; unexpected {unexpected or 'none'}")
        for name, p in own.items():
            value = np.asarray(state[name])
            if value.shape != p.shape:
                raise ValueError(f"load_state_dict: {name} expects shape {p.shape}; "
                                 f"the state has {value.shape}")
            p.set_(value.astype(p.dtype, copy=False))

    def save(self, path, metadata: dict | None = None) -> Path:
        """Write the parameters to an ``.npz`` (atomically), with optional metadata."""
        return save_npz(path, self.state_dict(), metadata)

    def load(self, path) -> dict | None:
        """Load parameters saved by ``save``; returns the metadata."""
        arrays, meta = load_npz(path)
        check_finite(arrays, path)
        self.load_state_dict(arrays)
        return meta

    def copy_from(self, other: "Module") -> None:
        """Copy ``other``'s parameter values (e.g. into a target network)."""
        self.load_state_dict(other.state_dict())

    def astype(self, dtype) -> "Module":
        """Convert every parameter in place (float64 for gradient checks)."""
        for _, p in self.named_parameters():
            p.data = p.data.astype(dtype)
        return self

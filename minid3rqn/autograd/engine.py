"""The reverse-mode engine: a Tensor that remembers how it was made.

Every op in this package follows one pattern (see ``elementwise.exp``)::

    def exp(x):
        x = as_tensor(x)
        y = np.exp(x.data)                                   # forward
        return Tensor.from_op(y, (x,), lambda g: (g * y,), "exp")
                                                             # backward: dL/dx = g * e^x

``from_op`` records the parents and a *vector-Jacobian product*: given ``g = dL/dy``
(same shape as ``y``) it returns ``dL/dx`` for every parent (``None`` where a parent
needs no gradient). ``Tensor.backward`` sorts the graph topologically with an explicit
stack (no recursion, so an LSTM unrolled over many steps cannot overflow Python's
stack) and calls the products from the output back to the leaves, summing the
gradients that meet at a node.
"""
from __future__ import annotations

import contextlib
from typing import Callable, Iterable, Sequence

import numpy as np

FLOAT_DTYPES = (np.float32, np.float64)
_GRAD_ENABLED = True


@contextlib.contextmanager
def no_grad():
    """Inside this block no graph is recorded: ops return plain leaf tensors.

    Use it for inference (acting, evaluation) and for optimizer updates.
    """
    global _GRAD_ENABLED
    previous = _GRAD_ENABLED
    _GRAD_ENABLED = False
    try:
        yield
    finally:
        _GRAD_ENABLED = previous


def is_grad_enabled() -> bool:
    return _GRAD_ENABLED


def _check_float(array: np.ndarray, name: str) -> None:
    if array.dtype not in FLOAT_DTYPES:
        raise TypeError(
            f"{name} must hold float32 or float64 values; got dtype {array.dtype}. "
            f"Convert with .astype(np.float32) (training) or np.float64 (gradient checks)."
        )


class Tensor:
    """A NumPy array plus what is needed to differentiate through it.

    Attributes:
        data: the value, a float32 or float64 ``np.ndarray``.
        grad: ``dL/data`` after ``backward()`` (leaves with ``requires_grad`` only),
            same shape and dtype as ``data``; gradients accumulate until ``zero_grad``.
        requires_grad: whether gradients flow to (and through) this tensor.
    """

    __slots__ = ("data", "grad", "requires_grad", "_parents", "_vjp", "op")
    __array_priority__ = 1000  # so that ndarray * Tensor calls Tensor.__rmul__

    def __init__(self, data, requires_grad: bool = False, dtype=None):
        if isinstance(data, Tensor):
            data = data.data
        if isinstance(data, (np.ndarray, np.generic)):  # NumPy keeps its own dtype
            array = np.asarray(data) if dtype is None else np.asarray(data, dtype=dtype)
        else:  # Python scalars and lists: float32 unless told otherwise
            array = np.asarray(data, dtype=np.float32 if dtype is None else dtype)
        _check_float(array, "Tensor data")
        self.data: np.ndarray = array
        self.grad: np.ndarray | None = None
        self.requires_grad = bool(requires_grad)
        self._parents: tuple[Tensor, ...] = ()
        self._vjp: Callable | None = None
        self.op = ""

    # -- building the graph -------------------------------------------------------
    @staticmethod
    def from_op(data: np.ndarray, parents: Sequence["Tensor"], vjp: Callable,
                op: str) -> "Tensor":
        """Wrap the result of an op and, if needed, remember how to differentiate it.

        Args:
            data: the op's output array.
            parents: the input tensors, in the order ``vjp`` returns their gradients.
            vjp: ``g -> tuple of dL/d(parent)`` (an array per parent, or ``None``).
            op: a short name, shown in ``repr`` and in error messages.
        """
        out = Tensor.__new__(Tensor)
        out.data = data
        out.grad = None
        out.op = op
        out._parents = ()
        out._vjp = None
        needs = _GRAD_ENABLED and any(p.requires_grad for p in parents)
        out.requires_grad = needs
        if needs:
            out._parents = tuple(parents)
            out._vjp = vjp
        return out

    # -- basic facts ---------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, ...]:
        return self.data.shape

    @property
    def ndim(self) -> int:
        return self.data.ndim

    @property
    def dtype(self):
        return self.data.dtype

    @property
    def size(self) -> int:
        return self.data.size

    @property
    def T(self) -> "Tensor":
        from .shape import transpose
        return transpose(self)

    def __len__(self) -> int:
        return len(self.data)

    def numpy(self) -> np.ndarray:
        return self.data

    def item(self) -> float:
        return self.data.item()

    def detach(self) -> "Tensor":
        """The same values, cut from the graph."""
        return Tensor(self.data)

    def astype(self, dtype) -> "Tensor":
        from .elementwise import astype
        return astype(self, dtype)

    def zero_grad(self) -> None:
        self.grad = None

    def __repr__(self) -> str:
        extra = f", op={self.op}" if self.op else ""
        extra += ", requires_grad=True" if self.requires_grad else ""
        return f"Tensor(shape={self.shape}, dtype={self.dtype}{extra})"

    # -- reverse mode --------------------------------------------------------------
    def backward(self, grad=None) -> None:
        """Accumulate ``d(self)/d(leaf)`` into ``leaf.grad`` for every leaf needing it.

        Args:
            grad: the covector ``dL/d(self)``; may be omitted for a single-element
                tensor (then it is 1).
        """
        if not self.requires_grad:
            raise RuntimeError(
                "backward() called on a tensor that does not require grad: none of the "
                "tensors it was computed from has requires_grad=True (or it was made "
                "inside no_grad())."
            )
        if grad is None:
            if self.size != 1:
                raise ValueError(
                    f"backward() without an argument needs a single-element tensor; "
                    f"this one has shape {self.shape}. Pass grad= of that shape."
                )
            grad = np.ones_like(self.data)
        else:
            grad = np.asarray(grad.data if isinstance(grad, Tensor) else grad,
                              dtype=self.dtype)
            if grad.shape != self.shape:
                raise ValueError(f"backward(grad=...) expected shape {self.shape}; "
                                 f"got {grad.shape}")

        order = _topological_order(self)
        grads: dict[int, np.ndarray] = {id(self): grad}
        for node in reversed(order):
            g = grads.pop(id(node), None)
            if g is None:
                continue
            if not node._parents:  # a leaf: keep the gradient
                node.grad = g.copy() if node.grad is None else node.grad + g
                continue
            parent_grads = node._vjp(g)
            for parent, pg in zip(node._parents, parent_grads):
                if pg is None or not parent.requires_grad:
                    continue
                if pg.shape != parent.shape:
                    raise RuntimeError(
                        f"internal error: op '{node.op}' returned a gradient of shape "
                        f"{pg.shape} for an input of shape {parent.shape}")
                key = id(parent)
                if key in grads:
                    grads[key] = grads[key] + pg
                else:
                    grads[key] = pg

    # -- operators (implemented in elementwise / shape / reduce) -------------------
    def __add__(self, other):
        from .elementwise import add
        return add(self, other)

    def __radd__(self, other):
        from .elementwise import add
        return add(other, self)

    def __sub__(self, other):
        from .elementwise import sub
        return sub(self, other)

    def __rsub__(self, other):
        from .elementwise import sub
        return sub(other, self)

    def __mul__(self, other):
        from .elementwise import mul
        return mul(self, other)

    def __rmul__(self, other):
        from .elementwise import mul
        return mul(other, self)

    def __truediv__(self, other):
        from .elementwise import div
        return div(self, other)

    def __rtruediv__(self, other):
        from .elementwise import div
        return div(other, self)

    def __neg__(self):
        from .elementwise import neg
        return neg(self)

    def __pow__(self, exponent):
        from .elementwise import pow
        return pow(self, exponent)

    def __matmul__(self, other):
        from .elementwise import matmul
        return matmul(self, other)

    def __rmatmul__(self, other):
        from .elementwise import matmul
        return matmul(other, self)

    def __getitem__(self, index):
        from .shape import getitem
        return getitem(self, index)

    def sum(self, axis=None, keepdims=False):
        from .reduce import sum
        return sum(self, axis, keepdims)

    def mean(self, axis=None, keepdims=False):
        from .reduce import mean
        return mean(self, axis, keepdims)

    def max(self, axis=None, keepdims=False):
        from .reduce import max
        return max(self, axis, keepdims)

    def reshape(self, *shape):
        from .shape import reshape
        if len(shape) == 1 and isinstance(shape[0], (tuple, list)):
            shape = tuple(shape[0])
        return reshape(self, shape)

    def transpose(self, *axes):
        from .shape import transpose
        if len(axes) == 1 and isinstance(axes[0], (tuple, list)):
            axes = tuple(axes[0])
        return transpose(self, axes or None)

    def exp(self):
        from .elementwise import exp
        return exp(self)

    def log(self):
        from .elementwise import log
        return log(self)

    def relu(self):
        from .elementwise import relu
        return relu(self)


def _topological_order(root: Tensor) -> list[Tensor]:
    """Nodes reachable from ``root`` that require grad, parents before children.

    An explicit stack replaces recursion: each entry is (node, parents_done).
    """
    order: list[Tensor] = []
    visited: set[int] = set()
    stack: list[tuple[Tensor, bool]] = [(root, False)]
    while stack:
        node, parents_done = stack.pop()
        if parents_done:
            order.append(node)
            continue
        if id(node) in visited:
            continue
        visited.add(id(node))
        stack.append((node, True))
        for parent in node._parents:
            if parent.requires_grad and id(parent) not in visited:
                stack.append((parent, False))
    return order


def as_tensor(x, like: Tensor | None = None) -> Tensor:
    """``x`` as a Tensor. Scalars and arrays take ``like``'s dtype (no silent upcast)."""
    if isinstance(x, Tensor):
        return x
    dtype = like.dtype if like is not None else None
    if isinstance(x, np.ndarray) and dtype is None:
        return Tensor(x)
    return Tensor(np.asarray(x, dtype=dtype if dtype is not None else np.float32))


def unbroadcast(grad: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """Sum ``grad`` down to ``shape``: the adjoint of NumPy broadcasting.

    If ``x`` of shape ``shape`` was broadcast to ``grad.shape``, every copy of an entry
    received a share of the gradient, so ``dL/dx`` is the sum over the copies: over the
    leading axes broadcasting added, and over axes where ``x`` had length 1.
    """
    if grad.shape == shape:
        return grad
    extra = grad.ndim - len(shape)
    if extra:
        grad = grad.sum(axis=tuple(range(extra)))
    ones = tuple(i for i, n in enumerate(shape) if n == 1 and grad.shape[i] != 1)
    if ones:
        grad = grad.sum(axis=ones, keepdims=True)
    return grad.reshape(shape)


def check_same_dtype(tensors: Iterable[Tensor], op: str) -> None:
    """Ops refuse to mix float32 and float64, which would silently upcast training."""
    dtypes = {t.dtype for t in tensors}
    if len(dtypes) > 1:
        raise TypeError(f"{op}: inputs mix dtypes {sorted(str(d) for d in dtypes)}; "
                        f"convert them to one dtype first (e.g. x.astype(np.float32)).")

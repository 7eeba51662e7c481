"""The reverse-mode engine: a Tensor that remembers how it was made, and its operators.

Every op in this package follows one pattern (see ``exp`` below)::

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

This file holds the Tensor and the ops its operators and methods call (``a + b``,
``a @ b``, ``x[i]``, ``x.sum()``, ...); the other ops build on these in the other files.
"""
from __future__ import annotations

import contextlib
from typing import Callable, Iterable, Sequence

import numpy as np

from . import kernels

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
        version: a counter bumped whenever ``data`` is assigned, which includes the
            in-place forms ``t.data -= step`` (what the optimizer does) and
            ``t.data[...] = value`` written as ``t.set_(value)``. Kernels that keep
            something derived from a weight (a convolution's weight matrix) recompute
            it when the version moves.
    """

    __slots__ = ("_data", "grad", "requires_grad", "_parents", "_vjp", "op", "version",
                 "__weakref__")
    __array_priority__ = 1000  # so that ndarray * Tensor calls Tensor.__rmul__

    def __init__(self, data, requires_grad: bool = False, dtype=None):
        if isinstance(data, Tensor):
            data = data.data
        if isinstance(data, (np.ndarray, np.generic)):  # NumPy keeps its own dtype
            array = np.asarray(data) if dtype is None else np.asarray(data, dtype=dtype)
        else:  # Python scalars and lists: float32 unless told otherwise
            array = np.asarray(data, dtype=np.float32 if dtype is None else dtype)
        _check_float(array, "Tensor data")
        self._data: np.ndarray = array
        self.version = 0
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
        out._data = data
        out.version = 0
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

    # -- the value ----------------------------------------------------------------
    @property
    def data(self) -> np.ndarray:
        return self._data

    @data.setter
    def data(self, array: np.ndarray) -> None:
        self._data = array
        self.version += 1

    def set_(self, value) -> "Tensor":
        """Overwrite the value in place (``data[...] = value``) and bump ``version``."""
        self._data[...] = value
        self.version += 1
        return self

    # -- basic facts ---------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, ...]:
        return self._data.shape

    @property
    def ndim(self) -> int:
        return self._data.ndim

    @property
    def dtype(self):
        return self._data.dtype

    @property
    def size(self) -> int:
        return self._data.size

    @property
    def T(self) -> "Tensor":
        return transpose(self)

    def __len__(self) -> int:
        return len(self.data)

    def item(self) -> float:
        return self.data.item()

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

    # -- operators: each calls the op of the same name defined below the class ------
    def __add__(self, other):
        return add(self, other)

    def __radd__(self, other):
        return add(other, self)

    def __sub__(self, other):
        return sub(self, other)

    def __rsub__(self, other):
        return sub(other, self)

    def __mul__(self, other):
        return mul(self, other)

    def __rmul__(self, other):
        return mul(other, self)

    def __truediv__(self, other):
        return div(self, other)

    def __rtruediv__(self, other):
        return div(other, self)

    def __neg__(self):
        return neg(self)

    def __pow__(self, exponent):
        return pow(self, exponent)

    def __matmul__(self, other):
        return matmul(self, other)

    def __rmatmul__(self, other):
        return matmul(other, self)

    def __getitem__(self, index):
        return getitem(self, index)

    def sum(self, axis=None, keepdims=False):
        return sum(self, axis, keepdims)

    def mean(self, axis=None, keepdims=False):
        return mean(self, axis, keepdims)

    def reshape(self, *shape):
        if len(shape) == 1 and isinstance(shape[0], (tuple, list)):
            shape = tuple(shape[0])
        return reshape(self, shape)

    def transpose(self, *axes):
        if len(axes) == 1 and isinstance(axes[0], (tuple, list)):
            axes = tuple(axes[0])
        return transpose(self, axes or None)


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


def float_tensor(value, name: str, op: str) -> Tensor:
    """``value`` as a Tensor, or a TypeError naming the argument if it holds no floats."""
    if isinstance(value, Tensor):
        return value
    array = np.asarray(value)
    if array.dtype not in FLOAT_DTYPES:
        raise TypeError(f"{op}: {name} must hold float32 or float64 values; got dtype "
                        f"{array.dtype}")
    return as_tensor(array)


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


def broadcast_pair(a, b, op: str) -> tuple[Tensor, Tensor]:
    """``a`` and ``b`` as Tensors of one dtype whose shapes broadcast (a scalar or array
    takes the other's dtype); raises TypeError / ValueError naming ``op`` otherwise."""
    if isinstance(a, Tensor):
        b = as_tensor(b, like=a)
    elif isinstance(b, Tensor):
        a = as_tensor(a, like=b)
    else:
        a, b = as_tensor(a), as_tensor(b)
    if a.dtype != b.dtype:
        check_same_dtype((a, b), op)
    sa, sb = a._data.shape, b._data.shape
    if sa == sb or (len(sb) <= len(sa) and sa[len(sa) - len(sb):] == sb):
        return a, b                                    # b broadcasts along a's lead axes
    try:
        np.broadcast_shapes(a.shape, b.shape)
    except ValueError:
        raise ValueError(f"{op}: shapes {a.shape} and {b.shape} do not broadcast") from None
    return a, b


# -- arithmetic: + - * / unary minus ** ------------------------------------------------
def add(a, b) -> Tensor:
    """y = a + b;  dy/da = 1, dy/db = 1."""
    a, b = broadcast_pair(a, b, "add")
    return Tensor.from_op(a.data + b.data, (a, b),
                          lambda g: (unbroadcast(g, a.shape), unbroadcast(g, b.shape)), "add")


def sub(a, b) -> Tensor:
    """y = a - b;  dy/da = 1, dy/db = -1."""
    a, b = broadcast_pair(a, b, "sub")
    return Tensor.from_op(a.data - b.data, (a, b),
                          lambda g: (unbroadcast(g, a.shape), unbroadcast(-g, b.shape)), "sub")


def mul(a, b) -> Tensor:
    """y = a * b;  dy/da = b, dy/db = a."""
    a, b = broadcast_pair(a, b, "mul")
    return Tensor.from_op(a.data * b.data, (a, b),
                          lambda g: (unbroadcast(g * b.data, a.shape),
                                     unbroadcast(g * a.data, b.shape)), "mul")


def div(a, b) -> Tensor:
    """y = a / b;  dy/da = 1/b, dy/db = -a/b^2 = -y/b."""
    a, b = broadcast_pair(a, b, "div")
    y = a.data / b.data
    return Tensor.from_op(y, (a, b),
                          lambda g: (unbroadcast(g / b.data, a.shape),
                                     unbroadcast(-g * y / b.data, b.shape)), "div")


def neg(x) -> Tensor:
    """y = -x;  dy/dx = -1."""
    x = as_tensor(x)
    return Tensor.from_op(-x.data, (x,), lambda g: (-g,), "neg")


def pow(x, exponent) -> Tensor:
    """y = x^p for a constant p;  dy/dx = p x^(p-1)."""
    x = as_tensor(x)
    if isinstance(exponent, Tensor):
        raise TypeError("pow: exponent must be a Python number (a constant); "
                        "for x^t with a tensor t use exp(t * log(x))")
    p = float(exponent)
    y = x.data ** p
    return Tensor.from_op(y, (x,), lambda g: (g * p * x.data ** (p - 1),), "pow")


# -- exp, log, relu ---------------------------------------------------------------------
def exp(x) -> Tensor:
    """y = e^x;  dy/dx = e^x = y."""
    x = as_tensor(x)
    y = np.exp(x.data)
    return Tensor.from_op(y, (x,), lambda g: (g * y,), "exp")


def log(x) -> Tensor:
    """y = ln x;  dy/dx = 1/x."""
    x = as_tensor(x)
    return Tensor.from_op(np.log(x.data), (x,), lambda g: (g / x.data,), "log")


def relu(x) -> Tensor:
    """y = max(x, 0);  dy/dx = 1 if x > 0 else 0 (that is, where y > 0)."""
    x = as_tensor(x)
    y = np.maximum(x.data, kernels.zeros_like_layout(x.data))  # (faster than the scalar 0)
    return Tensor.from_op(y, (x,), lambda g: (g * (y > 0),), "relu")


# -- matrix product: @ -----------------------------------------------------------------
def matmul(a, b) -> Tensor:
    """Y = A @ B (batched over leading axes, broadcast like NumPy).

    dL/dA = G @ B^T,  dL/dB = A^T @ G  (then summed over broadcast batch axes).
    Vectors (1-D) are treated as in NumPy: promoted, then the added axis removed.
    """
    a, b = _pair_matmul(a, b)
    y = a.data @ b.data

    def vjp(g):
        ad, bd = a.data, b.data
        if ad.ndim == 1 and bd.ndim == 1:       # dot product: g is a scalar
            return g * bd, g * ad
        if ad.ndim == 1:                        # (k) @ (..., k, n) -> (..., n)
            ga = (g[..., None, :] @ np.swapaxes(bd, -1, -2))[..., 0, :]
            gb = ad[:, None] * g[..., None, :]
            return unbroadcast(ga, a.shape), unbroadcast(gb, b.shape)
        if bd.ndim == 1:                        # (..., m, k) @ (k) -> (..., m)
            ga = g[..., :, None] * bd
            gb = (np.swapaxes(ad, -1, -2) @ g[..., :, None])[..., 0]
            return unbroadcast(ga, a.shape), unbroadcast(gb, b.shape)
        ga = g @ np.swapaxes(bd, -1, -2)
        gb = np.swapaxes(ad, -1, -2) @ g
        return unbroadcast(ga, a.shape), unbroadcast(gb, b.shape)

    return Tensor.from_op(y, (a, b), vjp, "matmul")


def _pair_matmul(a, b) -> tuple[Tensor, Tensor]:
    if isinstance(a, Tensor):
        b = as_tensor(b, like=a)
    else:
        b = as_tensor(b)
        a = as_tensor(a, like=b)
    if a.dtype != b.dtype:
        check_same_dtype((a, b), "matmul")
    if a.ndim == 0 or b.ndim == 0:
        raise ValueError(f"matmul: inputs must have at least 1 dimension; got shapes "
                         f"{a.shape} and {b.shape}")
    k_a = a.shape[-1]
    k_b = b.shape[0] if b.ndim == 1 else b.shape[-2]
    if k_a != k_b:
        raise ValueError(f"matmul: inner dimensions differ: a is {a.shape}, b is "
                         f"{b.shape} ({k_a} != {k_b})")
    return a, b


# -- reductions: sum, mean -----------------------------------------------------------
# A reduction removes axes; its gradient puts them back (``keepdims`` shape) and
# broadcasts ``g`` over them, because every reduced entry influenced the result.
def reduction_axes(axis, ndim: int, op: str) -> tuple[int, ...]:
    """``axis`` (None, an int or a tuple) as sorted non-negative axes of an ``ndim``-D
    tensor; None means all. Raises ValueError naming ``op`` for an axis out of range."""
    if axis is None:
        return tuple(range(ndim))
    axes = (axis,) if isinstance(axis, (int, np.integer)) else tuple(axis)
    out = []
    for a in axes:
        if not -ndim <= a < max(ndim, 1):
            raise ValueError(f"{op}: axis {a} is out of range for a tensor with "
                             f"{ndim} dimensions")
        out.append(a % max(ndim, 1))
    return tuple(sorted(set(out)))


def _regrow(g: np.ndarray, axes: tuple[int, ...], keepdims: bool) -> np.ndarray:
    """g with the reduced axes restored as length-1 axes (ready to broadcast)."""
    return g if keepdims else np.expand_dims(g, axes)


def sum(x, axis=None, keepdims: bool = False) -> Tensor:
    """y = sum_i x_i over ``axis``;  dy/dx_i = 1."""
    x = as_tensor(x)
    axes = reduction_axes(axis, x.ndim, "sum")
    y = np.sum(x.data, axis=axes, keepdims=keepdims)
    return Tensor.from_op(np.asarray(y), (x,),
                          lambda g: (np.broadcast_to(_regrow(g, axes, keepdims),
                                                     x.shape).copy(),), "sum")


def mean(x, axis=None, keepdims: bool = False) -> Tensor:
    """y = (1/n) sum_i x_i over ``axis``;  dy/dx_i = 1/n."""
    x = as_tensor(x)
    axes = reduction_axes(axis, x.ndim, "mean")
    n = int(np.prod([x.shape[a] for a in axes])) if axes else 1
    y = np.add.reduce(x.data, axis=axes, keepdims=keepdims) / n     # as np.mean sums
    return Tensor.from_op(np.asarray(y, dtype=x.dtype), (x,),
                          lambda g: (np.broadcast_to(_regrow(g, axes, keepdims) / n,
                                                     x.shape).astype(x.dtype),), "mean")


# -- moving entries: reshape, transpose, indexing --------------------------------------
# Their gradients move ``g`` back the same way.
def reshape(x, shape) -> Tensor:
    """y = x viewed with a new shape;  dL/dx = g reshaped back."""
    x = as_tensor(x)
    shape = tuple(int(s) for s in shape)
    try:
        y = x.data.reshape(shape)
    except ValueError:
        raise ValueError(f"reshape: cannot reshape a tensor of shape {x.shape} "
                         f"({x.size} entries) into {shape}") from None
    return Tensor.from_op(y, (x,), lambda g: (g.reshape(x.shape),), "reshape")


def transpose(x, axes=None) -> Tensor:
    """y = x with axes permuted;  dL/dx = g permuted by the inverse permutation."""
    x = as_tensor(x)
    if axes is None:
        axes = tuple(reversed(range(x.ndim)))
    else:
        axes = tuple(int(a) for a in axes)
    if sorted(a % max(x.ndim, 1) for a in axes) != list(range(x.ndim)):
        raise ValueError(f"transpose: axes {axes} are not a permutation of "
                         f"0..{x.ndim - 1} for shape {x.shape}")
    return Tensor.from_op(np.transpose(x.data, axes), (x,),
                          lambda g: (np.transpose(g, np.argsort(axes)),), "transpose")


def getitem(x, index) -> Tensor:
    """y = x[index] (slices, ints, boolean masks, integer arrays);  dL/dx = g scattered.

    With integer arrays an entry can be picked several times (a gather), so the
    scatter adds (``np.add.at``); slices, ints and boolean masks pick each entry at
    most once, so plain assignment does (much faster). This is how Q(s, a) is read off
    a batch of Q-values: ``q[np.arange(B), actions]``.
    """
    x = as_tensor(x)
    if isinstance(index, Tensor):
        raise TypeError("getitem: index with NumPy arrays or ints, not Tensors")
    try:
        y = x.data[index]
    except IndexError as e:
        raise IndexError(f"getitem: index {index!r} does not fit shape {x.shape}: {e}") from None

    parts = index if isinstance(index, tuple) else (index,)
    gathers = any(isinstance(p, (list, np.ndarray)) and np.asarray(p).dtype != bool
                  for p in parts)

    def vjp(g):
        gx = np.zeros_like(x.data)
        if gathers:    # an entry may be picked twice: add, don't overwrite
            np.add.at(gx, index, g)
        else:          # slices, ints and masks pick each entry at most once
            gx[index] = g
        return (gx,)

    return Tensor.from_op(np.array(y, copy=True), (x,), vjp, "getitem")

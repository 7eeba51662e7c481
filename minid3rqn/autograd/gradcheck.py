"""Checking a backward pass against central differences, in float64.

Two checks, both exact up to O(eps^2) truncation and float64 rounding:

1. Directional (as HIPS autograd's ``check_grads``): pick a random covector ``u`` on
   the output and a random direction ``v`` on every input. The analytic side is the
   vector-Jacobian product ``<J^T u, v> = sum_i <dL/dx_i, v_i>`` with ``L = <u, f(x)>``;
   the numerical side is the Jacobian-vector product by central differences,
   ``<u, (f(x + eps v) - f(x - eps v)) / (2 eps)>``. One pair of evaluations tests
   every entry of every gradient at once.
2. Elementwise (small inputs only): perturb each input entry alone and compare
   ``(L(x + eps e_k) - L(x - eps e_k)) / (2 eps)`` with ``dL/dx[k]``. Slower, but it
   names the exact entry that is wrong.

Use it on your own op::

    from minid3rqn.autograd import gradcheck
    gradcheck(lambda x, w: my_op(x, w), [np.random.randn(2, 3), np.random.randn(3)])
"""
from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from .engine import Tensor


class GradcheckError(AssertionError):
    """Raised when an analytic gradient disagrees with central differences."""


def _as_array(out) -> np.ndarray:
    if not isinstance(out, Tensor):
        raise TypeError(f"gradcheck: fn must return a Tensor; got {type(out).__name__}")
    return out.data


def _agree(exact: float, numeric: float, atol: float, rtol: float) -> bool:
    return abs(exact - numeric) <= atol + rtol * abs(numeric)


def gradcheck(fn: Callable[..., Tensor], inputs: Sequence[np.ndarray], *,
              eps: float = 1e-6, atol: float = 1e-6, rtol: float = 1e-5,
              n_directions: int = 2, elementwise: bool | None = None,
              max_elementwise: int = 400, check_inputs: Sequence[int] | None = None,
              seed: int = 0) -> bool:
    """Check ``fn``'s backward pass against central differences; raise if it is wrong.

    Args:
        fn: maps Tensors (one per entry of ``inputs``) to one Tensor.
        inputs: float64 arrays (float32 is refused: its rounding swamps eps).
        eps: finite-difference step.
        atol, rtol: agreement required: ``|analytic - numeric| <= atol + rtol*|numeric|``.
        n_directions: random directions in the directional check.
        elementwise: also perturb every entry alone; default: when the inputs hold at
            most ``max_elementwise`` entries in all.
        check_inputs: indices of the inputs to differentiate (default: all). Others
            are passed as constants (e.g. integer-valued masks).
        seed: seeds the random covector and directions.

    Returns:
        True when every check passes.

    Raises:
        GradcheckError: naming the input (and entry), the analytic and numeric values.
    """
    arrays = []
    for i, a in enumerate(inputs):
        a = np.asarray(a)
        if a.dtype != np.float64:
            raise TypeError(f"gradcheck: inputs[{i}] must be float64; got {a.dtype}")
        arrays.append(a.copy())
    which = list(range(len(arrays))) if check_inputs is None else list(check_inputs)
    rng = np.random.default_rng(seed)

    # Analytic side: one backward pass with a random covector u.
    tensors = [Tensor(a, requires_grad=(i in which)) for i, a in enumerate(arrays)]
    out = fn(*tensors)
    y = _as_array(out)
    if y.dtype != np.float64:
        raise TypeError(f"gradcheck: fn returned {y.dtype} for float64 inputs; ops must "
                        f"preserve the dtype")
    u = rng.standard_normal(y.shape)
    if not out.requires_grad:
        raise GradcheckError("gradcheck: the output does not depend on any checked input")
    out.backward(u)
    analytic = [tensors[i].grad if tensors[i].grad is not None else np.zeros_like(arrays[i])
                for i in range(len(arrays))]

    def objective(shifted: list[np.ndarray]) -> float:
        """L = <u, fn(shifted)>."""
        return float(np.sum(_as_array(fn(*[Tensor(a) for a in shifted])) * u))

    _check_directions(objective, arrays, analytic, which, rng, n_directions, eps, atol, rtol)
    if elementwise is None:
        elementwise = sum(arrays[i].size for i in which) <= max_elementwise
    if elementwise:
        _check_entries(objective, arrays, analytic, which, eps, atol, rtol)
    return True


def _check_directions(objective, arrays, analytic, which, rng, n_directions, eps, atol,
                      rtol) -> None:
    """Check 1: the VJP <J^T u, v> against the central-difference JVP along random v."""
    for d in range(n_directions):
        v = {i: rng.standard_normal(arrays[i].shape) for i in which}
        plus = [a + eps * v[i] if i in v else a for i, a in enumerate(arrays)]
        minus = [a - eps * v[i] if i in v else a for i, a in enumerate(arrays)]
        numeric = (objective(plus) - objective(minus)) / (2 * eps)
        exact = sum(float(np.sum(analytic[i] * v[i])) for i in which)
        if not _agree(exact, numeric, atol, rtol):
            raise GradcheckError(
                f"gradcheck: directional derivative {d} disagrees: analytic (VJP) "
                f"{exact:.10g} vs numeric (JVP) {numeric:.10g}; "
                f"difference {abs(exact - numeric):.3g}")


def _check_entries(objective, arrays, analytic, which, eps, atol, rtol) -> None:
    """Check 2: every entry of every checked input perturbed alone."""
    for i in which:
        flat = arrays[i].reshape(-1)
        for k in range(flat.size):
            saved = flat[k]
            flat[k] = saved + eps
            f_plus = objective(arrays)
            flat[k] = saved - eps
            f_minus = objective(arrays)
            flat[k] = saved
            numeric = (f_plus - f_minus) / (2 * eps)
            exact = analytic[i].reshape(-1)[k]
            if not _agree(exact, numeric, atol, rtol):
                index = [int(j) for j in np.unravel_index(k, arrays[i].shape)]
                raise GradcheckError(
                    f"gradcheck: d/d inputs[{i}]{index} disagrees: analytic "
                    f"{exact:.10g} vs numeric {numeric:.10g}")

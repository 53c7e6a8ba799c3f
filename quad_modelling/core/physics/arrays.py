"""The few array operations the physics needs, on numpy arrays, torch tensors and CasADi expressions alike.

The quadrotor's physics (:mod:`quad_modelling.core.physics`) is written once against these operations plus
the arithmetic operators, so the hybrid's training back-propagates through the very formulas the numpy model
runs (:mod:`quad_modelling.core.training.physics_torch` only converts states and parameters), and the CasADi
export (:mod:`quad_modelling.core.export.casadi_model`) builds the same formulas as symbolic expressions. torch
and casadi are never imported here unless such an array is passed: a tensor brings its own module, so the numpy
path needs neither installed.

Backends: numpy float arrays; torch tensors (:func:`is_tensor`); *symbolic* arrays (:func:`is_symbolic`): numpy
arrays of dtype object whose elements are CasADi ``SX`` scalars. numpy's arithmetic, ``@``, ``einsum``, ``cross``,
``sum`` and the elementary ufuncs (``exp``, ``sin``, ``tanh``, ...) already work on them element by element;
this module supplies the rest (comparisons, max, where, atan2, norm), so an expression is built by the very
code that computes the numbers.

Shapes: a batch of B members along axis 0; vectors (B, 3), rotations (B, 3, 3), rotor quantities (B, 4).
"""

from __future__ import annotations

import numpy as np


def is_tensor(x) -> bool:
    """True for a torch tensor (told by its type's module, without importing torch)."""
    return type(x).__module__.split(".", 1)[0] == "torch"


def is_symbolic(x) -> bool:
    """True for a symbolic array: a numpy array of CasADi scalar expressions (dtype object; module docstring)."""
    return isinstance(x, np.ndarray) and x.dtype == object


def _casadi():
    import casadi

    return casadi


def _elementwise(function, *args):
    """``function`` applied to the elements of ``args`` (broadcast), as a symbolic array."""
    return np.frompyfunc(function, len(args), 1)(*args)


def as_array(x):
    """``x`` as an array of its backend: a tensor or a symbolic array as it is, anything else as a float numpy array."""
    return x if is_tensor(x) or is_symbolic(x) else np.asarray(x, dtype=float)


def greater(x, limit: float):
    """x > limit element-wise (a symbolic array: CasADi 0/1 expressions, for :func:`where`)."""
    return _elementwise(lambda a: a > limit, x) if is_symbolic(x) else x > limit


def less(x, limit: float):
    """x < limit element-wise (a symbolic array: CasADi 0/1 expressions, for :func:`where`)."""
    return _elementwise(lambda a: a < limit, x) if is_symbolic(x) else x < limit


def clamp_min(x, low: float):
    """max(x, low) element-wise."""
    if is_symbolic(x):
        return _elementwise(lambda a: _casadi().fmax(a, low), x)
    return x.clamp_min(low) if is_tensor(x) else np.maximum(x, low)


def exp(x):
    """e^x element-wise (a Python float gives a numpy float)."""
    return x.exp() if is_tensor(x) else np.exp(x)


def sqrt(x):
    """√x element-wise."""
    return x.sqrt() if is_tensor(x) else np.sqrt(x)


def cross(a, b):
    """a × b of (..., 3) vectors."""
    if is_tensor(a) or is_tensor(b):
        import torch

        return torch.linalg.cross(a, b, dim=-1)
    out = np.empty(np.broadcast_shapes(a.shape, b.shape), dtype=np.result_type(a, b))  # np.cross: 2x slower on (1, 3)
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def rotate(rot, v):
    """R v (B, 3) of rotations (B, 3, 3) and vectors (B, 3). On torch one ``bmm`` (28 us against 48 us for a
    broadcast sum ``(R * v[:, None, :]).sum(2)``, B = 256, float32, one thread, torch 2.13); ``bmm`` rather than
    ``@``, whose batched form adds expand and reshape views: about 5 autograd nodes less per call in the hybrid's
    training (116 -> 101 per step of its TorchScript trace, with :func:`rotate_back`'s)."""
    if is_tensor(rot):
        return rot.bmm(v[..., None])[..., 0]
    return np.einsum("bij,bj->bi", rot, v)


def rotate_back(rot, v):
    """R^T v (B, 3) (on torch one ``bmm``, as :func:`rotate`)."""
    if is_tensor(rot):
        return rot.transpose(-1, -2).bmm(v[..., None])[..., 0]
    return np.einsum("bji,bj->bi", rot, v)


def columns(parts):
    """(B, k) from k arrays (B,)."""
    if is_tensor(parts[0]):
        import torch

        return torch.stack(parts, dim=1)
    out = np.empty((len(parts[0]), len(parts)), dtype=np.result_type(*parts))  # np.column_stack: 2x slower on (1,)
    for i, part in enumerate(parts):
        out[:, i] = part
    return out


def vector_norm(x, keepdims: bool = False):
    """Euclidean norm of each row of (B, k) ``x``."""
    if is_tensor(x):
        return x.norm(dim=1, keepdim=keepdims)
    if is_symbolic(x):
        return np.sqrt((x * x).sum(axis=1, keepdims=keepdims))
    return np.linalg.norm(x, axis=1, keepdims=keepdims)


def where(condition, a, b):
    """a where condition, else b."""
    if is_tensor(condition):
        import torch

        return torch.where(condition, a, b)
    if is_symbolic(condition):
        return _elementwise(lambda c, x, y: _casadi().if_else(c, x, y), condition, a, b)
    return np.where(condition, a, b)


def atan2(y, x):
    """atan2(y, x) element-wise."""
    if is_tensor(y):
        import torch

        return torch.atan2(y, x)
    if is_symbolic(y) or is_symbolic(x):
        return _elementwise(lambda a, b: _casadi().atan2(a, b), y, x)
    return np.arctan2(y, x)


def remainder(x, modulus: float):
    """x mod modulus, with the sign of the modulus (Python's %, numpy's and torch's remainder)."""
    if is_symbolic(x):
        return x - modulus * _elementwise(lambda a: _casadi().floor(a / modulus), x)
    return x.remainder(modulus) if is_tensor(x) else np.remainder(x, modulus)


def sin(x):
    return x.sin() if is_tensor(x) else np.sin(x)


def cos(x):
    return x.cos() if is_tensor(x) else np.cos(x)


def zeros_like(x):
    if is_tensor(x):
        import torch

        return torch.zeros_like(x)
    return np.zeros_like(x)


def unit_z_like(v, value: float):
    """(B, 3) of ``v``'s batch and backend holding (0, 0, value)."""
    out = zeros_like(v)
    if is_tensor(v):
        import torch

        return out + torch.tensor([0.0, 0.0, value], dtype=v.dtype)
    out[:, 2] = value
    return out

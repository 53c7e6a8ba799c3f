"""The hybrid model's residual network in numpy: a small tanh MLP with stored normalisation.

Inference needs no torch: the trained weights are plain float64 arrays (stored in the hybrid
``.npz`` model file through :mod:`quad_modelling.core.models.model_files`). With input features
``f`` (F,), their training mean/std ``μ_f, σ_f`` and the output scale ``s`` (6,):

.. math::

    h_0 = (f − μ_f) / σ_f, \\qquad h_{j+1} = \\tanh(W_j h_j + b_j)\\ (j < L),
    \\qquad Δ = s ⊙ (W_L h_L + b_L)

``Δ`` is the network's correction (units of ``s``; in the hybrid: three linear accelerations in
body FRD [m/s²] then three angular accelerations [rad/s²]). The last layer starts at zero, so an
untrained net adds exactly nothing.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from quad_modelling.core.physics import arrays
from quad_modelling.errors import ModelError

ARRAY_PREFIX = "net_"
"""Prefix of the net's arrays in a model file (``net_w0``, ``net_b0``, ..., ``net_in_mean``...)."""


@dataclass
class ResidualNet:
    """Weights ``weights[j]`` (out, in), ``biases[j]`` (out,), input mean/std (F,), output scale (n_out,)."""

    weights: list[np.ndarray]
    biases: list[np.ndarray]
    in_mean: np.ndarray
    in_std: np.ndarray
    out_scale: np.ndarray

    def __post_init__(self) -> None:
        if not self.weights or len(self.weights) != len(self.biases):
            raise ModelError(f"residual net: {len(self.weights)} weight matrices for {len(self.biases)} bias vectors")
        width = len(self.in_mean)
        if self.in_std.shape != (width,):
            raise ModelError(f"residual net: input std has shape {self.in_std.shape}, expected ({width},)")
        for j, (w, b) in enumerate(zip(self.weights, self.biases)):
            if w.ndim != 2 or w.shape[1] != width or b.shape != (w.shape[0],):
                raise ModelError(f"residual net: layer {j} has weights {w.shape} and bias {b.shape} after {width} inputs")
            width = w.shape[0]
        if self.out_scale.shape != (width,):
            raise ModelError(f"residual net: output scale has shape {self.out_scale.shape}, expected ({width},)")
        for name, value in self.arrays().items():
            if not np.all(np.isfinite(value)):
                raise ModelError(f"residual net: array {name} holds non-finite values")
        if not np.all(self.in_std > 0):  # the inputs are divided by it: a 0 made NaN forecasts and a NaN export
            raise ModelError(f"residual net: input std holds a value <= 0 (feature {int(np.argmin(self.in_std > 0))}); it is positive")

    @property
    def n_inputs(self) -> int:
        return len(self.in_mean)

    @property
    def n_outputs(self) -> int:
        return len(self.out_scale)

    @property
    def hidden(self) -> tuple[int, ...]:
        return tuple(w.shape[0] for w in self.weights[:-1])

    def forward(self, features: np.ndarray) -> np.ndarray:
        """Correction Δ (..., n_out) of features (..., F) (module docstring); numpy or symbolic
        (:mod:`quad_modelling.core.physics.arrays`: the CasADi export builds the net's expression with this code)."""
        h = (arrays.as_array(features) - self.in_mean) / self.in_std
        for w, b in zip(self.weights[:-1], self.biases[:-1]):
            h = np.tanh(h @ w.T + b)
        return (h @ self.weights[-1].T + self.biases[-1]) * self.out_scale

    def is_zero(self) -> bool:
        """True when the net adds nothing (last layer all zero)."""
        return not (np.any(self.weights[-1]) or np.any(self.biases[-1]))

    # ---- model files ---------------------------------------------------------
    def arrays(self) -> dict[str, np.ndarray]:
        """The arrays stored in a model file (names with :data:`ARRAY_PREFIX`)."""
        out = {f"{ARRAY_PREFIX}in_mean": self.in_mean, f"{ARRAY_PREFIX}in_std": self.in_std,
               f"{ARRAY_PREFIX}out_scale": self.out_scale}
        for j, (w, b) in enumerate(zip(self.weights, self.biases)):
            out[f"{ARRAY_PREFIX}w{j}"] = w
            out[f"{ARRAY_PREFIX}b{j}"] = b
        return out

    @staticmethod
    def stores(name: str) -> bool:
        """Whether a model file's array ``name`` is one of a net's (:meth:`arrays`)."""
        return re.fullmatch(f"{ARRAY_PREFIX}(w[0-9]+|b[0-9]+|in_mean|in_std|out_scale)", name) is not None

    @classmethod
    def from_arrays(cls, contents: dict[str, np.ndarray], where: str) -> ResidualNet:
        """The net stored in ``contents`` (a model file's arrays); ModelError naming ``where`` when incomplete."""
        layers = 0
        while f"{ARRAY_PREFIX}w{layers}" in contents:
            layers += 1
        try:
            weights = [np.asarray(contents[f"{ARRAY_PREFIX}w{j}"], dtype=float) for j in range(layers)]
            biases = [np.asarray(contents[f"{ARRAY_PREFIX}b{j}"], dtype=float) for j in range(layers)]
            stats = [np.asarray(contents[f"{ARRAY_PREFIX}{k}"], dtype=float) for k in ("in_mean", "in_std", "out_scale")]
        except KeyError as err:
            raise ModelError(f"{where}: residual net array {err.args[0]} is missing") from err
        except (TypeError, ValueError) as err:
            raise ModelError(f"{where}: residual net arrays are not numbers ({err})") from err
        try:
            return cls(weights, biases, *stats)
        except ModelError as err:
            raise ModelError(f"{where}: {err}") from err


def zero_net(in_mean: np.ndarray, in_std: np.ndarray, out_scale: np.ndarray, hidden: tuple[int, ...],
             rng: np.random.Generator) -> ResidualNet:
    """A net of the given hidden widths: hidden layers drawn as torch.nn.Linear does (U(±1/√fan_in)), last layer zero."""
    widths = [len(in_mean), *hidden, len(out_scale)]
    weights, biases = [], []
    for j, (fan_in, fan_out) in enumerate(zip(widths[:-1], widths[1:])):
        bound = 1.0 / np.sqrt(fan_in)
        last = j == len(widths) - 2
        weights.append(np.zeros((fan_out, fan_in)) if last else rng.uniform(-bound, bound, (fan_out, fan_in)))
        biases.append(np.zeros(fan_out) if last else rng.uniform(-bound, bound, fan_out))
    return ResidualNet(weights, biases, np.asarray(in_mean, float), np.maximum(np.asarray(in_std, float), 1e-9),
                       np.asarray(out_scale, float))

"""A published network's forward pass in numpy: actors and the evaluator act without torch.

The learner's acting networks are plain MLPs (learner/td3/networks.py): `mlp` is
``[Standardize ->] Linear -> [LayerNorm ->] ReLU -> ... -> Linear``, and `Actor` squashes
its output into the action box with ``centre + half_width * tanh(·)``. Weights arrive as
numpy arrays named as in the learner's state dict (``net.0.weight``, ``net.0.bias``, ...,
``action_low``, ``action_high`` for an actor; ``0.weight``, ... for a Q network; a
LayerNorm's are 1-d; a Standardize's, first, are ``0.shift`` and ``0.scale``).
`PolicyNet` computes the same function from them in float32, so an actor process never
imports torch: it starts about 1.4 s of CPU sooner and holds a few hundred MB less.
"""

from __future__ import annotations

import re
from typing import Optional, Protocol

import numpy as np

from service.core import WeightArrays

_LINEAR = re.compile(r"^(?P<prefix>.*?)(?P<index>\d+)\.(?P<part>weight|bias|shift|scale)$")
_SQUASH = ("action_low", "action_high")


class ActingNet(Protocol):
    """What a behaviour acts with: maps inputs [B, in] to outputs [B, out] and adopts
    published weights. A `PolicyNet` in actors; a benchmark may act with a live network."""

    def __call__(self, x: np.ndarray) -> np.ndarray: ...

    def load(self, weights: WeightArrays) -> None: ...


class PolicyNet:
    """``x -> [(x - shift) / scale ->] Linear -> [LayerNorm ->] ReLU -> ... -> Linear
    [-> centre + half_width * tanh]`` in numpy."""

    def __init__(self, weights: WeightArrays) -> None:
        """Builds the network from its weights (see `load`).

        Raises:
            ValueError: If the names do not describe an MLP (see `load`).
        """
        self._layers: list[tuple[np.ndarray, np.ndarray, Optional[tuple[np.ndarray, ...]]]] = []
        self._squash: Optional[tuple[np.ndarray, np.ndarray]] = None
        self._standardize: Optional[tuple[np.ndarray, np.ndarray]] = None
        self._shapes: Optional[dict[str, tuple[int, ...]]] = None
        self.load(weights)

    def load(self, weights: WeightArrays) -> None:
        """Adopts new weights of the same names and shapes (as torch's strict
        `load_state_dict` does).

        Raises:
            ValueError: If a name is not a linear layer's or the squash bounds, a layer
                lacks its weight or bias, or the names or shapes differ from the first.
        """
        shapes = {k: tuple(np.shape(v)) for k, v in weights.items()}
        if self._shapes is not None and shapes != self._shapes:
            raise ValueError(
                f"weights named/shaped {sorted(shapes.items())} do not fit this network's "
                f"{sorted(self._shapes.items())}"
            )
        layers: dict[int, dict[str, np.ndarray]] = {}
        prefixes = set()
        for name, value in weights.items():
            match = _LINEAR.match(name)
            if match is None and name not in _SQUASH:
                raise ValueError(f"weight {name!r} is not a linear layer's or an action bound")
            if match is not None:
                prefixes.add(match["prefix"])
                part = layers.setdefault(int(match["index"]), {})
                part[match["part"]] = np.array(value, dtype=np.float32)  # its own copy
        if len(prefixes) > 1:  # e.g. a twin critic: split it into its networks first
            raise ValueError(f"weights of more than one network: {sorted(prefixes)}")
        self._standardize = None
        first = min(layers, default=0)
        if {"shift", "scale"} & set(layers.get(first, {})):
            self._standardize = self._standardizer(layers.pop(first))
        if any(set(part) != {"weight", "bias"} for part in layers.values()) or not layers:
            raise ValueError(f"every linear layer needs a weight and a bias: {sorted(shapes)}")
        self._layers = []
        for i in sorted(layers):
            weight, bias = layers[i]["weight"], layers[i]["bias"]
            if weight.ndim == 2:
                self._layers.append((weight.T, bias, None))
            elif self._layers and self._layers[-1][2] is None:  # a LayerNorm's scale, shift
                self._layers[-1] = (*self._layers[-1][:2], (weight, bias))
            else:
                raise ValueError(f"layer {i}: a LayerNorm must follow a linear layer")
        if all(k in weights for k in _SQUASH):
            low, high = (np.array(weights[k], dtype=np.float32) for k in _SQUASH)
            self._squash = ((high + low) / 2, (high - low) / 2)
        elif any(k in weights for k in _SQUASH):
            raise ValueError(f"an actor needs both {_SQUASH}, got {sorted(shapes)}")
        self._shapes = shapes

    @staticmethod
    def _standardizer(part: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """A Standardize's (shift, scale); refuses one without both."""
        if set(part) != {"shift", "scale"}:
            raise ValueError(f"a standardizer needs a shift and a scale, got {sorted(part)}")
        return part["shift"], part["scale"]

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """The network's output for inputs [B, in], float32 [B, out]."""
        h = np.asarray(x, dtype=np.float32)
        if self._standardize is not None:
            shift, scale = self._standardize
            n = len(shift)
            h = np.concatenate([(h[..., :n] - shift) / scale, h[..., n:]], axis=-1)
        for weight, bias, norm in self._layers[:-1]:
            h = h @ weight + bias
            if norm is not None:  # torch's LayerNorm: biased variance, eps 1e-5
                centred = h - h.mean(axis=-1, keepdims=True)
                scale = np.sqrt((centred * centred).mean(axis=-1, keepdims=True) + 1e-5)
                h = centred / scale * norm[0] + norm[1]
            h = np.maximum(h, 0.0)
        weight, bias, _ = self._layers[-1]
        h = h @ weight + bias
        if self._squash is not None:
            centre, half_width = self._squash
            h = centre + half_width * np.tanh(h)
        return h


class TwinQ:
    """A twin critic (learner/td3/networks.py's `TwinCritic`) in numpy: the smaller of its
    two estimates, min(Q1, Q2)(x, a), as value-based switching takes it."""

    def __init__(self, weights: WeightArrays) -> None:
        self.q1, self.q2 = (PolicyNet(part) for part in self._split(weights))

    @staticmethod
    def _split(weights: WeightArrays) -> tuple[WeightArrays, WeightArrays]:
        parts = tuple(
            {k.removeprefix(p): v for k, v in weights.items() if k.startswith(p)}
            for p in ("q1_net.", "q2_net.")
        )
        if sum(map(len, parts)) != len(weights):
            raise ValueError(
                f"a twin critic's weights are q1_net.* and q2_net.*: {sorted(weights)}"
            )
        return parts[0], parts[1]

    def load(self, weights: WeightArrays) -> None:
        """Adopts new weights of the same names and shapes."""
        q1, q2 = self._split(weights)
        self.q1.load(q1)
        self.q2.load(q2)

    def __call__(self, x: np.ndarray, action: np.ndarray) -> np.ndarray:
        """min(Q1, Q2) of inputs [B, in] and actions [B, A], float32 [B]."""
        xa = np.concatenate([np.asarray(x, np.float32), np.asarray(action, np.float32)], axis=-1)
        return np.minimum(self.q1(xa), self.q2(xa))[:, 0]

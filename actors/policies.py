"""Behaviour-policy helpers for actors: Gaussian exploration noise and uniform random actions.

Each sampler returns the action together with its log-likelihood under the behaviour
policy, which the learner needs for importance ratios (paper eq. (14), ρ = π / π_old).
"""

import math

import numpy as np

_LOG_2PI = math.log(2.0 * math.pi)


def gaussian_log_prob(action: np.ndarray, mean: np.ndarray, std: float | np.ndarray) -> np.ndarray:
    """Log-density of a diagonal Gaussian, summed over the action dimension.

    ``log N(a | μ, σ²) = Σ_j [ −½ ((a_j − μ_j) / σ_j)² − log σ_j − ½ log 2π ]``

    Args:
        action: Actions, shape [B, A] (or [A]).
        mean: Means, broadcastable to ``action``.
        std: Standard deviation(s) (not variance), scalar or broadcastable to ``action``.

    Returns:
        float64 log-densities of shape [B] (a scalar array for a single action).

    Raises:
        ValueError: If any standard deviation is not strictly positive.
    """
    std_arr = np.asarray(std, dtype=np.float64)
    if np.any(std_arr <= 0.0):
        raise ValueError(f"std must be > 0 everywhere, got {std}: the density is undefined")
    z = (np.asarray(action, dtype=np.float64) - np.asarray(mean, dtype=np.float64)) / std_arr
    per_dim = -0.5 * z**2 - np.log(std_arr) - 0.5 * _LOG_2PI
    return np.sum(np.broadcast_to(per_dim, z.shape), axis=-1)


def _as_bounds(low: float | np.ndarray, high: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Converts action bounds to float64 arrays of shape [A] and checks low < high."""
    low_arr = np.atleast_1d(np.asarray(low, dtype=np.float64))
    high_arr = np.atleast_1d(np.asarray(high, dtype=np.float64))
    if low_arr.shape != high_arr.shape or low_arr.ndim != 1:
        raise ValueError(
            f"low {low_arr.shape} and high {high_arr.shape} must be scalars or vectors of "
            "the same shape [action_dim]"
        )
    if not np.all(np.isfinite(low_arr) & np.isfinite(high_arr) & (low_arr < high_arr)):
        raise ValueError(f"action bounds must be finite with low < high, got {low} and {high}")
    return low_arr, high_arr


class GaussianExploration:
    """Additive Gaussian exploration noise around a deterministic action.

    The behaviour policy is ``a ~ N(μ(s), σ² I)``. Actions are returned UNCLIPPED: the
    environment clips them itself, and the importance ratios computed later are taken
    on the unclipped sampled action, whose density is the Gaussian's (the clipped
    action has a point mass at the bounds and no such density).
    """

    def __init__(self, std: float, low: float | np.ndarray, high: float | np.ndarray) -> None:
        """Initialises the sampler.

        Args:
            std: Absolute standard deviation of the noise, in action units.
            low: Lower action bound(s), scalar or shape [A].
            high: Upper action bound(s), scalar or shape [A].

        Raises:
            ValueError: If ``std`` is not positive or the bounds are invalid.
        """
        if not std > 0.0:
            raise ValueError(
                f"std={std} must be > 0: a zero std makes the behaviour density a point "
                "mass and every importance ratio undefined; use the policy directly instead"
            )
        self.std = float(std)
        self.low, self.high = _as_bounds(low, high)

    def sample(self, mean: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Samples exploratory actions around ``mean``.

        Args:
            mean: Deterministic actions, shape [B, A] (or [A]).
            rng: Random generator; the only source of randomness.

        Returns:
            ``(action, log_prob)``: the UNCLIPPED float32 action, shape like ``mean``, and
            its float64 log-likelihood under N(mean, std²), shape [B] (scalar for [A]).

        Raises:
            ValueError: If the last dimension of ``mean`` is not the action dimension.
        """
        mean = np.asarray(mean, dtype=np.float32)
        if mean.ndim == 0 or mean.shape[-1] != self.low.shape[0]:
            raise ValueError(
                f"mean has shape {mean.shape}; expected [B, {self.low.shape[0]}] or "
                f"[{self.low.shape[0]}]"
            )
        noise = rng.standard_normal(mean.shape) * self.std
        action = (mean + noise).astype(np.float32)
        # Density of the float32 action actually stored, so replay and ratios agree.
        return action, gaussian_log_prob(action, mean, self.std)

    def clip(self, action: np.ndarray) -> np.ndarray:
        """Clips actions to the bounds, as the environment does when it applies them."""
        return np.clip(action, self.low, self.high).astype(np.float32)


class UniformRandomPolicy:
    """Uniform random actions over a box, the paper's random baseline."""

    def __init__(self, low: float | np.ndarray, high: float | np.ndarray) -> None:
        """Initialises the policy.

        Args:
            low: Lower action bound(s), scalar or shape [A].
            high: Upper action bound(s), scalar or shape [A].

        Raises:
            ValueError: If the bounds are not finite with low < high.
        """
        self.low, self.high = _as_bounds(low, high)
        self.log_prob = -float(np.sum(np.log(self.high - self.low)))
        """Log-density of every action in the box: −Σ_j log(high_j − low_j)."""

    def sample(self, batch: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Samples a batch of actions.

        Args:
            batch: Number of actions B.
            rng: Random generator; the only source of randomness.

        Returns:
            ``(action, log_prob)``: float32 actions of shape [B, A] and float64
            log-densities of shape [B].
        """
        action = rng.uniform(self.low, self.high, size=(batch, self.low.shape[0]))
        return action.astype(np.float32), np.full(batch, self.log_prob, dtype=np.float64)

"""The backbone behaviour (sec. III-B): a = μ(s) + clip(π(s), [−L, L]), eq. (10).

μ is the hard-coded policy (or a trained teacher actor μ̂, eq. 11) and drives behaviour;
π learns the correction. Exploration noise is added to the correction only, so the
backbone keeps steering the trajectories. Replay stores μ(s) (``backbone_action``) and
the sampled correction (``action``, unclipped) separately. With ``observe_backbone`` π and
the critics also see μ(s) (`backbone_input`), and replay stores μ(s') too
(``next_backbone_action``) so that the learner can form the input at s'.

With a ``centre`` the actor is standalone (IBRL, Hu et al. 2023), not a residual: the same
machinery with the box's centre as the base, a = clip(centre + c), and the tree proposes
c = μ(s) − centre where the residual's tree proposes c = 0.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Optional

import numpy as np

from actors.behaviours.gaussian import box_column
from actors.behaviours.switching import check_margin, split_weights, switch_mask
from actors.hardcoded import HardCodedPolicy
from actors.policies import gaussian_log_prob
from actors.policy_net import ActingNet, TwinQ
from service.core import Columns, ColumnSpec, WeightArrays


def compose_action(
    backbone: np.ndarray,
    correction: np.ndarray,
    *,
    limit: float,
    low: np.ndarray,
    high: np.ndarray,
) -> np.ndarray:
    """Eq. (10) with clipping: clip(μ(s) + clip(c, −limit, limit), low, high).

    Args:
        backbone: μ(s), [B, A].
        correction: c (e.g. π(s) + noise), [B, A].
        limit: Half-width L of the correction range [−L, L].
        low: Lower action bounds [A].
        high: Upper action bounds [A].

    Returns:
        float32 actions the environment applies, [B, A].
    """
    corrected = np.asarray(backbone) + np.clip(correction, -limit, limit)
    return np.clip(corrected, low, high).astype(np.float32)


def backbone_input(obs: np.ndarray, backbone: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """The correction's input when it observes the backbone: [s, μ(s) / scale], [B, O + A]
    (float32; `learner.backbone.networks.backbone_input` is the same on tensors)."""
    return np.concatenate(
        [np.asarray(obs, np.float32), np.asarray(backbone, np.float32) / scale], axis=-1
    ).astype(np.float32)


class BackboneBehaviour:
    """Acts μ(s) + clip(c), c ~ N(π(s), σ²); warm-up c ~ N(0, σ_prefill²) (a = μ(s) + ε)."""

    def __init__(
        self,
        correction: ActingNet,
        backbone: HardCodedPolicy,
        *,
        limit: float,
        std: float,
        prefill_std: float,
        low: np.ndarray,
        high: np.ndarray,
        observe_backbone: bool = False,
        tree_input: bool = True,
        gate: Optional[Callable[[np.ndarray], np.ndarray]] = None,
        critic: Optional[TwinQ] = None,
        switch_margin: Optional[float] = None,
        propose_tree: bool = False,
        centre: Optional[np.ndarray] = None,
        prefill_uniform: float = 0.0,
    ) -> None:
        """Initialises the behaviour.

        Args:
            correction: The correction network π, outputs in [−limit, limit].
            backbone: μ, batched [B, obs_dim] -> [B, A].
            limit: Half-width of the correction range.
            std: Exploration noise std on the correction, in action units.
            prefill_std: Std of ε in the prefill actions μ(s) + ε.
            low: Lower action bounds [A].
            high: Upper action bounds [A].
            observe_backbone: Replay stores μ(s') too, and π's and the critic's input is
                [s, μ(s) / high] instead of s.
            tree_input: With observe_backbone, False keeps the networks' input s alone
                (μ(s) only the tree's proposal).
            gate: Where it returns False ([B] bool from the observation) the greedy
                policy drops the correction and acts μ(s) alone (e.g. the tree's recovery
                when progress stalls). Exploration ignores it.
            critic: The twin critic Q(s, c) (published with the weights under
                ``critic.``), for value-based switching; needs `switch_margin`.
            switch_margin: The greedy policy acts π's correction only where the smaller
                twin estimate values it above the tree's (c = 0) by this fraction of
                |Q(s, 0)| (`switch_mask`), else the tree alone. None: no switching.
                Exploration ignores it.
            propose_tree: Exploration acts around π's correction or the tree's (c = 0),
                whichever the critic values higher (IBRL's acting); needs `critic`.
            centre: A standalone actor: the action is clip(centre + c) (π's range the box
                around it: `limit` its largest half-width), and wherever the residual's
                tree proposes c = 0 (prefill, `propose_tree`, switching, `gate`) this one's
                proposes c = μ(s) − centre. None: the residual, a = μ(s) + c.
            prefill_uniform: The share of prefill steps, each drawn apart, that act
                uniformly in the box (a residual's c clipped to ±limit), not μ(s) + ε.
        """
        check_margin("switch_margin", switch_margin)
        if critic is None and (switch_margin is not None or propose_tree):
            raise ValueError("value-based switching and propose_tree need a critic")
        if critic is not None and switch_margin is None and not propose_tree:
            raise ValueError("a critic is used by switching (switch_margin) or propose_tree")
        self.critic = critic
        self.propose_tree = propose_tree
        self.switch_margin = switch_margin
        self.tree_only = False
        self._switched: list[float] = []
        self.correction = correction
        self.observe_backbone = observe_backbone
        self.tree_input = observe_backbone and tree_input
        self._next_mu: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        """Per environment, (s', μ(s')) from `next_columns`: s' is its next step's s unless
        its episode ended."""
        self.gate = gate
        self.centre = None if centre is None else np.asarray(centre, np.float32)
        self.backbone = backbone
        self.limit = float(limit)
        self.low, self.high = np.asarray(low), np.asarray(high)
        self.std, self.prefill_std = float(std), float(prefill_std)
        self.prefill_uniform = float(prefill_uniform)
        if not 0.0 <= self.prefill_uniform <= 1.0:
            raise ValueError(f"prefill_uniform={prefill_uniform} must be a share in [0, 1]")
        for name in ("std", "prefill_std"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"{name}={getattr(self, name)} must be > 0 (log_prob needs it)")

    def columns(self) -> dict[str, ColumnSpec]:
        shape = tuple(self.low.shape)
        columns: dict[str, ColumnSpec] = {
            "action": box_column(shape),
            "backbone_action": box_column(shape),
            "log_prob": {"dtype": "float32", "shape": []},
        }
        if self.observe_backbone:
            columns["next_backbone_action"] = box_column(shape)
        return columns

    def load(self, weights: WeightArrays) -> None:
        policy, critic, self.tree_only = split_weights(weights)
        self.correction.load(policy)
        if self.critic is not None:
            self.critic.load(critic)

    def _mu(self, obs: np.ndarray, envs: Optional[np.ndarray] = None) -> np.ndarray:
        obs = np.asarray(obs)
        rows = range(len(obs)) if envs is None else envs.tolist()
        known = [self._next_mu.get(e) for e in rows]
        # μ(s') was computed for the previous step's columns: tick the backbone only on the
        # rows whose episode restarted (or that it has not seen yet).
        fresh = np.array(
            [k is None or not np.array_equal(k[0], o) for k, o in zip(known, obs, strict=True)]
        )
        mu = np.empty((len(obs), *self.low.shape), dtype=np.float32)
        if fresh.any():
            mu[fresh] = np.asarray(self.backbone(obs[fresh]), dtype=np.float32)
        for j, k in enumerate(known):
            if not fresh[j] and k is not None:
                mu[j] = k[1]
        return mu

    def _input(self, obs: np.ndarray, mu: np.ndarray) -> np.ndarray:
        """The networks' input: [s, μ(s) / high] where they see the tree, else s."""
        return backbone_input(obs, mu, self.high.astype(np.float32)) if self.tree_input else obs

    def _pi(self, obs: np.ndarray, mu: np.ndarray) -> np.ndarray:
        return self.correction(self._input(obs, mu))

    def _tree(self, mu: np.ndarray) -> np.ndarray:
        """The tree's proposal as π's output, [B, A]: the correction 0 (residual), or a
        standalone actor's μ(s) − centre (μ(s) clipped to the box first)."""
        if self.centre is None:
            return np.zeros_like(mu)
        return (np.clip(mu, self.low, self.high) - self.centre).astype(np.float32)

    def _compose(self, mu: np.ndarray, correction: np.ndarray) -> np.ndarray:
        """The applied action: μ(s) + clip(c) (residual) or centre + clip(c), in the box."""
        return compose_action(
            self._base(mu), correction, limit=self.limit, low=self.low, high=self.high
        )

    def _base(self, mu: np.ndarray) -> np.ndarray:
        """What the correction is added to: μ(s) (residual) or the box's centre, [B, A]."""
        return mu if self.centre is None else np.broadcast_to(self.centre, mu.shape)

    def _switch(
        self, obs: np.ndarray, mu: np.ndarray, correction: np.ndarray, tree: np.ndarray
    ) -> np.ndarray:
        """[B] bool: where the critic values π's correction above the tree's proposal."""
        assert self.critic is not None and self.switch_margin is not None
        obs = self._input(obs, mu)
        q_tree = self.critic(obs, tree)
        q_policy = self.critic(obs, correction)
        use = switch_mask(q_tree, q_policy, self.switch_margin)
        self._switched.append(float(use.mean()))
        return use

    def greedy(self, obs: np.ndarray) -> np.ndarray:
        mu = np.asarray(self.backbone(obs), dtype=np.float32)
        if self.tree_only:  # the final selection kept the tree
            return compose_action(
                mu, np.zeros_like(mu), limit=self.limit, low=self.low, high=self.high
            )
        correction, tree = self._pi(obs, mu), self._tree(mu)
        if self.gate is not None:
            correction = np.where(self.gate(obs)[..., None], correction, tree)
        if self.switch_margin is not None:
            use = self._switch(obs, mu, correction, tree)
            correction = np.where(use[..., None], correction, tree)
        return self._compose(mu, correction)

    def next_columns(self, next_obs: np.ndarray, envs: Optional[np.ndarray] = None) -> Columns:
        """Columns about s' the learner needs: μ(s') when π observes the backbone."""
        if not self.observe_backbone:
            return {}
        mu = self._mu(next_obs, envs)
        rows = range(len(next_obs)) if envs is None else envs.tolist()
        for j, e in enumerate(rows):
            self._next_mu[e] = (np.array(next_obs[j], copy=True), mu[j])
        return {"next_backbone_action": mu}

    def act(
        self,
        obs: np.ndarray,
        rng: np.random.Generator,
        *,
        warmup: bool,
        envs: Optional[np.ndarray] = None,
    ) -> tuple[np.ndarray, Columns]:
        mu = self._mu(obs, envs)
        tree = self._tree(mu)  # the prefill acts around the tree: a = μ(s) + ε
        mean = tree if warmup else self._pi(obs, mu)
        if self.propose_tree and not warmup:  # IBRL: around whichever the critic values more
            assert self.critic is not None
            x = self._input(obs, mu)
            better = self.critic(x, mean) > self.critic(x, tree)
            mean = np.where(better[:, None], mean, tree).astype(np.float32)
        std = self.prefill_std if warmup else self.std
        # Noise on the correction only; the sample is stored unclipped (ratios are taken on it).
        correction = (mean + std * rng.standard_normal(mean.shape)).astype(np.float32)
        if warmup and self.prefill_uniform > 0.0:  # `backbone.prefill`: uniform or mixed
            correction, log_prob = self._uniform_share(mu, tree, correction, rng)
        else:
            log_prob = gaussian_log_prob(correction, mean, std)
        action = self._compose(mu, correction)
        log_prob = log_prob.astype(np.float32)
        return action, {"action": correction, "backbone_action": mu, "log_prob": log_prob}

    def _uniform_share(
        self, mu: np.ndarray, tree: np.ndarray, around: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        """The prefill's corrections with each row replaced, at odds `prefill_uniform`, by
        one that composes an action drawn uniformly from the box; and the mixture's
        log-likelihood of each (the uniform density is 1 / the box's volume)."""
        share = self.prefill_uniform
        uniform = rng.uniform(self.low, self.high, size=mu.shape) - self._base(mu)
        pick = rng.random(len(mu)) < share
        correction = np.where(pick[:, None], uniform, around).astype(np.float32)
        action = self._base(mu) + correction  # inside the box up to float32's rounding:
        inside = np.all((action >= self.low - 1e-5) & (action <= self.high + 1e-5), axis=1)
        volume = float(np.sum(np.log(self.high - self.low)))
        log_uniform = np.where(inside, np.log(share) - volume, -np.inf)
        with np.errstate(divide="ignore"):  # uniform alone: the tree's weight log 0
            log_tree = np.log1p(-share) + gaussian_log_prob(correction, tree, self.prefill_std)
        return correction, np.logaddexp(log_uniform, log_tree)

    def end_episodes(self, ended: np.ndarray, envs: Optional[np.ndarray] = None) -> None:
        pass  # a new episode's first s differs from the cached s': μ is ticked anew

    def stats(self) -> dict[str, float]:
        """With switching: the share of greedy steps π acted (``switch/policy_share``)."""
        out = {"switch/policy_share": float(np.mean(self._switched))} if self._switched else {}
        self._switched.clear()
        return out

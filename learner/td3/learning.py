"""TD3 learning step: the target, the two losses, Polyak averaging, and `TD3Learner`.

Equation numbers refer to the seed paper (sec. II-B2, III-A); the TD3 specifics
(clipped double Q, target-policy smoothing, delayed actor) are Fujimoto et al. (2018).
"""

from __future__ import annotations

import copy
from typing import Any, Optional

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from learner.captured import NoiseSource
from learner.checkpoint import load_generator_state
from learner.device import Adam, CompileMode, compile_networks
from learner.td3.captured import CapturedTD3
from learner.td3.config import TD3Config
from learner.td3.networks import Actor, TwinCritic, fit_standardizers


@torch.no_grad()
def td3_target(
    reward: torch.Tensor,
    terminated: torch.Tensor,
    next_obs: torch.Tensor,
    *,
    gamma: float,
    target_actor: nn.Module,
    target_critic: nn.Module,
    policy_noise: float,
    noise_clip: float,
    action_low: torch.Tensor,
    action_high: torch.Tensor,
    generator: torch.Generator | NoiseSource | None = None,
) -> torch.Tensor:
    """Clipped double-Q target with target-policy smoothing, eq. (5).

    a' = clip(pi'(s') + clip(N(0, (policy_noise * m)^2), -noise_clip * m, noise_clip * m),
    low, high), with m = (high - low) / 2 the max action; y = r + gamma * (1 - d) *
    min(Q1'(s', a'), Q2'(s', a')).

    Args:
        reward: r, shape [B].
        terminated: d, shape [B], bool; true only where s' is a terminal state.
        next_obs: s', shape [B, obs_dim].
        gamma: Discount factor.
        target_actor: pi', maps [B, obs_dim] to [B, act_dim].
        target_critic: (Q1', Q2'), maps (obs, act) to two [B] tensors.
        policy_noise: Smoothing noise std, as a fraction of max action.
        noise_clip: Smoothing noise bound, as a fraction of max action.
        action_low: Lower action bounds, shape [act_dim].
        action_high: Upper action bounds, shape [act_dim].
        generator: Source of the smoothing noise (a `NoiseSource` inside a captured
            step); the global RNG if None.

    Returns:
        The target y, shape [B], with no gradient.
    """
    max_action = (action_high - action_low) / 2
    next_action = target_actor(next_obs)
    if generator is None:
        eps = torch.randn_like(next_action)
    elif isinstance(generator, NoiseSource):
        eps = generator.normal_like(next_action)
    else:
        eps = torch.randn(
            next_action.shape,
            generator=generator,
            dtype=next_action.dtype,
            device=next_action.device,
        )
    bound = noise_clip * max_action
    noise = torch.clamp(eps * (policy_noise * max_action), -bound, bound)
    next_action = torch.clamp(next_action + noise, action_low, action_high)
    q1_next, q2_next = target_critic(next_obs, next_action)
    # Truncation is not termination: a time-limit cut leaves s' a live state whose value
    # we still bootstrap; only a true terminal state (terminated) zeroes the bootstrap.
    not_done = 1.0 - terminated.to(reward.dtype)
    return reward + gamma * not_done * torch.min(q1_next, q2_next)


def critic_loss(q1: torch.Tensor, q2: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Squared TD error of both critics against the shared target, eq. (9).

    Args:
        q1: Q1(s, a), shape [B].
        q2: Q2(s, a), shape [B].
        target: y from `td3_target`, shape [B], no gradient.

    Returns:
        mean((y - Q1)^2) + mean((y - Q2)^2), a scalar.
    """
    return F.mse_loss(q1, target) + F.mse_loss(q2, target)


def actor_loss(critic: TwinCritic, actor: nn.Module, obs: torch.Tensor) -> torch.Tensor:
    """Deterministic policy gradient loss: ascend Q1(s, pi(s)) (sec. II-B2).

    Args:
        critic: The online twin critic; only its first head is used.
        actor: The online actor pi.
        obs: s, shape [B, obs_dim].

    Returns:
        -mean(Q1(s, pi(s))), a scalar.
    """
    return -critic.q1(obs, actor(obs)).mean()


@torch.no_grad()
def soft_update(target: nn.Module, source: nn.Module, tau: float) -> None:
    """Polyak averaging theta' <- tau * theta + (1 - tau) * theta', in place.

    Only parameters are averaged; buffers (the actor's action bounds) are constants.

    Args:
        target: Network to move, theta'.
        source: Network to move towards, theta.
        tau: Step size in [0, 1].
    """
    # One fused call over all tensors instead of a Python loop per parameter.
    torch._foreach_lerp_(list(target.parameters()), list(source.parameters()), tau)


class TD3Learner:
    """One TD3 learner: actor, twin critic, their targets, optimisers and counters.

    The learner loop calls it like this::

        learner = make_td3_learner(obs_space, action_space, config, seed)
        while True:
            metrics = learner.update(replay.sample(config.batch_size))
            if learner.num_updates % broadcast_every == 0:
                weights.publish(learner.policy_state())
    """

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        action_low: np.ndarray,
        action_high: np.ndarray,
        *,
        config: TD3Config,
        seed: int,
        device: str | torch.device = "cpu",
        compile: CompileMode = "off",
        extra_inputs: int = 0,
    ) -> None:
        """Builds the networks (seeded, without touching the global RNG) and optimisers.

        Args:
            obs_dim: Observation size.
            act_dim: Action size.
            action_low: Lower action bounds, shape [act_dim].
            action_high: Upper action bounds, shape [act_dim].
            config: Hyper-parameters.
            seed: Seeds the network initialisation and the smoothing noise.
            device: Where the networks live and the update runs (the initial weights
                are drawn on the CPU, so every device starts from the same ones).
            compile: Compile the networks' forward passes (`learner.device.compile_networks`),
                or run each delay cycle as one captured step (``captured``,
                `learner.td3.captured`).
            extra_inputs: Inputs the networks see after the observation's (the
                backbone's μ(s)); never standardized.
        """
        self.device = torch.device(device)
        self._gamma = config.gamma
        self._tau = config.tau
        self._policy_noise = config.policy_noise
        self._noise_clip = config.noise_clip
        self._policy_delay = config.policy_delay
        self._frozen_actor_updates = config.frozen_actor_updates

        init_seed, noise_seed = np.random.SeedSequence(seed).generate_state(2)
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(int(init_seed))
            self._standardized = config.standardized(obs_dim)
            in_dim, sizes = obs_dim + extra_inputs, config.hidden_sizes
            self.actor = Actor(
                in_dim, act_dim, action_low, action_high, sizes, standardized=self._standardized
            )
            self.critic = TwinCritic(
                in_dim,
                act_dim,
                sizes,
                layer_norm=config.critic_layer_norm,
                standardized=self._standardized,
            )
        self.actor.to(self.device)
        self.critic.to(self.device)
        self.action_box = (self.actor.action_low.clone(), self.actor.action_high.clone())
        """The actions the critic values: the stored actions are clipped to it, and the
        target policy's smoothed actions (the actor's own range may be narrower)."""
        self.target_actor = copy.deepcopy(self.actor).requires_grad_(False)
        self.target_critic = copy.deepcopy(self.critic).requires_grad_(False)
        self.actor_optimizer = Adam(self.actor.parameters(), lr=config.actor_lr, device=self.device)
        self.critic_optimizer = Adam(
            self.critic.parameters(), lr=config.critic_lr, device=self.device
        )
        compile_networks(self._networks(), "off" if compile == "captured" else compile)
        self._capturing = compile == "captured"
        self._captured: Optional[CapturedTD3] = None
        self._generator = torch.Generator(device=self.device)
        self._generator.manual_seed(int(noise_seed))

        self.standardizers_fitted = not self._standardized
        """The networks' `Standardize` layers hold the first batch's statistics (or there
        are none)."""
        self.num_updates = 0
        """Calls to `update` so far (= critic updates)."""
        self.num_actor_updates = 0
        """Actor gradient steps so far (delayed, and none while frozen)."""

    def _networks(self) -> list[nn.Module]:
        """The networks an update runs (what `compile` compiles)."""
        return [self.actor, self.critic, self.target_actor, self.target_critic]

    def update(self, batch: dict[str, torch.Tensor]) -> dict[str, float]:
        """Runs one TD3 step: critic always; actor and targets every `policy_delay` calls.

        Args:
            batch: Columns ``obs`` [B, obs_dim], ``action`` [B, act_dim] (the unclipped
                sampled behaviour action), ``reward`` [B], ``terminated`` [B] bool,
                ``next_obs`` [B, obs_dim]. Other columns (``truncated``, ``log_prob``,
                ``policy_version``) are ignored: TD3 bootstraps through truncation.

        Returns:
            ``losses/critic`` and ``values/q1_mean``, plus ``losses/actor`` when the actor
            was updated on this call.
        """
        self.num_updates += 1
        # The actor stays fixed for the first `frozen_actor_updates` calls (paper fig. 3)
        # while the targets keep moving.
        return self._step(
            batch,
            step=self.num_updates,
            train_actor=self.num_updates > self._frozen_actor_updates,
        )

    def capture(self, *, compiled: Optional[str] = None) -> CapturedTD3:
        """The captured update (`learner.td3.captured`), made at its first use; `compiled`
        (on the CPU) compiles each cycle whole with that ``torch.compile`` backend."""
        if self._captured is None or self._captured.compiled != compiled:
            self._settle()
            self._captured = CapturedTD3(self, compiled=compiled)
        return self._captured

    @property
    def captures(self) -> bool:
        """Updates run as captured steps."""
        return self._capturing or self._captured is not None

    def _settle(self) -> None:
        """Applies the updates a captured cycle holds (before weights are read)."""
        if self._captured is not None:
            self._captured.settle()

    def read_metrics(self) -> dict[str, float]:
        """The captured updates' metrics since the last read, averaged (none when eager:
        each update returns its own)."""
        return {} if self._captured is None else self._captured.read_metrics()

    def _step(
        self, batch: dict[str, torch.Tensor], *, step: int, train_actor: bool, key: str = "online"
    ) -> dict[str, float]:
        """Critic step; actor (if `train_actor`) and targets when `step % policy_delay == 0`.
        Captured, the step joins its delay cycle (`key` names the counter `step` is of). The
        first step of all fits the standardizers on its observations."""
        if not self.standardizers_fitted:
            obs = batch["obs"].to(self.device)[:, : self._standardized]
            networks = (self.actor, self.critic, self.target_actor, self.target_critic)
            fit_standardizers(networks, obs)
            self.standardizers_fitted = True
        if self.captures:
            captured = self._captured or self.capture()
            return captured.step(batch, step=step, train_actor=train_actor, key=key)
        dev = self.device
        obs = batch["obs"].to(dev, non_blocking=True)
        # Actors store the *unclipped* sampled action, so that importance ratios can be
        # taken on it later; the environment applied clip(action, low, high), and that is
        # the action whose value the critic must learn.
        action = torch.clamp(batch["action"].to(dev, non_blocking=True), *self.action_box)
        target = self._critic_target(batch)
        q1, q2 = self.critic(obs, action)
        baseline = self._critic_baseline(batch)
        if baseline is not None:
            q1, q2 = q1 + baseline, q2 + baseline
        loss_critic = critic_loss(q1, q2, target)
        self.critic_optimizer.zero_grad(set_to_none=True)
        loss_critic.backward()
        self.critic_optimizer.step()

        scalars = [loss_critic.detach(), q1.detach().mean()]
        names = ["losses/critic", "values/q1_mean"]
        if step % self._policy_delay == 0:
            if train_actor:
                scalars.append(self._actor_step(obs, batch))
                names.append("losses/actor")
            soft_update(self.target_critic, self.critic, self._tau)
            soft_update(self.target_actor, self.actor, self._tau)
        # One host transfer for all metrics (a single sync on an accelerator).
        return dict(zip(names, torch.stack(scalars).tolist(), strict=True))

    def _critic_target(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        """The critics' regression target y, [B]; TD3's eq. (5) (hook: eq. 11, eq. 14)."""
        dev = self.device
        return td3_target(
            batch["reward"].to(dev, non_blocking=True),
            batch["terminated"].to(dev, non_blocking=True),
            batch["next_obs"].to(dev, non_blocking=True),
            gamma=self._gamma,
            **self._smoothing(),
        )

    def _smoothing(self) -> dict[str, Any]:
        """The target networks and target-policy smoothing that `td3_target` needs (the
        noise from inside the captured step when there is one)."""
        return {
            "target_actor": self.target_actor,
            "target_critic": self.target_critic,
            "policy_noise": self._policy_noise,
            "noise_clip": self._noise_clip,
            "action_low": self.action_box[0],
            "action_high": self.action_box[1],
            "generator": self._generator if self._captured is None else self._captured.noise,
        }

    def _observe(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """The batch as the networks see it, inside a captured step (hook: the backbone's
        [s, μ(s)] inputs; an eager update makes them before `_step`)."""
        return batch

    def _ramp_range(self, actor_steps: torch.Tensor) -> None:
        """Before a captured actor step, with the actor steps so far on the device (hook:
        the backbone's growing range)."""

    def _critic_baseline(self, batch: dict[str, torch.Tensor]) -> Optional[torch.Tensor]:
        """A fixed value added to both critics' outputs before the loss (hook: eq. 11)."""
        return None

    def _actor_loss(self, obs: torch.Tensor, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        """The actor's loss (hook: imitation eq. 8, TD3+BC); inside a captured step over
        the rows ``_rows`` keeps, when the batch has them."""
        rows = batch.get("_rows")
        if rows is not None:
            q = self.critic.q1(obs, self.actor(obs))
            return -(q * rows).sum() / rows.sum().clamp_min(1.0)
        return actor_loss(self.critic, self.actor, obs)

    def _actor_step(self, obs: torch.Tensor, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        """One gradient step on `_actor_loss`; returns the detached loss."""
        # The critic is only differentiated through, not trained here: skip its weight grads.
        self.critic.requires_grad_(False)
        loss = self._actor_loss(obs, batch)
        self.actor_optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.actor_optimizer.step()
        self.critic.requires_grad_(True)
        self.num_actor_updates += 1
        return loss.detach()

    @torch.no_grad()
    def act(self, obs: np.ndarray) -> np.ndarray:
        """Deterministic action pi(obs), shape [act_dim] or [B, act_dim], float32."""
        self._settle()
        x = torch.as_tensor(obs, dtype=torch.float32, device=self.device)
        return self.actor(x).cpu().numpy()

    def policy_state(self) -> dict[str, torch.Tensor]:
        """Actor weights as detached CPU copies, for broadcasting to actors."""
        if self._captured is not None:
            return self._captured.policy_state()
        return {k: v.detach().to("cpu", copy=True) for k, v in self.actor.state_dict().items()}

    def state_dict(self) -> dict[str, Any]:
        """Everything needed to resume bit-identically: networks, targets, optimisers,
        counters and the smoothing-noise RNG.

        Like `nn.Module.state_dict`, tensors are references to live state: serialise
        (e.g. `torch.save`) or deep-copy before training on.
        """
        self._settle()
        return {
            "actor": self.actor.state_dict(),
            "critic": self.critic.state_dict(),
            "target_actor": self.target_actor.state_dict(),
            "target_critic": self.target_critic.state_dict(),
            "actor_optimizer": self.actor_optimizer.state_dict(),
            "critic_optimizer": self.critic_optimizer.state_dict(),
            "num_updates": self.num_updates,
            "num_actor_updates": self.num_actor_updates,
            "noise_rng": self._generator.get_state(),
            "standardizers_fitted": self.standardizers_fitted,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restores a `state_dict`; training then continues exactly where it was saved.

        Args:
            state: A dict produced by `state_dict` of a learner with the same shapes.
        """
        self.actor.load_state_dict(state["actor"])
        self.critic.load_state_dict(state["critic"])
        self.target_actor.load_state_dict(state["target_actor"])
        self.target_critic.load_state_dict(state["target_critic"])
        self.actor_optimizer.load_state_dict(state["actor_optimizer"])
        self.critic_optimizer.load_state_dict(state["critic_optimizer"])
        self.num_updates = int(state["num_updates"])
        self.num_actor_updates = int(state["num_actor_updates"])
        load_generator_state(self._generator, state["noise_rng"])
        self.standardizers_fitted = bool(state.get("standardizers_fitted", True))
        if self._captured is not None:  # its graphs hold the old optimiser state
            self._captured = CapturedTD3(self, compiled=self._captured.compiled)

"""Pre-training (learner/pretrain): the imitation loss of eq. (8) and the TD3+BC actor loss,
against values computed by hand."""

from __future__ import annotations

import torch

from learner.pretrain.learning import imitation_loss, td3_bc_actor_loss


def test_imitation_loss_eq8_and_td3_bc_actor_loss():
    pi = torch.tensor([[1.0, 0.0], [0.0, 0.0]])
    mu = torch.tensor([[0.0, 0.0], [0.0, 2.0]])
    # per state Σ_j: 1 and 4; mean 2.5
    torch.testing.assert_close(imitation_loss(pi, mu), torch.tensor(2.5))
    q = torch.tensor([-4.0, -2.0])  # mean|Q| = 3 -> λ = 2.5 / 3
    expected = -(2.5 / 3) * (-3.0) + 5.0 / 4  # −λ mean Q + mean over all elements of (π − μ)²
    torch.testing.assert_close(td3_bc_actor_loss(q, pi, mu, alpha=2.5), torch.tensor(expected))

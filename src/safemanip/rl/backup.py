"""Bellman targets: the discounted reach-avoid backup (DRABE) and the usual discounted return.

Both are pure functions of tensors so they can be tested in closed form.
"""

from __future__ import annotations

import torch


def reach_avoid_target(l: torch.Tensor, g: torch.Tensor, next_value: torch.Tensor, terminated: torch.Tensor,
                       next_l: torch.Tensor, next_g: torch.Tensor, gamma: float) -> torch.Tensor:
    """Discounted reach-avoid Bellman target (paper eq. 2, Sec. IV-B) for a batch of transitions.

        y = (1 - gamma) * min(l(s), g(s)) + gamma * min(g(s), max(l(s), V'))

    Margins: ``l``/``g`` are those of the state s the action was taken in. The backup is a statement
    about s: "from s, the best achievable min-over-time of g, with the max-over-time of l inside it",
    so s's own margins bound the value (a failed s is worth at most g(s); a reached s at least l(s)),
    and everything after s enters through V'.

    V' is the bootstrap: Q_targ(s', mu_targ(s')) for a transition that did not terminate -- including
    a time-limit truncation, which is not an end of the task, so it keeps bootstrapping. For a
    terminated transition (success or failure) the episode has no future: V' is replaced by the
    terminal value min(l(s'), g(s')), the value of the absorbing state s'.
    """
    terminal_value = torch.minimum(next_l, next_g)
    bootstrap = torch.where(terminated, terminal_value, next_value)
    return (1.0 - gamma) * torch.minimum(l, g) + gamma * torch.minimum(g, torch.maximum(l, bootstrap))


def discounted_return_target(reward: torch.Tensor, next_value: torch.Tensor, terminated: torch.Tensor,
                             gamma: float) -> torch.Tensor:
    """The usual DDPG target r + gamma * (1 - d) * Q_targ(s', mu_targ(s')); truncation still bootstraps."""
    return reward + gamma * (~terminated).to(reward.dtype) * next_value

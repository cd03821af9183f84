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
                             next_reward: torch.Tensor, gamma: float) -> torch.Tensor:
    """The usual DDPG target r + gamma * V', with terminated states absorbing; truncation still bootstraps.

    V' is Q_targ(s', mu_targ(s')), except after a terminated transition (success or failure), where s' is
    absorbing: it keeps paying its own reward r(s') for ever, V' = r(s') / (1 - gamma) -- the same terminal
    rule as the reach-avoid backup's V' = min(l(s'), g(s')), in this objective's scale.

    Why not the textbook r + gamma * (1 - d) * Q' (V' = 0 at a terminal state): with r = min(l, g) < 0 on
    every step before success, a failure that ends the episode stops the penalties, so the best return
    comes from failing at once (the first version's Vanilla-RL learnt exactly that: 0 % success, the top box
    knocked over at step 2). With absorbing terminal states a failure far from the goal is worth
    min(l, g) / (1 - gamma) (about -25 at gamma = 0.98), a success l / (1 - gamma) > 0, and the comparison
    with RARL is between objectives, not between one objective and a loophole.
    """
    terminal_value = next_reward / (1.0 - gamma)
    return reward + gamma * torch.where(terminated, terminal_value, next_value)

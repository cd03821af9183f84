"""Actor and critic MLPs (paper: three layers of 256 ReLU units each)."""

from __future__ import annotations

import numpy as np
import torch
from torch import nn


def mlp(sizes: list[int]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


class Actor(nn.Module):
    def __init__(self, obs_dim: int, act_dim: int, hidden: tuple[int, ...]):
        super().__init__()
        self.net = mlp([obs_dim, *hidden, act_dim])

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return torch.tanh(self.net(obs))


class Critic(nn.Module):
    """One or two Q heads (twin critics, TD3) over (s, a)."""

    def __init__(self, obs_dim: int, act_dim: int, hidden: tuple[int, ...], n_heads: int = 2):
        super().__init__()
        self.heads = nn.ModuleList(mlp([obs_dim + act_dim, *hidden, 1]) for _ in range(n_heads))

    def forward(self, obs: torch.Tensor, act: torch.Tensor) -> list[torch.Tensor]:
        x = torch.cat([obs, act], dim=-1)
        return [head(x).squeeze(-1) for head in self.heads]


def actor_arrays(actor: Actor) -> list[np.ndarray]:
    """Weights and biases as float32 arrays, layer by layer (W as out x in)."""
    return [p.detach().cpu().numpy().astype(np.float32).copy() for p in actor.net.parameters()]


from safemanip.rl.numpy_actor import NumpyActor  # noqa: E402,F401  (re-exported for callers that have torch anyway)

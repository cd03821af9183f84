"""DDPG / TD3-style learner whose critic target is either the reach-avoid backup or the usual return.

RARL and Vanilla-RL share every line here except the one that computes the target.
"""

from __future__ import annotations

import copy

import torch
import torch.nn.functional as F

from safemanip.rl.backup import discounted_return_target, reach_avoid_target
from safemanip.rl.buffer import Batch
from safemanip.rl.config import TrainConfig
from safemanip.rl.networks import Actor, Critic


@torch.no_grad()
def polyak_update(params, target_params, polyak: float) -> None:
    """target <- polyak * target + (1 - polyak) * online, in place."""
    params, target_params = list(params), list(target_params)
    torch._foreach_mul_(target_params, polyak)
    torch._foreach_add_(target_params, params, alpha=1.0 - polyak)


class Learner:
    def __init__(self, obs_dim: int, act_dim: int, cfg: TrainConfig):
        self.cfg = cfg
        self.actor = Actor(obs_dim, act_dim, cfg.hidden)
        self.critic = Critic(obs_dim, act_dim, cfg.hidden, n_heads=2 if cfg.twin_critics else 1)
        self.actor_targ = copy.deepcopy(self.actor).requires_grad_(False)
        self.critic_targ = copy.deepcopy(self.critic).requires_grad_(False)
        self.actor_opt = torch.optim.AdamW(self.actor.parameters(), lr=cfg.learning_rate)
        self.critic_opt = torch.optim.AdamW(self.critic.parameters(), lr=cfg.learning_rate)
        self.updates = 0

    def target(self, batch: Batch, gamma: float) -> torch.Tensor:
        cfg = self.cfg
        with torch.no_grad():
            next_act = self.actor_targ(batch.next_obs)
            if cfg.target_noise > 0:  # TD3 target-policy smoothing
                noise = (torch.randn_like(next_act) * cfg.target_noise).clamp(-cfg.target_noise_clip, cfg.target_noise_clip)
                next_act = (next_act + noise).clamp(-1.0, 1.0)
            next_q = torch.stack(self.critic_targ(batch.next_obs, next_act)).min(dim=0).values
            if cfg.algorithm == "rarl":
                return reach_avoid_target(batch.l, batch.g, next_q, batch.terminated, batch.next_l, batch.next_g, gamma)
            reward = torch.minimum(batch.l, batch.g)  # paper: r = min(l(s), g(s))
            return discounted_return_target(reward, next_q, batch.terminated, gamma)

    def update(self, batch: Batch, gamma: float) -> dict[str, float]:
        y = self.target(batch, gamma)
        qs = self.critic(batch.obs, batch.act)
        critic_loss = sum(F.mse_loss(q, y) for q in qs)
        self.critic_opt.zero_grad(set_to_none=True)
        critic_loss.backward()
        self.critic_opt.step()
        self.updates += 1
        metrics = {"loss/critic": critic_loss.item(), "value/q_mean": qs[0].detach().mean().item()}
        if self.updates % self.cfg.policy_delay == 0:
            for p in self.critic.parameters():
                p.requires_grad_(False)
            actor_loss = -self.critic(batch.obs, self.actor(batch.obs))[0].mean()
            for p in self.critic.parameters():
                p.requires_grad_(True)
            self.actor_opt.zero_grad(set_to_none=True)
            actor_loss.backward()
            self.actor_opt.step()
            polyak_update(self.actor.parameters(), self.actor_targ.parameters(), self.cfg.polyak)
            polyak_update(self.critic.parameters(), self.critic_targ.parameters(), self.cfg.polyak)
            metrics["loss/actor"] = actor_loss.item()
        return metrics

    # ---------------------------------------------------------------- state for checkpoints
    def state_tensors(self) -> dict[str, torch.Tensor]:
        """Every tensor needed to resume: networks, targets, and both optimisers' moments."""
        out: dict[str, torch.Tensor] = {}
        for name, module in (("actor", self.actor), ("critic", self.critic), ("actor_targ", self.actor_targ),
                             ("critic_targ", self.critic_targ)):
            for k, v in module.state_dict().items():
                out[f"{name}.{k}"] = v.detach().clone().contiguous()
        for name, opt in (("actor_opt", self.actor_opt), ("critic_opt", self.critic_opt)):
            for pid, st in opt.state_dict()["state"].items():
                for k, v in st.items():
                    out[f"{name}.{pid}.{k}"] = torch.as_tensor(v).detach().clone().contiguous()
        return out

    def load_state_tensors(self, tensors: dict[str, torch.Tensor]) -> None:
        for name, module in (("actor", self.actor), ("critic", self.critic), ("actor_targ", self.actor_targ),
                             ("critic_targ", self.critic_targ)):
            prefix = name + "."
            module.load_state_dict({k[len(prefix):]: v for k, v in tensors.items() if k.startswith(prefix)
                                    and k.split(".")[0] == name})
        for name, opt in (("actor_opt", self.actor_opt), ("critic_opt", self.critic_opt)):
            sd = opt.state_dict()
            state: dict[int, dict] = {}
            for k, v in tensors.items():
                parts = k.split(".")
                if parts[0] == name:
                    state.setdefault(int(parts[1]), {})[parts[2]] = v
            sd["state"] = state
            opt.load_state_dict(sd)

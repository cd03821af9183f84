"""DDPG / TD3-style learner whose critic target is either the reach-avoid backup or the usual return.

RARL and Vanilla-RL share every line here except the one that computes the target.

Speed (``benchmarks/learner_throughput.py``): the twin critics are one batched module
(``networks.StackedMLP``); AdamW is the fused kernel where the device has one; the targets are
updated by one ``torch._foreach_lerp_`` over every parameter; and with ``precision`` bf16 the forward
passes run under ``torch.autocast`` while master weights, optimiser moments, losses and the Bellman
target stay fp32 (``rl/precision.py`` decides and says why).
"""

from __future__ import annotations

import contextlib
import copy

import torch

from safemanip.rl.backup import discounted_return_target, reach_avoid_target
from safemanip.rl.buffer import Batch
from safemanip.rl.config import TrainConfig
from safemanip.rl.networks import make_networks, squash
from safemanip.rl.precision import Precision, resolve_device, resolve_precision


@torch.no_grad()
def polyak_update(params, target_params, polyak: float) -> None:
    """target <- polyak * target + (1 - polyak) * online, in place, one fused call for all tensors."""
    torch._foreach_lerp_(list(target_params), list(params), 1.0 - polyak)


def make_optimizer(params, lr: float, device: torch.device) -> torch.optim.Optimizer:
    """AdamW, fused (one kernel for all parameters) where this PyTorch has it for the device."""
    params = list(params)
    try:
        return torch.optim.AdamW(params, lr=lr, fused=True)
    except (RuntimeError, ValueError):  # no fused kernel for this device / dtype
        return torch.optim.AdamW(params, lr=lr, foreach=device.type == "cuda")


class Learner:
    def __init__(self, obs_dim: int, act_dim: int, cfg: TrainConfig, precision: Precision | None = None):
        self.cfg = cfg
        self.device = resolve_device(cfg.device)
        self.precision = precision or resolve_precision(cfg.precision, self.device)
        actor, critic = make_networks(cfg.network, obs_dim, act_dim, cfg.hidden, 2 if cfg.twin_critics else 1,
                                      cfg.set_embed, cfg.env.object_size)
        self.actor, self.critic = actor.to(self.device), critic.to(self.device)
        self.actor_targ = copy.deepcopy(self.actor).requires_grad_(False)
        self.critic_targ = copy.deepcopy(self.critic).requires_grad_(False)
        self.actor_opt = make_optimizer(self.actor.parameters(), cfg.learning_rate, self.device)
        self.critic_opt = make_optimizer(self.critic.parameters(), cfg.learning_rate, self.device)
        self._online = [*self.actor.parameters(), *self.critic.parameters()]
        self._target = [*self.actor_targ.parameters(), *self.critic_targ.parameters()]
        self.updates = 0

    def set_learning_rate(self, lr: float) -> None:
        """Both optimisers' rate (a schedule's value for this update; Adam's moments are unaffected)."""
        for opt in (self.actor_opt, self.critic_opt):
            for group in opt.param_groups:
                group["lr"] = lr

    def autocast(self):
        """bf16 autocast for forward passes, or nothing (fp32)."""
        if self.precision.dtype != "bf16":
            return contextlib.nullcontext()
        return torch.autocast(self.device.type, dtype=torch.bfloat16)

    def to_device(self, batch: Batch) -> Batch:
        if self.device.type == "cpu":
            return batch
        return Batch(*(t.to(self.device, non_blocking=True) for t in batch))

    def target(self, batch: Batch, gamma: float) -> torch.Tensor:
        """The Bellman target y (fp32) from the target networks: min over the twin heads at a smoothed action."""
        cfg = self.cfg
        with torch.no_grad():
            with self.autocast():
                next_act = self.actor_targ(batch.next_obs).float()
            if cfg.target_noise > 0:  # TD3 target-policy smoothing
                noise = (torch.randn_like(next_act) * cfg.target_noise).clamp(-cfg.target_noise_clip, cfg.target_noise_clip)
                next_act = (next_act + noise).clamp(-1.0, 1.0)
            with self.autocast():
                next_qs = self.critic_targ(batch.next_obs, next_act)  # (heads, B)
            next_q = next_qs.float().min(dim=0).values
            if cfg.algorithm == "rarl":
                return reach_avoid_target(batch.l, batch.g, next_q, batch.terminated, batch.next_l, batch.next_g, gamma)
            reward = torch.minimum(batch.l, batch.g)  # paper: r = min(l(s), g(s))
            return discounted_return_target(reward, next_q, batch.terminated, torch.minimum(batch.next_l, batch.next_g),
                                            gamma)

    def update(self, batch: Batch, gamma: float) -> dict[str, float]:
        """One TD3 update on ``batch``; returns its scalars.

        On the CPU, denormal floats are flushed to zero for the update's duration. The Adam moments of weights whose
        gradient is exactly zero (dead ReLU units) decay geometrically through the denormal range, where each
        arithmetic operation costs about a hundred times its normal time: after a 400k-step benchmark run a quarter
        of the moments were denormal and the fused AdamW step ran 7x slower than on a fresh state (the loop at 0.70x
        of the learner alone, docs/benchmarks.md). Flushed, such a moment becomes 0, which it is heading to anyway.
        Only this thread and only during the update: the physics elsewhere in the process keeps IEEE arithmetic."""
        flushing = self.device.type == "cpu" and torch.set_flush_denormal(True)
        try:
            return self._update(batch, gamma)
        finally:
            if flushing:
                torch.set_flush_denormal(False)

    def _update(self, batch: Batch, gamma: float) -> dict[str, float]:
        cfg = self.cfg
        batch = self.to_device(batch)

        # ---- critic: every Q head regresses on the one target
        y = self.target(batch, gamma)
        with self.autocast():
            qs = self.critic(batch.obs, batch.act)  # (heads, B)
        critic_loss = ((qs.float() - y) ** 2).mean(dim=1).sum()
        self.critic_opt.zero_grad(set_to_none=True)
        critic_loss.backward()
        self.critic_opt.step()
        self.updates += 1
        metrics = {"loss/critic": critic_loss.detach(), "value/q_mean": qs[0].detach().float().mean()}

        # ---- actor and target networks, every policy_delay critic updates (TD3)
        if self.updates % cfg.policy_delay == 0:
            self.critic.requires_grad_(False)  # the actor loss needs no critic weight gradients
            with self.autocast():
                pre_tanh = self.actor.pre_tanh(batch.obs)
                actions = squash(pre_tanh)  # in fp32: a bf16 tanh has no gradient once saturated
                q1 = self.critic(batch.obs, actions, head=0)
            actor_loss = -q1.float().mean()
            if cfg.actor_preactivation_penalty > 0:  # keeps the actor where tanh still has a gradient
                actor_loss = actor_loss + cfg.actor_preactivation_penalty * pre_tanh.float().pow(2).mean()
            self.critic.requires_grad_(True)
            self.actor_opt.zero_grad(set_to_none=True)
            actor_loss.backward()
            self.actor_opt.step()
            polyak_update(self._online, self._target, cfg.polyak)
            metrics["loss/actor"] = actor_loss.detach()
            # share of action components pinned at the tanh bounds: near 1, the actor's gradient has vanished
            # and it emits one constant action (a DDPG failure that looks like a flat learning curve)
            metrics["actor/saturated"] = (actions.detach().float().abs() > 0.99).float().mean()
        return {k: v.item() for k, v in metrics.items()}

    # ---------------------------------------------------------------- state for checkpoints
    def state_tensors(self) -> dict[str, torch.Tensor]:
        """Every tensor needed to resume: networks, targets, and both optimisers' moments (on the CPU)."""
        out: dict[str, torch.Tensor] = {}
        for name, module in (("actor", self.actor), ("critic", self.critic), ("actor_targ", self.actor_targ),
                             ("critic_targ", self.critic_targ)):
            for k, v in module.state_dict().items():
                out[f"{name}.{k}"] = v.detach().cpu().clone().contiguous()
        for name, opt in (("actor_opt", self.actor_opt), ("critic_opt", self.critic_opt)):
            for pid, st in opt.state_dict()["state"].items():
                for k, v in st.items():
                    out[f"{name}.{pid}.{k}"] = torch.as_tensor(v).detach().cpu().clone().contiguous()
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
            params = [p for group in opt.param_groups for p in group["params"]]
            if any(pid >= len(params) or st["exp_avg"].shape != params[pid].shape for pid, st in state.items()):
                # a checkpoint of the older two-module critic: its weights were converted, its moments cannot be
                print(f"{name}: the checkpoint's optimiser moments do not fit this network layout; starting them afresh")
                continue
            sd["state"] = state
            opt.load_state_dict(sd)

"""Actor and critic networks: the paper's flat MLPs (three layers of 256 ReLU units) and an object-set
variant, both with the twin critic heads computed in one batched pass.

Twin critics as one module
--------------------------
``StackedMLP`` holds H independent MLPs as stacked weights (H, in, out); every layer is one
``baddbmm`` over the H heads (a shared input enters as a stride-0 view, so every activation is
contiguous: ReLU and its backward on a transposed tensor were measurably slower on CPU). TD3's two Q networks therefore cost the kernel launches of one, and the per-head
maths is exactly that of H separate ``nn.Linear`` stacks (same initialisation, same outputs).

Object-set networks (``network="set"``)
---------------------------------------
The observation layout is the env's (``env/observation.py``): the robot part (ROBOT_DIM = 18: ee,
bottom and top box positions and velocities) then any number of slots of SLOT_DIM = 9 (object
position, velocity, constraint one-hot), or 10 with ``object_size`` (the footprint radius last). A set
network reads each slot with one shared encoder over (position, velocity, one-hot[, radius], position
relative to the held box) and pools the encodings with a
masked mean and a masked max, which do not depend on slot order. A slot whose one-hot is all zero is
*absent* (a real object always has exactly one constraint type), so a k-object observation padded with
zero slots to any width gives the same output as the unpadded one, and one network serves any k.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from safemanip.env.observation import ROBOT_DIM, slot_dim
from safemanip.rl.numpy_actor import REL_DIM  # a slot's encoder also reads the position relative to the held box

NETWORKS = ("mlp", "set")
BOTTOM_POS = slice(6, 9)  # the held box's position inside the robot part


def mlp(sizes: list[int]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


class StackedMLP(nn.Module):
    """``heads`` independent ReLU MLPs with layer sizes ``sizes``, evaluated together.

    Input (B, in) is shared by every head; input (H, B, in) gives each head its own. Output (H, B, out).
    Each layer's weight is (H, in, out) and bias (H, 1, out), initialised as ``nn.Linear`` does
    (uniform in +-1/sqrt(fan_in)).
    """

    def __init__(self, heads: int, sizes: list[int], relu_last: bool = False):
        super().__init__()
        self.heads, self.sizes, self.relu_last = heads, list(sizes), relu_last
        self.weights = nn.ParameterList()
        self.biases = nn.ParameterList()
        for fan_in, fan_out in zip(sizes[:-1], sizes[1:]):
            bound = 1.0 / math.sqrt(fan_in)
            self.weights.append(nn.Parameter(torch.empty(heads, fan_in, fan_out).uniform_(-bound, bound)))
            self.biases.append(nn.Parameter(torch.empty(heads, 1, fan_out).uniform_(-bound, bound)))

    def forward(self, x: torch.Tensor, head: int | None = None) -> torch.Tensor:
        """All heads, or only ``head`` (then the output is (1, B, out): e.g. Q1 for the actor loss)."""
        ws, bs = list(self.weights), list(self.biases)
        if head is not None:
            ws, bs = [w[head:head + 1] for w in ws], [b[head:head + 1] for b in bs]
        if x.dim() == 2:  # shared input: a stride-0 view, no copy
            x = x.expand(ws[0].shape[0], *x.shape)
        for i, (w, b) in enumerate(zip(ws, bs)):
            if i > 0:
                x = torch.relu(x)
            x = torch.baddbmm(b, x, w)  # (H, B, in) @ (H, in, out) + (H, 1, out): every head in one call
        return torch.relu(x) if self.relu_last else x


def squash(pre_tanh: torch.Tensor) -> torch.Tensor:
    """The action: tanh of the pre-activation, always in fp32. Under bf16 autocast tanh would run in bf16, which
    rounds tanh(x) to exactly 1 for |x| > 3.5 and so makes its gradient exactly 0: a saturated actor then never
    recovers. In fp32 the gradient there is small but not zero, and Adam's normalised steps bring it back."""
    return torch.tanh(pre_tanh.float())


# ------------------------------------------------------------------------------------------ flat (paper)
class Actor(nn.Module):
    def __init__(self, obs_dim: int, act_dim: int, hidden: tuple[int, ...]):
        super().__init__()
        self.net = mlp([obs_dim, *hidden, act_dim])

    def pre_tanh(self, obs: torch.Tensor) -> torch.Tensor:
        """The action before its tanh squashing (what ``TrainConfig.actor_preactivation_penalty`` keeps small)."""
        return self.net(obs)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return squash(self.pre_tanh(obs))


class Critic(nn.Module):
    """``n_heads`` Q heads over (s, a) in one ``StackedMLP``: forward gives (n_heads, B)."""

    def __init__(self, obs_dim: int, act_dim: int, hidden: tuple[int, ...], n_heads: int = 2):
        super().__init__()
        self.q = StackedMLP(n_heads, [obs_dim + act_dim, *hidden, 1])
        self._register_load_state_dict_pre_hook(_stack_old_heads)

    def forward(self, obs: torch.Tensor, act: torch.Tensor, head: int | None = None) -> torch.Tensor:
        return self.q(torch.cat([obs, act], dim=-1), head).squeeze(-1)


# ------------------------------------------------------------------------------------------ object set
def split_slots(obs: torch.Tensor, width: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(robot (B, 18), slot features (B, S, width + 3), present mask (B, S)) of a batch of observations
    whose slots are ``width`` wide."""
    robot = obs[:, :ROBOT_DIM]
    slots = obs[:, ROBOT_DIM:].reshape(obs.shape[0], -1, width)
    rel = slots[..., 0:3] - robot[:, None, BOTTOM_POS]
    return robot, torch.cat([slots, rel], dim=-1), slots[..., 6:9].sum(-1) > 0.5


class SetNet(nn.Module):
    """H heads of: a shared per-slot encoder, masked mean+max pooling, then an MLP over
    (robot state, pooled encoding, extra input such as the action). Output (H, B, out_dim)."""

    def __init__(self, heads: int, extra_dim: int, out_dim: int, hidden: tuple[int, ...], embed: int,
                 object_size: bool = False):
        super().__init__()
        self.embed, self.slot_width = embed, slot_dim(object_size)
        self.encoder = StackedMLP(heads, [self.slot_width + REL_DIM, embed, embed], relu_last=True)
        self.head = StackedMLP(heads, [ROBOT_DIM + 2 * embed + extra_dim, *hidden, out_dim])

    def forward(self, obs: torch.Tensor, extra: torch.Tensor | None = None, head: int | None = None) -> torch.Tensor:
        robot, feats, mask = split_slots(obs, self.slot_width)
        batch, n_slots = mask.shape
        heads = self.head.heads if head is None else 1
        if n_slots:
            enc = self.encoder(feats.reshape(batch * n_slots, feats.shape[-1]), head).reshape(heads, batch, n_slots, -1)
            present = mask[None, :, :, None]
            enc = enc.masked_fill(~present, 0.0)  # encodings are >= 0 (ReLU), so 0 never wins the max
            count = present.sum(2).clamp(min=1).to(enc.dtype)
            pooled = torch.cat([enc.sum(2) / count, enc.amax(2)], dim=-1)
        else:
            pooled = robot.new_zeros(heads, batch, 2 * self.embed)
        parts = [robot.expand(heads, batch, ROBOT_DIM).to(pooled.dtype), pooled]
        if extra is not None:
            parts.append(extra.expand(heads, *extra.shape).to(pooled.dtype))
        return self.head(torch.cat(parts, dim=-1), head)


class SetActor(nn.Module):
    def __init__(self, act_dim: int, hidden: tuple[int, ...], embed: int, object_size: bool = False):
        super().__init__()
        self.net = SetNet(1, 0, act_dim, hidden, embed, object_size)

    def pre_tanh(self, obs: torch.Tensor) -> torch.Tensor:
        """The action before its tanh squashing."""
        return self.net(obs)[0]

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return squash(self.pre_tanh(obs))


class SetCritic(nn.Module):
    def __init__(self, act_dim: int, hidden: tuple[int, ...], embed: int, n_heads: int = 2,
                 object_size: bool = False):
        super().__init__()
        self.q = SetNet(n_heads, act_dim, 1, hidden, embed, object_size)

    def forward(self, obs: torch.Tensor, act: torch.Tensor, head: int | None = None) -> torch.Tensor:
        return self.q(obs, act, head).squeeze(-1)


def make_networks(network: str, obs_dim: int, act_dim: int, hidden: tuple[int, ...], n_heads: int,
                  set_embed: int = 128, object_size: bool = False) -> tuple[nn.Module, nn.Module]:
    """(actor, critic) of the named kind; a set network accepts any number of slots (``obs_dim`` unused) of
    the width ``object_size`` gives (a flat MLP's slots are inside ``obs_dim``)."""
    if network == "mlp":
        return Actor(obs_dim, act_dim, hidden), Critic(obs_dim, act_dim, hidden, n_heads)
    if network == "set":
        return (SetActor(act_dim, hidden, set_embed, object_size),
                SetCritic(act_dim, hidden, set_embed, n_heads, object_size))
    raise ValueError(f"network must be one of {NETWORKS}, got {network!r}")


def _stack_old_heads(state: dict, prefix: str, *args) -> None:
    """Load-state hook: a state dict of the older critic (one ``nn.Sequential`` per head,
    ``heads.{h}.{2i}.weight``) is rewritten in place into the stacked layout (``q.weights.{i}``,
    (H, in, out)), so checkpoints and toy models written before the fused critic still load."""
    keys = [k for k in state if k.startswith(prefix + "heads.")]
    if not keys:
        return
    heads = sorted({int(k[len(prefix):].split(".")[1]) for k in keys})
    layers = sorted({int(k[len(prefix):].split(".")[2]) for k in keys})
    for i, layer in enumerate(layers):
        state[f"{prefix}q.weights.{i}"] = torch.stack([state[f"{prefix}heads.{h}.{layer}.weight"].T for h in heads])
        state[f"{prefix}q.biases.{i}"] = torch.stack([state[f"{prefix}heads.{h}.{layer}.bias"][None] for h in heads])
    for k in keys:
        del state[k]


def actor_arrays(actor: nn.Module) -> list[np.ndarray] | dict[str, np.ndarray]:
    """The actor's parameters as float32 NumPy arrays for ``NumpyActor`` / a policy file: for the flat MLP
    a list of weights and biases layer by layer (W as out x in); for a set actor a dict by parameter name."""
    if isinstance(actor, SetActor):
        return {k: v.detach().cpu().float().numpy().copy() for k, v in actor.state_dict().items()}
    return [p.detach().cpu().float().numpy().copy() for p in actor.net.parameters()]


from safemanip.rl.numpy_actor import NumpyActor  # noqa: E402,F401  (re-exported for callers that have torch anyway)

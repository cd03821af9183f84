"""Learner updates per second next to a bare PyTorch loop doing the same matrix work, in one run.

    python benchmarks/learner_throughput.py [--updates 400] [--repeats 5] [--obs-dim 36]

The bare loop has the same shapes (3 x 256 MLPs, batch 200, twin critics, actor every 2nd update),
the same optimiser (AdamW) and the same maths, written inline with no buffer, no config and no
metrics: the ceiling for this network on this core. Both run with one torch thread, interleaved,
medians over repeats. Run it on an idle machine (no training or other benchmark at the same time).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import torch
from torch import nn

from safemanip.rl.buffer import ReplayBuffer
from safemanip.rl.config import TrainConfig
from safemanip.rl.learner import Learner


def filled_buffer(obs_dim: int, n: int = 20_000) -> ReplayBuffer:
    rng = np.random.default_rng(0)
    buf = ReplayBuffer(n, obs_dim, 3)
    buf.add_many({"obs": rng.normal(size=(n, obs_dim)).astype(np.float32), "act": rng.uniform(-1, 1, (n, 3)).astype(np.float32),
                  "next_obs": rng.normal(size=(n, obs_dim)).astype(np.float32),
                  **{k: rng.normal(size=n).astype(np.float32) for k in ("l", "g", "next_l", "next_g")},
                  "terminated": rng.random(n) < 0.02})
    return buf


def learner_rate(obs_dim: int, updates: int, buf: ReplayBuffer) -> float:
    learner = Learner(obs_dim, 3, TrainConfig())
    rng = np.random.default_rng(1)
    for _ in range(20):
        learner.update(buf.sample(200, rng), 0.99)
    t0 = time.perf_counter()
    for _ in range(updates):
        learner.update(buf.sample(200, rng), 0.99)
    return updates / (time.perf_counter() - t0)


def bare_rate(obs_dim: int, updates: int) -> float:
    def net(i, o):
        return nn.Sequential(nn.Linear(i, 256), nn.ReLU(), nn.Linear(256, 256), nn.ReLU(), nn.Linear(256, 256), nn.ReLU(),
                             nn.Linear(256, o))
    actor, actor_t = net(obs_dim, 3), net(obs_dim, 3)
    q1, q2, q1_t, q2_t = (net(obs_dim + 3, 1) for _ in range(4))
    opt_a = torch.optim.AdamW(actor.parameters(), lr=1e-3)
    opt_c = torch.optim.AdamW(list(q1.parameters()) + list(q2.parameters()), lr=1e-3)
    o, a, o2 = torch.randn(200, obs_dim), torch.rand(200, 3) * 2 - 1, torch.randn(200, obs_dim)
    l, g, l2, g2 = (torch.randn(200) for _ in range(4))
    done = torch.rand(200) < 0.02

    def one(i):
        with torch.no_grad():
            a2 = (torch.tanh(actor_t(o2)) + (torch.randn(200, 3) * 0.2).clamp(-0.5, 0.5)).clamp(-1, 1)
            x2 = torch.cat([o2, a2], -1)
            v = torch.minimum(q1_t(x2), q2_t(x2)).squeeze(-1)
            v = torch.where(done, torch.minimum(l2, g2), v)
            y = 0.01 * torch.minimum(l, g) + 0.99 * torch.minimum(g, torch.maximum(l, v))
        x = torch.cat([o, a], -1)
        loss = ((q1(x).squeeze(-1) - y) ** 2).mean() + ((q2(x).squeeze(-1) - y) ** 2).mean()
        opt_c.zero_grad()
        loss.backward()
        opt_c.step()
        if i % 2 == 0:
            loss_a = -q1(torch.cat([o, torch.tanh(actor(o))], -1)).mean()
            opt_a.zero_grad()
            loss_a.backward()
            opt_a.step()
            with torch.no_grad():
                for p, pt in zip(list(actor.parameters()) + list(q1.parameters()) + list(q2.parameters()),
                                 list(actor_t.parameters()) + list(q1_t.parameters()) + list(q2_t.parameters())):
                    pt.mul_(0.995).add_(p, alpha=0.005)

    for i in range(20):
        one(i)
    t0 = time.perf_counter()
    for i in range(updates):
        one(i)
    return updates / (time.perf_counter() - t0)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--updates", type=int, default=400)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--obs-dim", type=int, default=36, help="36 = the k=2 slide-out observation")
    args = p.parse_args()
    torch.set_num_threads(1)
    buf = filled_buffer(args.obs_dim)
    ours, bare = [], []
    for _ in range(args.repeats):
        ours.append(learner_rate(args.obs_dim, args.updates, buf))
        bare.append(bare_rate(args.obs_dim, args.updates))
    o, b = statistics.median(ours), statistics.median(bare)
    print(f"{'loop':<28} {'updates/s (median)':>18} {'ms/update':>10}")
    print(f"{'safemanip Learner.update':<28} {o:>18.1f} {1000 / o:>10.2f}")
    print(f"{'bare PyTorch, same maths':<28} {b:>18.1f} {1000 / b:>10.2f}")
    print(f"ratio learner / bare: {o / b:.2f}  (batch 200, 3x256, twin critics, policy delay 2, 1 thread)")


if __name__ == "__main__":
    main()

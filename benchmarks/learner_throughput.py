"""Learner updates per second: ours (fp32, bf16) against a bare PyTorch loop and SB3's TD3, in one run.

    python benchmarks/learner_throughput.py [--seconds 3] [--repeats 5] [--batches 200 1024] [--obs-dim 36]

Rows, measured interleaved (every repeat runs each row once, in turn) with one torch thread, medians
over the repeats, each measurement a fixed wall-clock slice after a warm-up:

  bare fp32      the same maths written inline: 3 x 256 ReLU MLPs, two separate critic MLPs, AdamW
                 (PyTorch's default implementation), target smoothing, policy delay 2, Polyak by
                 a Python loop over the parameters; no buffer sampling, no config, no metrics. The
                 reference every ratio is taken against.
  ours fp32      ``Learner.update`` (replay sampling included) with ``precision="fp32"``.
  ours bf16      the same with ``precision="bf16"`` (autocast forward passes, fp32 master weights,
                 losses and targets). Only fast where bf16 is native (AVX512-BF16 / AMX / CUDA); the
                 start-up check in ``rl/precision.py`` says which this machine is.
  ours fp32, set network   (``--with-set``) the object-set actor/critic on the same observations
                 (random one-hots, so some slots count as absent: a cost figure, not a learning one);
                 with bf16 also a bf16 row of it.
  SB3 TD3        ``stable_baselines3.TD3.train()`` on identical networks (net_arch 3 x 256, AdamW,
                 twin critics, policy delay 2, batch as given) with its replay buffer pre-filled;
                 skipped with a note when stable-baselines3 is not installed (``pip install -e .[bench]``).

The machine may be shared: run it when nothing else is, and compare rows of one run, not across runs.
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
from safemanip.rl.precision import cpu_bf16_flags

ACT_DIM = 3
HIDDEN = (256, 256, 256)


def filled_buffer(obs_dim: int, n: int = 20_000) -> ReplayBuffer:
    rng = np.random.default_rng(0)
    buf = ReplayBuffer(n, obs_dim, ACT_DIM)
    buf.add_many({"obs": rng.normal(size=(n, obs_dim)).astype(np.float32),
                  "act": rng.uniform(-1, 1, (n, ACT_DIM)).astype(np.float32),
                  "next_obs": rng.normal(size=(n, obs_dim)).astype(np.float32),
                  **{k: rng.normal(size=n).astype(np.float32) for k in ("l", "g", "next_l", "next_g")},
                  "terminated": rng.random(n) < 0.02})
    return buf


def timed(step, seconds: float, warmup: int = 10) -> float:
    """Updates per second of ``step(i)`` over a wall-clock slice (at least 5 updates), after a warm-up of
    ``warmup`` updates or one second, whichever ends first (at least 2)."""
    t0 = time.perf_counter()
    for i in range(warmup):
        step(i)
        if i >= 1 and time.perf_counter() - t0 > 1.0:
            break
    n, t0 = 0, time.perf_counter()
    while n < 5 or time.perf_counter() - t0 < seconds:
        step(n)
        n += 1
    return n / (time.perf_counter() - t0)


# ------------------------------------------------------------------------------------------ the rows
def ours(obs_dim: int, batch: int, precision: str, buf: ReplayBuffer, network: str = "mlp"):
    learner = Learner(obs_dim, ACT_DIM, TrainConfig(batch_size=batch, precision=precision, device="cpu", network=network))
    rng = np.random.default_rng(1)
    return lambda i: learner.update(buf.sample(batch, rng), 0.99), learner.precision


def bare(obs_dim: int, batch: int):
    def net(i, o):
        return nn.Sequential(nn.Linear(i, 256), nn.ReLU(), nn.Linear(256, 256), nn.ReLU(), nn.Linear(256, 256), nn.ReLU(),
                             nn.Linear(256, o))
    actor, actor_t = net(obs_dim, ACT_DIM), net(obs_dim, ACT_DIM)
    q1, q2, q1_t, q2_t = (net(obs_dim + ACT_DIM, 1) for _ in range(4))
    opt_a = torch.optim.AdamW(actor.parameters(), lr=1e-3)
    opt_c = torch.optim.AdamW(list(q1.parameters()) + list(q2.parameters()), lr=1e-3)
    o, a, o2 = torch.randn(batch, obs_dim), torch.rand(batch, ACT_DIM) * 2 - 1, torch.randn(batch, obs_dim)
    l, g, l2, g2 = (torch.randn(batch) for _ in range(4))
    done = torch.rand(batch) < 0.02
    online = list(actor.parameters()) + list(q1.parameters()) + list(q2.parameters())
    target = list(actor_t.parameters()) + list(q1_t.parameters()) + list(q2_t.parameters())

    def one(i):
        with torch.no_grad():
            a2 = (torch.tanh(actor_t(o2)) + (torch.randn(batch, ACT_DIM) * 0.2).clamp(-0.5, 0.5)).clamp(-1, 1)
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
                for p, pt in zip(online, target):
                    pt.mul_(0.995).add_(p, alpha=0.005)
    return one


def sb3(obs_dim: int, batch: int):
    """SB3 TD3's own train() on identical networks, or None if stable-baselines3 is missing."""
    try:
        import gymnasium as gym
        from stable_baselines3 import TD3
        from stable_baselines3.common.logger import configure
    except ImportError:
        return None

    class Dummy(gym.Env):
        observation_space = gym.spaces.Box(-10, 10, (obs_dim,), np.float32)
        action_space = gym.spaces.Box(-1, 1, (ACT_DIM,), np.float32)

    n = 20_000
    model = TD3("MlpPolicy", Dummy(), learning_rate=1e-3, buffer_size=n, batch_size=batch, tau=0.005, gamma=0.99,
                policy_delay=2, target_policy_noise=0.2, target_noise_clip=0.5, device="cpu", seed=0,
                policy_kwargs={"net_arch": list(HIDDEN), "optimizer_class": torch.optim.AdamW})
    model.set_logger(configure(None, []))
    rb, rng = model.replay_buffer, np.random.default_rng(0)
    rb.observations[:] = rng.normal(size=rb.observations.shape)
    rb.next_observations[:] = rng.normal(size=rb.next_observations.shape)
    rb.actions[:] = rng.uniform(-1, 1, rb.actions.shape)
    rb.rewards[:] = rng.normal(size=rb.rewards.shape)
    rb.dones[:] = rng.random(rb.dones.shape) < 0.02
    rb.full, rb.pos = True, 0
    return lambda i: model.train(gradient_steps=1, batch_size=batch)


# ------------------------------------------------------------------------------------------ main
def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=3.0, help="wall-clock slice per measurement")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--batches", type=int, nargs="+", default=[200, 1024])
    p.add_argument("--obs-dim", type=int, default=36, help="36 = the k=2 slide-out observation")
    p.add_argument("--no-bf16", action="store_true", help="skip the bf16 row (slow where bf16 is emulated)")
    p.add_argument("--with-set", action="store_true", help="add rows for the object-set network (fp32, bf16)")
    args = p.parse_args()
    torch.set_num_threads(1)
    flags = cpu_bf16_flags()
    print(f"torch {torch.__version__}, 1 thread; CPU bf16 features: {', '.join(sorted(flags)) or 'none (bf16 is emulated)'}")
    buf = filled_buffer(args.obs_dim)
    for batch in args.batches:
        rows: dict[str, object] = {"bare fp32 (reference)": bare(args.obs_dim, batch)}
        rows["ours fp32 (Learner.update)"], _ = ours(args.obs_dim, batch, "fp32", buf)
        if not args.no_bf16:
            rows["ours bf16 (Learner.update)"], prec = ours(args.obs_dim, batch, "bf16", buf)
        if args.with_set:
            rows["ours fp32, set network"], _ = ours(args.obs_dim, batch, "fp32", buf, "set")
            if not args.no_bf16:
                rows["ours bf16, set network"], _ = ours(args.obs_dim, batch, "bf16", buf, "set")
        step = sb3(args.obs_dim, batch)
        if step is not None:
            rows["SB3 TD3 train()"] = step
        rates: dict[str, list[float]] = {name: [] for name in rows}
        for _ in range(args.repeats):
            for name, fn in rows.items():
                rates[name].append(timed(fn, args.seconds))
        ref = statistics.median(rates["bare fp32 (reference)"])
        print(f"\nbatch {batch}  (3x256, twin critics, policy delay 2; median of {args.repeats} interleaved "
              f"{args.seconds:g} s slices)")
        print(f"{'loop':<28} {'updates/s':>10} {'ms/update':>10} {'samples/s':>10} {'vs bare':>8}  spread")
        for name, values in rates.items():
            med = statistics.median(values)
            print(f"{name:<28} {med:>10.1f} {1000 / med:>10.2f} {med * batch:>10.0f} {med / ref:>7.2f}x  "
                  f"{min(values):.1f}-{max(values):.1f}")
        if "SB3 TD3 train()" in rates:
            theirs = statistics.median(rates["SB3 TD3 train()"])
            for ours_row in ("ours fp32 (Learner.update)", "ours bf16 (Learner.update)"):
                if ours_row in rates:
                    print(f"{ours_row.split(' (')[0]} / SB3 TD3: {statistics.median(rates[ours_row]) / theirs:.2f}x")
        else:
            print("SB3 TD3: skipped (stable-baselines3 not installed; pip install -e .[bench])")
    if not args.no_bf16:
        print(f"\nbf16 row: {prec.reason}")


if __name__ == "__main__":
    main()

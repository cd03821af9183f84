"""The training loop's update rate against its learner's standalone rate, in one run (issue 42).

    python benchmarks/training_loop.py [--config results/training/rarl-k2-conservative-s0/config.json]
        [--steps 400000] [--learner-seconds 20] [--precision auto|bf16|fp32] [--out RUN_FOLDER] [--learner-only]

Rows:

  learner alone      ``Learner.update`` with the config's batch, networks, precision, device and torch threads,
                     sampling included, from a full replay buffer of the config's size (random transitions of the
                     env's observation size): the rate the loop can reach at most. Measured in 5 s slices before the
                     run and again after it; the median of all slices is the reference of the ratios.
  learner beside     the same, while another process steps the config's env with random actions on the other core:
  an env             the learner's rate when a rollout worker keeps its core busy (the two share caches and memory
                     bandwidth), so the most a loop with one worker on a 2-core machine can reach. ``--learner-only``
                     prints the learner rows alone (no run).
  loop, mean         the run's updates per second over its training phase: from the first row of its scalars.csv
                     with an update to its last row (so neither the warm-up before ``learning_starts``, in which the
                     data rate allows no update, nor the final evaluation and checkpoint).
  loop, worst 30 s   the slowest window of at least 30 s between two rows of the run's scalars.csv (the loop logs its
                     counters every ``log_every_s``, 10 s in the benchmark's recipe).
  loop, whole run    updates over the run's whole wall time, start-up and warm-up included (for comparison).

Where the loop's time goes (Linux for the first table):

  CPU time           per process of the run, sampled from /proc once a second: the learner's process (and the part
                     of it outside its main thread), the rollout worker(s), the evaluation process; CPU seconds and
                     cores used over the run's wall time (start-up and the final evaluation included).
  loop's timing      means over training of the loop's own scalars (``rl/train.py``'s ``log``): the share of time the
                     learner waited for data and the worker(s) waited for the learner (ahead of the data rate), and
                     the workers' CPU ms per env step, with the update rate it allows at most when each worker has a
                     whole core (``benchmarks/rollout_profile.py`` splits that cost: physics, env Python, resets,
                     the collector's own work). A loop short of the bar whose learner waits for data while its
                     worker(s) stay below one core is starved of CPU (the evaluation process, a busy machine); with
                     its worker(s) at one core it is bound by the env's cost per step.

The run is a real ``safemanip train`` with the config's rollout workers, evaluations and checkpoints, in a process of
its own (the learner measurements are made in this one, not while it runs); ``--steps`` sets its budget, so a short
smoke run is possible (the worst window needs 30 s of training). The table names the CPU (its model name) and
whether bf16 is native on it (``rl/precision.py``): the rates belong to that kind of machine. Run it when nothing
else runs: issue 42 asks for a mean of at least 0.9x and no window below 0.7x of the learner alone over a whole
400k-step run of the recipe on an idle 2-core machine.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from safemanip.rl.buffer import ReplayBuffer
from safemanip.rl.config import load_run_config
from safemanip.rl.envs import env_builder
from safemanip.rl.learner import Learner
from safemanip.rl.precision import cpu_bf16_flags, cpu_model

RECIPE = Path(__file__).resolve().parents[1] / "results" / "training" / "rarl-k2-conservative-s0" / "config.json"
WINDOW_S = 30.0
SLICE_S = 5.0


def learner_alone(cfg, seconds: float) -> tuple[list[float], str]:
    """Updates per second of ``Learner.update`` plus sampling, in ``SLICE_S`` slices over about ``seconds``; and the
    learner's precision with its reason."""
    torch.set_num_threads(cfg.torch_threads)
    factory = None
    if cfg.selection_aware:  # as safemanip train passes it
        from safemanip.selection.training_env import SelectedSlotsEnv

        factory = SelectedSlotsEnv
    env = env_builder(cfg.rollout_env_kwargs, factory)()
    obs_dim, act_dim = env.observation_space.shape[0], env.action_space.shape[0]
    env.close()
    rng = np.random.default_rng(0)
    n = cfg.buffer_size
    buf = ReplayBuffer(n, obs_dim, act_dim)
    buf.add_many({"obs": rng.normal(size=(n, obs_dim)).astype(np.float32),
                  "act": rng.uniform(-1, 1, (n, act_dim)).astype(np.float32),
                  "next_obs": rng.normal(size=(n, obs_dim)).astype(np.float32),
                  **{k: rng.normal(0, 0.3, size=n).astype(np.float32) for k in ("l", "g", "next_l", "next_g")},
                  "terminated": rng.random(n) < 0.02})
    learner = Learner(obs_dim, act_dim, cfg)
    for _ in range(10):  # warm-up: first calls allocate
        learner.update(buf.sample(cfg.batch_size, rng), cfg.gamma)
    rates = []
    for _ in range(max(1, round(seconds / SLICE_S))):
        done, t0 = 0, time.perf_counter()
        while done < 5 or time.perf_counter() - t0 < min(SLICE_S, seconds):
            learner.update(buf.sample(cfg.batch_size, rng), cfg.gamma)
            done += 1
        rates.append(done / (time.perf_counter() - t0))
    return rates, f"{learner.precision.dtype} ({learner.precision.reason})"


ENV_STEPPER = """
import json, sys
import numpy as np
from safemanip.rl.envs import env_builder
from safemanip.util.procs import die_with_parent
die_with_parent(int(sys.argv[2]))
env, rng = env_builder(json.loads(sys.argv[1]))(), np.random.default_rng(0)
env.reset(seed=0)
print("stepping", flush=True)
while True:
    _, _, terminated, truncated, _ = env.step(rng.uniform(-1, 1, 3).astype(np.float32))
    if terminated or truncated:
        env.reset()
"""


def learner_beside_an_env(cfg, seconds: float) -> list[float]:
    """``learner_alone`` while another process steps the config's env with random actions on the other core: what
    the learner can reach at most in a loop whose rollout worker keeps its core busy (the two share caches and memory
    bandwidth)."""
    stepper = subprocess.Popen([sys.executable, "-c", ENV_STEPPER, json.dumps(cfg.rollout_env_kwargs), str(os.getpid())],
                               stdout=subprocess.PIPE, text=True)
    try:
        if stepper.stdout.readline().strip() != "stepping":  # it has built its env and steps from here on
            sys.exit("the env-stepping process failed to start")
        rates, _ = learner_alone(cfg, seconds)
    finally:
        stepper.kill()
        stepper.wait()
    return rates


def log_points(run: Path) -> list[tuple[float, int]]:
    """(wall_s, updates) at each of the loop's log rows (one ``perf/updates_per_s`` row per log)."""
    with open(run / "scalars.csv", newline="") as f:
        return [(float(r["wall_s"]), int(r["updates"])) for r in csv.DictReader(f) if r["name"] == "perf/updates_per_s"]


def waiting(run: Path) -> dict:
    """The training phase's means of the loop's own timing scalars (``rl/train.py``'s ``log``): the share of time the
    learner waited for data and the rollout workers for the learner, and the workers' CPU ms per env step (weighted
    by the steps of each interval). Missing (an older run, or a backend that does not measure them): None."""
    rows: dict[str, list[tuple[int, int, float]]] = {}
    with open(run / "scalars.csv", newline="") as f:
        for r in csv.DictReader(f):
            if r["name"] in ("perf/learner_waiting", "perf/rollout_waiting", "perf/rollout_cpu_ms_per_step"):
                rows.setdefault(r["name"], []).append((int(r["env_steps"]), int(r["updates"]), float(r["value"])))
    out: dict = {}
    for name, values in rows.items():
        training = [(prev[0], v) for prev, v in zip(values, values[1:]) if v[1] > 0]  # (steps before, row)
        if not training:
            continue
        if name == "perf/rollout_cpu_ms_per_step":
            weights = [v[0] - before for before, v in training]
            out[name] = sum(w * v[2] for w, (_, v) in zip(weights, training)) / max(1, sum(weights))
        else:
            out[name] = statistics.mean(v[2] for _, v in training)
    return out


def loop_rates(points: list[tuple[float, int]]) -> dict:
    """The training phase's mean rate and its slowest window of at least ``WINDOW_S`` seconds."""
    training = [p for p in points if p[1] > 0]
    out: dict = {"mean": None, "worst": None, "worst_at": None, "span_s": 0.0, "updates": 0}
    if len(training) < 2:
        return out
    (t0, u0), (t1, u1) = training[0], training[-1]
    out.update(mean=(u1 - u0) / (t1 - t0), span_s=t1 - t0, updates=u1 - u0)
    for i, (ta, ua) in enumerate(training):
        later = next(((tb, ub) for tb, ub in training[i + 1:] if tb - ta >= WINDOW_S), None)
        if later is None:
            break
        rate = (later[1] - ua) / (later[0] - ta)
        if out["worst"] is None or rate < out["worst"]:
            out.update(worst=rate, worst_at=ta)
    return out


class CpuSampler:
    """CPU seconds of a process and its descendants, by role, from /proc (Linux; elsewhere nothing is reported).

    Each process's last reading is kept, so a process that has ended still counts with what it used."""

    def __init__(self, root: int):
        self.root = root
        self.tick = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
        self.seen: dict[int, tuple[str, float]] = {}  # pid -> (role, CPU s)
        self.learner_main = 0.0  # the learner's main thread

    def _stat(self, path: str) -> tuple[str, float] | None:
        try:
            text = Path(path).read_text()
        except OSError:
            return None
        comm, rest = text[text.index("(") + 1:text.rindex(")")], text[text.rindex(")") + 2:].split()
        return comm, (int(rest[11]) + int(rest[12])) / self.tick  # utime + stime

    def _children(self, pid: int) -> list[int]:
        out = []
        for task in Path(f"/proc/{pid}/task").glob("*"):
            try:
                out += [int(c) for c in (task / "children").read_text().split()]
            except (OSError, ValueError):
                pass
        return out

    def _role(self, pid: int, comm: str) -> str:
        if pid == self.root:
            return "learner process"
        if comm == "safemanip-eval":
            return "evaluation process"
        try:
            cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            cmdline = ""
        if "resource_tracker" in cmdline or "forkserver" in cmdline:
            return "multiprocessing helpers"
        return "rollout worker(s)" if "multiprocessing" in cmdline else "other"

    def sample(self) -> None:
        todo, done = [self.root], set()
        while todo:
            pid = todo.pop()
            if pid in done:
                continue
            done.add(pid)
            stat = self._stat(f"/proc/{pid}/stat")
            if stat is None:
                continue
            # asked again each time: the evaluation process names itself only once it has started
            role = "learner process" if pid == self.root else self._role(pid, stat[0])
            self.seen[pid] = (role, stat[1])
            if pid == self.root:
                main = self._stat(f"/proc/{pid}/task/{pid}/stat")
                if main is not None:
                    self.learner_main = main[1]
            todo += self._children(pid)

    def report(self, wall: float, env_steps: int) -> None:
        if not self.seen:
            return
        by_role: dict[str, list[float]] = {}
        for role, seconds in self.seen.values():
            by_role.setdefault(role, []).append(seconds)
        print(f"\nCPU time over the whole run ({wall:.0f} s wall; start-up, warm-up and final evaluation included):")
        print("| process | CPU s | cores used |")
        print("|---|---|---|")
        for role in ("learner process", "rollout worker(s)", "evaluation process", "multiprocessing helpers", "other"):
            if role in by_role:
                total = sum(by_role[role])
                print(f"| {role} ({len(by_role[role])}) | {total:.0f} | {total / wall:.2f} |")
                if role == "learner process":
                    print(f"| learner process, outside its main thread | {total - self.learner_main:.0f} | "
                          f"{(total - self.learner_main) / wall:.2f} |")
        workers = sum(by_role.get("rollout worker(s)", []))
        if workers > 0:
            print(f"rollout workers: {env_steps / workers:.0f} env steps per CPU-second (their start-up included)")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--config", type=Path, default=RECIPE, help="a run's config.json (default: the benchmark recipe's "
                   "rarl-k2-conservative-s0)")
    p.add_argument("--steps", type=int, default=None, help="the run's env-step budget (default: the config's)")
    p.add_argument("--learner-seconds", type=float, default=20.0, help="learner alone: seconds before and after the run")
    p.add_argument("--precision", choices=("auto", "bf16", "fp32"), help="override the config's (bf16 is emulated, "
                   "ten times slower, on a CPU without native bf16)")
    p.add_argument("--out", type=Path, help="the run's folder (default: a new temporary folder; kept)")
    p.add_argument("--learner-only", action="store_true", help="only the learner rows (alone, and beside an env "
                   "stepping on the other core), no run")
    args = p.parse_args()
    cfg, _ = load_run_config(args.config)
    if args.steps is not None:
        cfg.total_env_steps = args.steps
    if args.precision is not None:
        cfg.precision = args.precision
    run = args.out or Path(tempfile.mkdtemp(prefix="training-loop-"))
    flags = cpu_bf16_flags()
    print(f"CPU: {cpu_model()}; bf16 native: {'yes (' + ', '.join(sorted(flags)) + ')' if flags else 'no (emulated)'}; "
          f"torch {torch.__version__}, {cfg.torch_threads} thread(s)")
    print(f"config: {args.config} (k = {cfg.k}, {cfg.network} {list(cfg.hidden)}, batch {cfg.batch_size}, "
          f"buffer {cfg.buffer_size}, precision {cfg.precision}, {cfg.n_collectors} {cfg.backend} rollout worker(s), "
          f"evaluation every {cfg.eval_every_s:g} s, checkpoint every {cfg.checkpoint_every_s:g} s); "
          f"budget {cfg.total_env_steps} env steps; run folder {run}")

    before, precision = learner_alone(cfg, args.learner_seconds)
    beside = learner_beside_an_env(cfg, args.learner_seconds)
    if args.learner_only:
        after, _ = learner_alone(cfg, args.learner_seconds)
        ref = statistics.median(before + after)
        print(f"learner: {precision}\n\n| row | updates/s | vs learner alone |\n|---|---|---|")
        for name, rates in (("learner alone, before", before), ("learner beside an env stepping on the other core",
                                                                 beside), ("learner alone, after", after)):
            print(f"| {name} ({min(rates):.1f}-{max(rates):.1f}) | {statistics.median(rates):.1f} | "
                  f"{statistics.median(rates) / ref:.2f}x |")
        return
    command = [sys.executable, "-m", "safemanip.cli", "train", "--config", str(args.config), "--out", str(run),
               "--total-env-steps", str(cfg.total_env_steps), "--precision", cfg.precision, "--no-progress"]
    t0 = time.perf_counter()
    with open(run.parent / f"{run.name}.log", "w") as log:
        proc = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT)
        cpu = CpuSampler(proc.pid)
        while proc.poll() is None:
            cpu.sample()
            try:
                proc.wait(timeout=1.0)
            except subprocess.TimeoutExpired:
                pass
        code = proc.returncode
    wall = time.perf_counter() - t0
    if code != 0:
        sys.exit(f"the run failed with exit code {code}; see {run.parent / f'{run.name}.log'}")
    after, _ = learner_alone(cfg, args.learner_seconds)

    summary = json.loads((run / "summary.json").read_text())
    loop = loop_rates(log_points(run))
    ref = statistics.median(before + after)
    print(f"learner: {precision}; run: {summary['env_steps']} env steps and {summary['updates']} updates in "
          f"{wall:.0f} s ({summary['env_steps'] / wall:.0f} env steps/s), learner {summary['learner']['dtype']}")
    print()
    print("| row | updates/s | vs learner alone |")
    print("|---|---|---|")

    def row(name: str, rate: float | None) -> None:
        print(f"| {name} | {'n/a' if rate is None else f'{rate:.1f}'} | "
              f"{'' if rate is None else f'{rate / ref:.2f}x'} |")

    row(f"learner alone, before the run (median of {len(before)} x {SLICE_S:g} s, "
        f"{min(before):.1f}-{max(before):.1f})", statistics.median(before))
    row(f"learner alone, after the run ({min(after):.1f}-{max(after):.1f})", statistics.median(after))
    row(f"learner beside an env stepping on the other core ({min(beside):.1f}-{max(beside):.1f}): the most a "
        f"2-core loop can reach", statistics.median(beside))
    row(f"loop, mean over training ({loop['updates']} updates in {loop['span_s']:.0f} s)", loop["mean"])
    worst = "loop, worst 30 s window" + (f" (from {loop['worst_at']:.0f} s)" if loop["worst"] is not None
                                          else " (training shorter than 30 s)")
    row(worst, loop["worst"])
    row("loop, whole run (start-up, warm-up, final evaluation included)", summary["updates"] / wall)
    cpu.report(wall, summary["env_steps"])
    timing = waiting(run)
    if timing:
        print("\nthe loop's own timing over training (scalars.csv, perf/*):")
        if "perf/learner_waiting" in timing:
            print(f"  learner waiting for data: {100 * timing['perf/learner_waiting']:.0f}% of the time")
        if "perf/rollout_waiting" in timing:
            print(f"  rollout worker(s) waiting for the learner (ahead of the data rate): "
                  f"{100 * timing['perf/rollout_waiting']:.0f}% of the time")
        if "perf/rollout_cpu_ms_per_step" in timing:
            ms = timing["perf/rollout_cpu_ms_per_step"]
            ceiling = cfg.n_collectors * 1000 / ms / cfg.env_steps_per_update
            print(f"  rollout worker CPU: {ms:.2f} ms per env step: with a whole core each, {cfg.n_collectors} worker(s) "
                  f"feed at most {ceiling:.0f} updates/s ({ceiling / ref:.2f}x the learner alone) at "
                  f"{cfg.env_steps_per_update:g} env steps per update")
    if loop["mean"] is not None and loop["worst"] is not None:
        met = loop["mean"] >= 0.9 * ref and loop["worst"] >= 0.7 * ref
        print(f"\nissue 42's bar (mean >= 0.9x, every 30 s window >= 0.7x the learner alone): "
              f"{'met' if met else 'not met'} in this run")


if __name__ == "__main__":
    main()

"""``safemanip bench train``: every run of the benchmark, here one after another or on a Ray cluster one task each.

Both ways run the same function per run (``run_job``) on the same plain data (``Job``), so they write the same
records into the same folders: ``RUNS/NAME/`` (config, checkpoints, logs, evaluations, policies, summary, as
``safemanip train`` writes them) and the run's output in ``RUNS/NAME.log``. The function decides when it starts
whether to train from the start or resume from the newest checkpoint (``safemanip train --resume``'s path), so a
queue stopped anywhere, or a Ray task retried after its worker died, goes on from the last checkpoint. A finished or
promoted run is skipped.

On a cluster the run folders must be on a filesystem every node mounts at the same path: a task checks that it sees
the folder the driver wrote a token into before it trains, rather than training into a folder nobody reads.
"""

from __future__ import annotations

import json
import secrets
import signal
import time
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass, replace
from pathlib import Path

from safemanip.bench.benchmark import Benchmark
from safemanip.bench.runs import RecordError, read_summary, run_records

CPUS_PER_RUN = 2
"""Ray CPUs a run asks for: the learner and its one rollout worker process (the recipe's)."""
RETRIES = 2
"""Times Ray starts a run's task again after its worker or node died; it resumes from the newest checkpoint."""
STOP_WAIT_S = 120.0
"""After a stop, how long the driver waits for the runs on the cluster to save a checkpoint and their policy."""
WAIT_POLL_S = 0.5
"""How often the driver wakes while runs train on the cluster (to answer a SIGINT/SIGTERM at once)."""
TOKEN_FILE = ".bench-driver"
"""In the runs folder: the token each task checks, so a node that does not share the folder refuses to train."""


@dataclass(frozen=True)
class Job:
    """What one run needs, as plain data (sent to a Ray task as it is)."""

    name: str
    folder: str
    """The run's folder, an absolute path (the same on every node of a cluster)."""
    config: dict
    """Its training config (as config.json holds it), for a start from scratch; a resumed run uses its own."""
    budget: int
    command: str
    """The command recorded in the run's policies."""
    token: str | None = None
    """The runs folder's token (``TOKEN_FILE``) on a cluster; None here."""


def plan(bench: Benchmark, runs_dir: Path, only: list[str] | None, policies: Path) -> tuple[list[Job], list[str]]:
    """(the runs to train or resume, in queue order; what is skipped, one line each), every record they depend
    on checked first: a problem anywhere refuses the whole queue, with every problem listed."""
    from safemanip.util.files import check_output_dir

    runs = bench.select(only)
    problems = check_output_dir(runs_dir)
    records = run_records(bench, runs, runs_dir, policies) if not problems else []
    problems += [r.problem for r in records if r.problem and r.state not in ("promoted", "finished")]
    if problems:
        raise RecordError(f"nothing trained: {len(problems)} problem(s):\n  - " + "\n  - ".join(problems))
    folder = Path(runs_dir).absolute()
    chosen = "" if bench.source.startswith("the shipped") else f" --benchmark {bench.source}"
    jobs = [Job(r.run.name, str(folder / r.run.name), json.loads(bench.config(r.run, folder / r.run.name).to_json()),
                bench.budget_env_steps, f"safemanip bench train --out {folder} --only {r.run.name}{chosen}")
            for r in records if r.state not in ("promoted", "finished")]
    skipped = [f"{r.run.name}: {r.state}" for r in records if r.state in ("promoted", "finished")]
    return jobs, skipped


def run_job(job: Job) -> dict:
    """Train the run from the start, or resume it from its newest checkpoint, whichever its folder calls for, with
    its output in FOLDER.log; returns {"name", "action", "env_steps", "stopped_by"} from its summary. A run that
    finished already is left as it is (a retried task whose first attempt finished)."""
    from safemanip.rl.checkpoint import find_checkpoint
    from safemanip.rl.config import TrainConfig, load_run_config
    from safemanip.rl.train import train

    folder = Path(job.folder)
    if job.token is not None:
        _check_token(folder.parent, job.token)
    if (folder / "summary.json").is_file():
        steps, stopped_by = read_summary(folder)
        if stopped_by is None and steps >= job.budget:
            return {"name": job.name, "action": "finished already", "env_steps": steps, "stopped_by": None}
    resume = find_checkpoint(folder) is not None
    cfg = load_run_config(folder / "config.json")[0] if resume else TrainConfig.from_dict(job.config)
    env_factory = None  # the registry's env the config names
    if cfg.selection_aware:  # rl imports nothing from selection: the training loop takes its env as an argument
        from safemanip.selection.training_env import SelectedSlotsEnv

        env_factory = SelectedSlotsEnv
    folder.parent.mkdir(parents=True, exist_ok=True)
    with open(folder.parent / f"{folder.name}.log", "a" if resume else "w", encoding="utf-8", buffering=1) as log, \
            redirect_stdout(log), redirect_stderr(log):
        try:
            train(cfg, resume=resume, progress=False, command=job.command, run_dir=folder, env_factory=env_factory)
        except Exception:  # the traceback goes to the run's log; the caller reports the error in one line
            import traceback

            traceback.print_exc()
            raise
    steps, stopped_by = read_summary(folder)
    return {"name": job.name, "action": "resumed" if resume else "trained", "env_steps": steps,
            "stopped_by": stopped_by}


def _check_token(runs_dir: Path, token: str) -> None:
    try:
        seen = (runs_dir / TOKEN_FILE).read_text().strip()
    except OSError:
        seen = None
    if seen != token:
        import socket

        raise RuntimeError(f"the node {socket.gethostname()} does not see the runs folder {runs_dir} that "
                           f"safemanip bench train writes into: mount it at the same path on every node of the "
                           f"cluster (a shared filesystem), then run the command again")


def outcome_line(outcome: dict, budget: int) -> str:
    text = f"{outcome['name']}: {outcome['action']}, {outcome['env_steps']:,} env steps"
    if outcome["stopped_by"]:
        return text + f", stopped by {outcome['stopped_by']} (run the command again to resume it)"
    if outcome["env_steps"] < budget:  # the recipe's time limit ended it before the budget: a stalled run
        return text + f", stopped by its time limit before {budget:,} (see its log)"
    return text


def train_here(jobs: list[Job], log=print) -> int:
    """The runs one after another in this process; exit code 0, 1 (a run failed or stopped short) or 128 + the
    signal that stopped one (the queue stops with it)."""
    failed = 0
    for job in jobs:
        log(f"{time.strftime('%H:%M')} {'resume' if _resumable(job) else 'train'} {job.name}")
        try:
            outcome = run_job(job)
        except Exception as err:  # one run's failure does not stop the others (as on a cluster)
            log(_failure_line(job, err))
            failed += 1
            continue
        log(outcome_line(outcome, job.budget))
        if outcome["stopped_by"]:
            return 128 + int(getattr(signal, outcome["stopped_by"], signal.SIGINT))
        failed += outcome["env_steps"] < job.budget
    return 1 if failed else 0


def train_on_ray(jobs: list[Job], runs_dir: Path, address: str, cpus_per_run: float = CPUS_PER_RUN,
                 log=print) -> int:
    """One Ray task per run on the cluster at ``address`` (checked first: a cluster that does not answer is refused
    within seconds), as many at a time as its CPUs allow; exit codes as ``train_here``. SIGINT/SIGTERM cancel the
    tasks: each run still training saves a checkpoint and its policy, then stops."""
    import ray

    from safemanip.util.files import atomic_write_text
    from safemanip.util.procs import init_ray, stop_on_signals

    init_ray(address)
    failed = 0
    try:
        token = secrets.token_hex(16)
        Path(runs_dir).mkdir(parents=True, exist_ok=True)
        atomic_write_text(Path(runs_dir) / TOKEN_FILE, token + "\n")
        # the task ships by reference (the package must be installed on every node); a worker or node that dies
        # is retried, and the retry resumes from the newest checkpoint
        task = ray.remote(num_cpus=cpus_per_run, max_retries=RETRIES)(run_job)
        # the stop is polled, not raised: an exception raised inside a Ray call from a signal handler comes out as
        # a SystemError, and a blocking wait never returns to Python, where the handler runs
        with stop_on_signals(raise_exc=False) as stopped:
            pending = {task.remote(replace(job, token=token)): job for job in jobs}
            log(f"{len(jobs)} run(s) sent to the Ray cluster at {address}, {cpus_per_run:g} CPUs each")
            while pending and stopped["signum"] is None:
                done, _ = ray.wait(list(pending), num_returns=1, timeout=WAIT_POLL_S)
                for ref in done:
                    job = pending.pop(ref)
                    try:
                        outcome = ray.get(ref)
                    except ray.exceptions.RayError as err:
                        log(_failure_line(job, err))
                        failed += 1
                        continue
                    log(f"{time.strftime('%H:%M')} {outcome_line(outcome, job.budget)}")
                    failed += outcome["env_steps"] < job.budget
            if stopped["signum"] is not None:
                _stop(ray, pending, log)
                return 128 + stopped["signum"]
    finally:
        ray.shutdown()
    return 1 if failed else 0


def _stop(ray, pending: dict, log) -> None:
    """Cancel the runs still on the cluster and wait (up to ``STOP_WAIT_S``) until each has saved a checkpoint and
    its policy: a driver that leaves at once takes its tasks with it before they have saved anything."""
    log(f"stopping: {len(pending)} run(s) on the cluster save a checkpoint and their policy (at most "
        f"{STOP_WAIT_S:.0f} s; run the same command to resume them)")
    for ref in pending:  # not forced: the run's own stop handler (SIGINT) ends its training loop at a safe point
        ray.cancel(ref)
    deadline = time.monotonic() + STOP_WAIT_S
    while pending and time.monotonic() < deadline:
        done, _ = ray.wait(list(pending), num_returns=1, timeout=WAIT_POLL_S)
        for ref in done:
            pending.pop(ref)


def _resumable(job: Job) -> bool:
    from safemanip.rl.checkpoint import find_checkpoint

    return find_checkpoint(Path(job.folder)) is not None


def _failure_line(job: Job, err: BaseException) -> str:
    """A run's failure in one line: the run's own exception (the last line of a Ray task error's traceback, else the
    message's first line), and where its traceback is if the run got as far as its log."""
    lines = [line.strip() for line in str(err).splitlines() if line.strip()] or [err.__class__.__name__]
    text = lines[-1] if hasattr(err, "cause") else lines[0]  # RayTaskError: a traceback ending in the exception
    log = Path(f"{job.folder}.log")
    return f"{job.name}: failed: {text[:300]}" + (f" (the traceback is in {log})" if log.is_file() else "")


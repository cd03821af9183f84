"""Running evaluation episodes in parallel: local processes (default) or Ray tasks.

Episodes are independent, so seeds are cut into chunks and each chunk runs in one worker with its
own env, actor and selectors (``run_chunk``). A record depends only on its seed and the spec, never
on which chunk or process ran it: every episode starts from ``env.reset(seed)``, selectors are reset
per episode, and the policy's NumPy forward pass is limited to one BLAS thread everywhere (a
multi-threaded matrix product may sum in a different order, and a last-bit difference in an action
can change a contact-rich rollout). Hence both backends give identical records for the same seeds.

The policy travels as arrays inside the spec, so Ray nodes need the ``safemanip`` package but not the
policy file.
"""

from __future__ import annotations

import contextlib
import math
import os
import shutil
import signal
import sys
import tempfile
import time
from dataclasses import dataclass, field
from typing import Callable, Iterator

import numpy as np

from safemanip.rl.numpy_actor import make_numpy_actor  # no torch import: workers start fast
from safemanip.util.procs import Interrupted, QuietSpawnContext, die_with_parent, signals_deferred
from safemanip.evaluation.registry import SelectorOptions

BACKENDS = ("local", "ray")
"""The compute backends by name (``--backend``)."""
_ONE_THREAD = {v: "1" for v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}


@dataclass
class EvalSpec:
    """Everything a worker needs to run episodes; plain data (pickled to processes / Ray tasks)."""

    actor_arrays: list[np.ndarray] | dict[str, np.ndarray]
    """Actor weights as saved in a policy file: a list layer by layer (W as out x in) for the flat MLP, a
    dict by parameter name for the object-set actor (``rl/numpy_actor.py``)."""
    k: int
    policy_constraints: str
    env_kwargs: dict
    selector: str
    constraints: str
    options: SelectorOptions = field(default_factory=SelectorOptions)
    pad: bool = False
    camera: str = "front"
    object_size: bool = False
    """The policy's slots carry footprint radii (it was trained with ``object_size``)."""
    planner: str | None = None
    """Instead of the policy, the privileged planner keeping clear of 'all' objects or of the 'fragile' ones only
    (``control.planner.PLANNER_AVOID``): the bound on the same scenes."""
    shield: str | None = None
    """A safety filter around the policy (``safety.SHIELDS``), or None."""


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # workers also get OMP/OPENBLAS_NUM_THREADS=1 from their environment (see run_local)
        yield
        return
    with threadpool_limits(limits=1, user_api="blas"):
        yield


def run_chunk(spec: EvalSpec, seeds: list[int], on_record: Callable[[dict], None] | None = None) -> list[dict]:
    """Records of the episodes with these seeds, in the order given; ``on_record`` sees each as it finishes."""
    from safemanip.env.slide_out import SlideOutEnv
    from safemanip.evaluation.episode import run_episode
    from safemanip.selection.reducer import Reducer
    from safemanip.evaluation.registry import make_constraint_selector, make_object_selector
    from safemanip.selection.view import EnvViewBuilder

    with one_blas_thread():
        env = SlideOutEnv(**spec.env_kwargs)
        try:
            if spec.planner is not None:
                from safemanip.control.planner import GridPlanner
                from safemanip.evaluation.episode import run_planner_episode

                planner = GridPlanner(avoid=spec.planner)
                records = []
                for s in seeds:
                    records.append(run_planner_episode(env, planner, s))
                    if on_record is not None:
                        on_record(records[-1])
                return records
            actor = make_numpy_actor(spec.actor_arrays)
            reducer = Reducer(spec.k, spec.policy_constraints, pad=spec.pad, empty_slots=actor.network == "set",
                              object_size=spec.object_size)
            osel = make_object_selector(spec.selector, spec.options)
            csel = make_constraint_selector(spec.constraints, spec.options)
            builder = EnvViewBuilder(camera=spec.camera)
            shield = None
            if spec.shield is not None:
                from safemanip.safety import make_shield
                shield = make_shield(spec.shield)
            records = []
            for s in seeds:
                records.append(run_episode(env, actor, reducer, osel, csel, s, builder=builder, shield=shield,
                                           soft_reach=spec.options.soft_reach))
                if on_record is not None:
                    on_record(records[-1])
            return records
        finally:
            env.close()


def chunk_seeds(seeds: list[int], workers: int, chunk_size: int | None = None) -> list[list[int]]:
    """Consecutive chunks; by default about 8 per worker (load balance) but at most 25 episodes each."""
    if chunk_size is None:
        chunk_size = max(1, min(25, math.ceil(len(seeds) / (8 * workers))))
    return [seeds[i:i + chunk_size] for i in range(0, len(seeds), chunk_size)]


class Progress:
    """A line on stderr at most every ``every_s`` seconds (and at the end)."""

    def __init__(self, total: int, enabled: bool, every_s: float = 10.0, label: str = "eval"):
        self.total, self.enabled, self.every_s, self.label = total, enabled, every_s, label
        self.done = 0
        self.start = self.last = time.perf_counter()

    def add(self, n: int) -> None:
        self.done += n
        now = time.perf_counter()
        if self.enabled and (now - self.last >= self.every_s or self.done == self.total):
            rate = self.done / max(now - self.start, 1e-9)
            print(f"{self.label}: {self.done}/{self.total} episodes ({rate:.1f}/s)", file=sys.stderr, flush=True)
            self.last = now


@contextlib.contextmanager
def _env_vars(values: dict) -> Iterator[None]:
    old = {k: os.environ.get(k) for k in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


class PartialRun(Exception):
    """A run stopped by SIGINT/SIGTERM: the records of the episodes finished before it, in seed order."""

    def __init__(self, records: list[dict], signum: int):
        super().__init__(f"stopped by signal {signum} after {len(records)} episodes")
        self.records, self.signum = records, signum


class WorkerFailure(Exception):
    """A worker process died (killed, out of memory) or failed: the records of every episode finished before it,
    in seed order (including those its own chunk finished), the seeds that did not finish, and why."""

    def __init__(self, records: list[dict], missing: list[int], reason: str):
        super().__init__(f"{reason}; {len(records)} episodes finished, {len(missing)} did not")
        self.records, self.missing, self.reason = records, missing, reason


_WORKER_SPEC: EvalSpec | None = None
_WORKER_JOURNAL: str | None = None


def _worker_init(parent_pid: int, spec: EvalSpec, journal: str | None = None) -> None:
    """Pool worker start-up: die with the parent (kill -9 included) and keep the spec, so that tasks carry only
    their seeds. (A task holding the weights can fill the pipe to the workers; if they are then killed, the
    pool's feeder thread blocks on that pipe for ever and so does the shutdown.) ``journal``: a folder where each
    finished episode's record is appended at once, so that a worker killed mid-chunk loses none of them."""
    global _WORKER_SPEC, _WORKER_JOURNAL
    die_with_parent(parent_pid)
    _WORKER_SPEC, _WORKER_JOURNAL = spec, journal


def _run_chunk_in_worker(seeds: list[int]) -> list[dict]:
    if _WORKER_JOURNAL is None:
        return run_chunk(_WORKER_SPEC, seeds)
    import json

    with open(os.path.join(_WORKER_JOURNAL, f"worker-{os.getpid()}.jsonl"), "a", encoding="utf-8") as journal:
        def keep(record: dict) -> None:
            journal.write(json.dumps(record, default=float) + "\n")
            journal.flush()  # in the kernel's hands: survives a SIGKILL of this process

        return run_chunk(_WORKER_SPEC, seeds, keep)


def _journal_records(folder: str) -> list[dict]:
    """Every whole record in a journal folder (a line torn by a kill is left out)."""
    from safemanip.util.files import parse_json

    out = []
    for name in sorted(os.listdir(folder)):
        with open(os.path.join(folder, name), encoding="utf-8", errors="replace") as f:
            for line in f:
                try:
                    record = parse_json(line, "a journal line", max_bytes=1_000_000)
                except ValueError:
                    continue
                if isinstance(record, dict) and isinstance(record.get("seed"), int):
                    out.append(record)
    return out


def run_local(spec: EvalSpec, seeds: list[int], workers: int = 2, chunk_size: int | None = None,
              on_chunk: Callable[[int], None] | None = None) -> list[dict]:
    """In this process for one worker, else a spawn pool of ``workers`` processes. An ``Interrupted``
    (SIGINT/SIGTERM) stops the workers and raises ``PartialRun`` with the records finished so far."""
    chunks = chunk_seeds(seeds, workers, chunk_size)
    records: list[dict] = []
    journal = tempfile.mkdtemp(prefix="safemanip-eval-") if workers > 1 else None
    try:
        _run_local(spec, chunks, workers, on_chunk, records, journal)
    except Interrupted as stop:
        raise PartialRun(_in_seed_order(records, [s for c in chunks for s in c], partial=True), stop.signum) from None
    except _PoolBroke as broke:
        have = {r["seed"] for r in records}
        records += [r for r in _journal_records(journal) if r["seed"] not in have and r["seed"] in set(seeds)]
        done = _in_seed_order(records, seeds, partial=True)
        finished = {r["seed"] for r in done}
        raise WorkerFailure(done, [s for s in seeds if s not in finished], broke.reason) from None
    finally:
        if journal is not None:
            shutil.rmtree(journal, ignore_errors=True)
    return _in_seed_order(records, seeds)


class _PoolBroke(Exception):
    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


def _worker_exits(pool) -> str:
    from safemanip.util.procs import describe_exit

    processes = list((getattr(pool, "_processes", None) or {}).values())
    # the pool's own thread reaps the dead worker and sends SIGTERM to the others: wait (briefly) until the exit code
    # it reaped is stored, and report the worker that died first, not the ones the pool ended
    deadline = time.monotonic() + 2.0
    while True:
        codes = [c for c in (p.exitcode for p in processes) if c not in (None, 0)]
        first = [c for c in codes if c != -signal.SIGTERM]
        if first or time.monotonic() > deadline:
            break
        time.sleep(0.05)
    codes = first or codes
    return f"a worker process {describe_exit(codes[0])}" if codes else "a worker process died"


def _run_local(spec, chunks, workers, on_chunk, records: list[dict], journal: str | None = None) -> None:
    if workers <= 1:
        for c in chunks:
            part = run_chunk(spec, c)
            records += part
            if on_chunk:
                on_chunk(len(c))
    else:
        # spawn, not fork: MuJoCo/OpenGL state and threads do not survive a fork safely. The children
        # inherit the one-thread BLAS settings from the environment before they import numpy. A
        # ProcessPoolExecutor (not mp.Pool) so that a worker that dies raises BrokenProcessPool
        # instead of being replaced silently and hanging the run.
        from concurrent.futures import ProcessPoolExecutor, as_completed

        from concurrent.futures.process import BrokenProcessPool

        pool = ProcessPoolExecutor(min(workers, len(chunks)), mp_context=QuietSpawnContext(),
                                   initializer=_worker_init, initargs=(os.getpid(), spec, journal))
        try:
            # the pool starts its workers here, in submit (not in its constructor): with the one-thread settings
            # in the environment, and with SIGINT/SIGTERM held back until every worker is started and known to
            # the pool, which then ends them all (a stop half-way through sending a worker its start-up data
            # left a worker nobody ended, printing an unpickling traceback)
            with _env_vars(_ONE_THREAD), signals_deferred():
                futures = [pool.submit(_run_chunk_in_worker, c) for c in chunks]
            try:
                for fut in as_completed(futures):
                    part = fut.result()
                    records += part
                    if on_chunk:
                        on_chunk(len(part))
            except BrokenProcessPool:
                reason = _worker_exits(pool)
                for fut in futures:  # chunks that finished before the pool broke
                    if fut.done() and not fut.cancelled() and fut.exception() is None:
                        have = {r["seed"] for r in records}
                        records += [r for r in fut.result() if r["seed"] not in have]
                raise _PoolBroke(reason) from None
            except (Interrupted, KeyboardInterrupt):
                raise
            except Exception as err:  # an episode raised in a worker: keep what is finished, say what failed
                raise _PoolBroke(f"an episode failed in a worker ({err.__class__.__name__}: {str(err)[:300]})") from None
        except BaseException:
            # do not keep simulating after a failure or a stop: cancel what has not started, end the workers
            for proc in list(getattr(pool, "_processes", {}).values()):
                proc.kill()
            pool.shutdown(wait=True, cancel_futures=True)
            raise
        pool.shutdown(wait=True)


def run_ray(spec: EvalSpec, seeds: list[int], workers: int = 2, address: str | None = None,
            chunk_size: int | None = None, on_chunk: Callable[[int], None] | None = None) -> list[dict]:
    """One Ray task per chunk, on the cluster at ``address`` or on a local instance with ``workers`` CPUs.

    An already initialised Ray (e.g. by the caller) is used as it is and left running.
    """
    try:
        import ray
    except ImportError as err:
        raise RuntimeError("--backend ray needs Ray: pip install 'ray[default]'") from err
    started = False
    if not ray.is_initialized():
        from safemanip.util.procs import init_ray

        init_ray(address, workers)
        started = True
    records: list[dict] = []
    pending: list = []
    try:
        remote = ray.remote(num_cpus=1)(run_chunk)
        spec_ref = ray.put(spec)  # one copy of the weights in the object store, shared by all tasks
        chunks = chunk_seeds(seeds, max(workers, int(ray.cluster_resources().get("CPU", workers))), chunk_size)
        pending = [remote.remote(spec_ref, c) for c in chunks]
        failure = None
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            try:
                part = ray.get(done[0])
            except ray.exceptions.RayError as err:  # a task that failed after Ray's own retries: go on with the rest
                failure = failure or f"a Ray task failed ({err.__class__.__name__}: {(str(err).splitlines() or [''])[0][:200]})"
                continue
            records += part
            if on_chunk:
                on_chunk(len(part))
        if failure:
            done_records = _in_seed_order(records, seeds, partial=True)
            finished = {r["seed"] for r in done_records}
            raise WorkerFailure(done_records, [s for s in seeds if s not in finished], failure)
    except Interrupted as stop:
        for ref in pending:
            ray.cancel(ref, force=True)
        raise PartialRun(_in_seed_order(records, seeds, partial=True), stop.signum) from None
    finally:
        if started:  # only shut down (or disconnect from) what this call started
            ray.shutdown()
    return _in_seed_order(records, seeds)


def _in_seed_order(records: list[dict], seeds: list[int], partial: bool = False) -> list[dict]:
    by_seed = {r["seed"]: r for r in records}
    return [by_seed[int(s)] for s in seeds if not partial or int(s) in by_seed]


def run_episodes(spec: EvalSpec, seeds: list[int], *, workers: int = 2, backend: str = "local",
                 address: str | None = None, chunk_size: int | None = None, progress: bool = False) -> list[dict]:
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    bar = Progress(len(seeds), progress)
    if backend == "ray":
        return run_ray(spec, seeds, workers, address, chunk_size, bar.add)
    return run_local(spec, seeds, workers, chunk_size, bar.add)

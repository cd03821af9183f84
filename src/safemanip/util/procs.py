"""Process hygiene: worker processes that die with their parent, and SIGINT/SIGTERM turned into an
orderly stop of the main process.

``die_with_parent`` is the initializer of every worker process the package starts (training
collectors, evaluation pools): on Linux it asks the kernel for SIGKILL when the parent dies
(``prctl(PR_SET_PDEATHSIG)``), and on every platform a daemon thread watches the parent's pid as a
fallback (e.g. a worker blocked on a pipe write when its parent was killed with SIGKILL)."""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import threading
import time
from typing import Iterator

PR_SET_PDEATHSIG = 1


class Interrupted(Exception):
    """SIGINT or SIGTERM arrived: stop, keep what is finished."""

    def __init__(self, signum: int):
        super().__init__(f"interrupted by {signal.Signals(signum).name}")
        self.signum = signum

    @property
    def exit_code(self) -> int:
        return 128 + self.signum


def die_with_parent(parent_pid: int | None = None, poll_s: float = 0.5, ignore_sigint: bool = True) -> None:
    """Make this (worker) process exit when its parent does.

    ``parent_pid``: the pid to watch; pass the parent's own ``os.getpid()`` from the parent (the default,
    the current parent, is already wrong if the parent died while this process was starting up). With
    ``ignore_sigint`` a Ctrl-C in the terminal (sent to the whole process group) is left to the parent,
    which stops the workers."""
    parent_pid = parent_pid or os.getppid()
    if ignore_sigint:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    with contextlib.suppress(Exception):  # not Linux, or no libc: the watchdog below still works
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if os.getppid() != parent_pid:  # the parent died before prctl took effect
        os._exit(1)

    def watch() -> None:
        while True:
            time.sleep(poll_s)
            if os.getppid() != parent_pid:
                os._exit(1)

    threading.Thread(target=watch, name="parent-watchdog", daemon=True).start()


def run_as_worker(parent_pid: int, target, *args) -> None:
    """Process target wrapper: ``die_with_parent(parent_pid)``, then ``target(*args)``."""
    die_with_parent(parent_pid)
    target(*args)


@contextlib.contextmanager
def stop_on_signals(raise_exc: bool = True, signals=(signal.SIGINT, signal.SIGTERM)) -> Iterator[dict]:
    """Within the block the first SIGINT/SIGTERM sets ``state["signum"]`` and, with ``raise_exc``, raises
    ``Interrupted`` in the main thread; without it the caller polls the flag at a safe point (the
    training loop, so that no update is left half-done). Later signals are ignored so that saving can
    finish. Yields the state dict."""
    state: dict = {"signum": None}
    if threading.current_thread() is not threading.main_thread():
        yield state
        return

    def handler(signum, frame):
        if state["signum"] is None:
            state["signum"] = signum
            if raise_exc:
                raise Interrupted(signum)

    old = {s: signal.signal(s, handler) for s in signals}
    try:
        yield state
    finally:
        for s, h in old.items():
            signal.signal(s, h)


_REAPER = None


def init_ray(address: str | None = None, num_cpus: int | None = None) -> None:
    """``ray.init`` for the cluster at ``address``, or a local instance that does not outlive this process.

    A local instance's own processes (GCS, raylet, its workers and agents) are descendants of this one; a
    watchdog (``util/reaper.py``) kills any of them still running once this process is gone, even after
    ``kill -9`` (Ray's agents alone would linger for about a minute)."""
    global _REAPER
    import ray

    kwargs = {"include_dashboard": False, "log_to_driver": False}
    if address:
        ray.init(address=address, **kwargs)
        return
    if _REAPER is None or _REAPER.poll() is not None:  # first: a kill during ray.init leaves nothing either
        from safemanip.util.reaper import start_reaper

        _REAPER = start_reaper()
    ray.init(num_cpus=num_cpus, **kwargs)

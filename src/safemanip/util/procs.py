"""Process hygiene: worker processes that die with their parent, and SIGINT/SIGTERM turned into an
orderly stop of the main process.

``die_with_parent`` is the initializer of every worker process the package starts (training
collectors, evaluation pools): on Linux it asks the kernel for SIGKILL when the parent dies
(``prctl(PR_SET_PDEATHSIG)``), and on every platform a daemon thread watches the parent's pid as a
fallback (e.g. a worker blocked on a pipe write when its parent was killed with SIGKILL).

A worker that is still starting when its parent stops is ended quietly from both sides: the parent holds
SIGINT/SIGTERM back while it starts workers (``signals_deferred``), so that it never stops half-way through
sending a worker its start-up data and every worker it started is one it knows to end; and a worker of
``QuietSpawnContext`` that finds its start-up data cut off (the parent was killed) exits without a traceback."""

from __future__ import annotations

import contextlib
import ctypes
import multiprocessing.context
import os
import signal
import sys
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
    if getattr(sys.excepthook, "_start_up_only", False):  # started: errors are reported again (QuietSpawnContext)
        sys.excepthook = sys.__excepthook__
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


@contextlib.contextmanager
def signals_deferred(signals=(signal.SIGINT, signal.SIGTERM)) -> Iterator[None]:
    """Hold SIGINT/SIGTERM back within the block and deliver them, to whatever handler was installed before, when
    it ends. Around starting worker processes: a stop raised half-way through writing a worker's start-up data
    leaves a worker that the pool does not know (so never ends) and that fails to unpickle what it got, with a
    traceback. A second signal within the block is delivered at once (a start that hangs can still be stopped).
    Only in the main thread (signal handlers run there); elsewhere the block runs as it is."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held: list[int] = []

    def restore() -> None:
        for s, handler in old.items():
            signal.signal(s, handler if handler is not None else signal.SIG_DFL)

    def hold(signum, frame):
        if held:  # asked twice: stop now, as without the block
            held.clear()
            restore()
            signal.raise_signal(signum)
        else:
            held.append(signum)

    old = {s: signal.signal(s, hold) for s in signals}
    try:
        yield
    finally:
        restore()
        for signum in held:
            signal.raise_signal(signum)


def _start_quietly(parent_pid: int) -> None:
    """Run in a starting worker while it unpickles its start-up data, before anything heavy is imported: leave
    Ctrl-C to the parent, and exit without a traceback if the start-up fails because the parent stopped (data cut
    off or a pipe closed by a killed parent, or the parent gone). ``die_with_parent`` restores the hook."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)

    def hook(kind, value, tb) -> None:
        import pickle

        interrupted = issubclass(kind, (EOFError, pickle.UnpicklingError, BrokenPipeError, KeyboardInterrupt))
        if interrupted or os.getppid() != parent_pid:
            return  # the interpreter exits with code 1, silently: the parent that wanted this worker is gone
        sys.__excepthook__(kind, value, tb)

    hook._start_up_only = True  # type: ignore[attr-defined]
    sys.excepthook = hook


class _StartQuietly:
    """Pickled first among a worker process's start-up data, so that ``_start_quietly`` runs in the worker before
    the rest (the heavy part, e.g. policy weights) is read."""

    def __init__(self, parent_pid: int):
        self.parent_pid = parent_pid

    def __reduce__(self):
        return _start_quietly, (self.parent_pid,)


def _rebuild_process(started, cls, state: dict):
    process = cls.__new__(cls)
    process.__dict__.update(state)
    return process


class QuietSpawnProcess(multiprocessing.context.SpawnProcess):
    """A spawn process whose start-up (``_StartQuietly``) makes a start cut off by its parent's end silent."""

    def __reduce__(self):
        return _rebuild_process, (_StartQuietly(os.getpid()), type(self), self.__dict__)


class QuietSpawnContext(multiprocessing.context.SpawnContext):
    """``multiprocessing.get_context("spawn")`` with ``QuietSpawnProcess`` (for ``ProcessPoolExecutor(mp_context=)``)."""

    Process = QuietSpawnProcess


class WorkerDied(RuntimeError):
    """A worker process (an evaluation worker, a rollout worker or a Ray actor) died or failed: the run stopped
    and kept what was finished; the message says what happened and how to go on. Exit code 1."""

    exit_code = 1


def describe_exit(code: int | None) -> str:
    """'exited with code 3' / 'was killed by SIGKILL' for a process exit code (negative: the signal)."""
    if code is None:
        return "died"
    if code < 0:
        try:
            return f"was killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"was killed by signal {-code}"
    return f"exited with code {code}"


class ClusterUnreachable(ValueError):
    """A Ray cluster address that is malformed or where no Ray cluster answers (exit code 2)."""


RAY_ADDRESS_VARIABLE = "RAY_ADDRESS"
PROBE_TIMEOUT_S = 5.0
_HTTP2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + b"\x00\x00\x00\x04\x00\x00\x00\x00\x00"


def ray_address(flag: str | None) -> tuple[str | None, str]:
    """(address, where it came from) of the Ray cluster to join: the --address flag, else the RAY_ADDRESS
    environment variable, else None (start a local instance). Never a file."""
    if flag:
        return flag, "--address"
    env = os.environ.get(RAY_ADDRESS_VARIABLE, "").strip()
    return (env, RAY_ADDRESS_VARIABLE) if env else (None, "")


def check_ray_address(address: str, source: str = "--address", timeout_s: float = PROBE_TIMEOUT_S) -> None:
    """Refuse (ClusterUnreachable, within about ``timeout_s`` seconds) an address where no Ray cluster answers.

    HOST:PORT (or ray://HOST:PORT, Ray Client) is checked with a TCP connection and the HTTP/2 preface that every
    gRPC server, Ray's GCS included, answers at once with a SETTINGS frame: ``ray.init`` itself waits minutes on a
    port that is closed, filtered or held by another service. 'auto' (a cluster started on this machine) is
    left to Ray, which looks it up locally."""
    import socket

    text = address.strip()
    if text in ("auto", "local"):
        return
    target = text[len("ray://"):] if text.startswith("ray://") else text
    host, _, port = target.rpartition(":")
    host = host.strip("[]")
    if not host or not port.isdigit() or not 0 < int(port) < 65536 or any(c.isspace() or c == "/" for c in target):
        raise ClusterUnreachable(f"{source} {address[:100]!r} is not a Ray cluster address: give HOST:PORT (e.g. "
                                 f"10.0.0.5:6379, the GCS address `ray start --head` prints), ray://HOST:PORT or auto")
    start = time.monotonic()
    try:
        with socket.create_connection((host, int(port)), timeout=timeout_s) as sock:
            sock.settimeout(max(0.5, timeout_s - (time.monotonic() - start)))
            sock.sendall(_HTTP2_PREFACE)
            head = b""
            while len(head) < 9:
                part = sock.recv(9 - len(head))
                if not part:
                    break
                head += part
    except socket.timeout:
        raise ClusterUnreachable(f"{source} {address}: no Ray cluster answered within {timeout_s:g} s (the address is "
                                 f"filtered, or the port belongs to another service); check the address, that the "
                                 f"cluster runs (`ray status` on its head node) and the firewall") from None
    except OSError as err:
        raise ClusterUnreachable(f"{source} {address}: cannot reach a Ray cluster there ({err.strerror or err}); start "
                                 f"it with `ray start --head` on that machine or fix the address") from None
    if len(head) < 9 or head[3] != 0x04:  # an HTTP/2 SETTINGS frame: a gRPC server such as Ray's GCS
        raise ClusterUnreachable(f"{source} {address}: the service on that port is not a Ray cluster (it does not "
                                 f"speak gRPC); give the GCS address `ray start --head` prints (port 6379 by default)")


_REAPER = None


def init_ray(address: str | None = None, num_cpus: int | None = None) -> None:
    """``ray.init`` for the cluster at ``address`` (the --address flag) or at RAY_ADDRESS, each checked first
    (``check_ray_address``: an address where no cluster answers fails within seconds, not minutes), else a
    local instance that does not outlive this process.

    A local instance's own processes (GCS, raylet, its workers and agents) are descendants of this one; a
    watchdog (``util/reaper.py``) kills any of them still running once this process is gone, even after
    ``kill -9`` (Ray's agents alone would linger for about a minute)."""
    global _REAPER
    import ray

    kwargs = {"include_dashboard": False, "log_to_driver": False}
    address, source = ray_address(address)
    if address:
        check_ray_address(address, source)
        try:
            ray.init(address=address, **kwargs)
        except ConnectionError as err:  # the cluster answers but refuses this driver: say why, not a traceback
            cause = err.__cause__ if err.__cause__ is not None else err
            if "auth" in type(cause).__name__.lower() or "token" in str(cause).lower():
                raise ClusterUnreachable(
                    f"{source} {address}: the Ray cluster refused this connection: it uses token authentication (the "
                    f"default of `ray start` in recent Ray versions). Run this command with the cluster's "
                    f"RAY_AUTH_MODE=token and its token in RAY_AUTH_TOKEN (or ~/.ray/auth_token)") from None
            raise ClusterUnreachable(f"{source} {address}: cannot join the Ray cluster there "
                                     f"({(str(cause).splitlines() or [''])[0][:200]}); check `ray status` on its "
                                     f"head node") from None
        return
    if _REAPER is None or _REAPER.poll() is not None:  # first: a kill during ray.init leaves nothing either
        from safemanip.util.reaper import start_reaper

        _REAPER = start_reaper()
    ray.init(num_cpus=num_cpus, **kwargs)

"""A watchdog process that kills a process's descendants once that process is gone, however it went.

Our own workers die with their parent (``procs.die_with_parent``), but processes started by a library are out
of our hands: after ``kill -9`` of a driver, a local Ray instance's dashboard and runtime-env agents wait about a
minute on the dead GCS before they exit. ``start_reaper()`` (Linux; a no-op elsewhere) starts

    python -m safemanip.util.reaper PID

which, while PID lives, notes PID's descendants (pid and start time) every ``POLL_S`` seconds, and when PID is
gone sends SIGKILL to every one of them still running under the same start time (so a reused pid is never hit).
When PID is gone it first stops (SIGSTOP) every noted process and whatever they started since the last poll,
then kills them: a Ray worker spawned in the last quarter second before the kill, or one a raylet respawns while
the reaper is killing its siblings, would otherwise escape (two Ray processes outliving a kill -9 of an eval was
a rare CI failure with an earlier last-sweep-then-kill order).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

POLL_S = 0.25


def _stat(pid: int) -> tuple[int, int] | None:
    """(parent pid, start time in clock ticks) of a live process, or None."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    if fields[0] == "Z":
        return None
    return int(fields[1]), int(fields[19])


def descendants(*roots: int) -> dict[int, int]:
    """pid -> start time of every live descendant of any of ``roots`` (one pass over /proc)."""
    children: dict[int, list[int]] = {}
    started: dict[int, int] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            info = _stat(int(entry))
            if info is not None:
                children.setdefault(info[0], []).append(int(entry))
                started[int(entry)] = info[1]
    out, todo = {}, list(roots)
    while todo:
        for child in children.get(todo.pop(), []):
            if child not in out:
                out[child] = started[child]
                todo.append(child)
    return out


TAG_VARIABLE = "SAFEMANIP_REAPER_TAG"
"""Set in the watched process's environment, so every process it starts, and they start, inherits it."""


def tagged(tag: str, not_before: int) -> dict[int, int]:
    """pid -> start time of every live process started at or after ``not_before`` whose environment holds the tag:
    the watched process's lineage, found even after an orphan was re-parented away from it."""
    needle = f"{TAG_VARIABLE}={tag}".encode()
    out = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                environ = Path(f"/proc/{entry}/environ").read_bytes()
            except OSError:
                continue
            info = _stat(int(entry))
            if info is not None and info[1] >= not_before and needle in environ.split(b"\0"):
                out[int(entry)] = info[1]
    return out


def watch(root: int, tag: str | None = None) -> None:
    me = os.getpid()
    root_started = _stat(root)
    seen: dict[int, int] = {}
    while root_started is not None and _stat(root) == root_started:
        seen.update(descendants(root))
        seen = {p: t for p, t in seen.items() if p != me and (_stat(p) or (0, -1))[1] == t}
        time.sleep(POLL_S)
    # Freeze first, kill second: SIGSTOP every noted process, oldest (parents) first, and add what they started
    # since the last poll until nothing new turns up; a stopped process can neither fork nor respawn a worker
    # it sees die (a raylet does), so the SIGKILLs that follow leave nothing behind.
    stopped: dict[int, int] = {}
    while True:
        seen.update(descendants(*seen))
        if tag and root_started is not None:
            # also what was started in the last poll interval and re-parented away from the tree before it was
            # noted: Ray's agents, started by the raylet, escaped so once in about six kills
            seen.update(tagged(tag, root_started[1]))
        seen.pop(me, None)
        fresh = sorted(((t, p) for p, t in seen.items() if p not in stopped))
        if not fresh:
            break
        for started, pid in fresh:
            stopped[pid] = started
            _signal_if_same(pid, started, signal.SIGSTOP)
    for pid, started in stopped.items():
        _signal_if_same(pid, started, signal.SIGKILL)


def _signal_if_same(pid: int, started: int, signum: int) -> None:
    """Send ``signum`` to ``pid`` only if it is still the process that started at ``started`` (pids get reused)."""
    info = _stat(pid)
    if info is not None and info[1] == started:
        try:
            os.kill(pid, signum)
        except OSError:
            pass


def start_reaper() -> subprocess.Popen | None:
    """Start the watchdog for this process (Linux only; returns None elsewhere)."""
    if not sys.platform.startswith("linux"):
        return None
    tag = os.environ.get(TAG_VARIABLE) or f"{os.getpid()}-{time.time_ns()}"
    os.environ[TAG_VARIABLE] = tag  # before anything it should reap is started
    return subprocess.Popen([sys.executable, "-m", "safemanip.util.reaper", str(os.getpid()), tag],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


if __name__ == "__main__":
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C to the group is for the watched process
    watch(int(sys.argv[1]), sys.argv[2] if len(sys.argv) > 2 else None)

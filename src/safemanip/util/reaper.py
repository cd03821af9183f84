"""A watchdog process that kills a process's descendants once that process is gone, however it went.

Our own workers die with their parent (``procs.die_with_parent``), but processes started by a library are out
of our hands: after ``kill -9`` of a driver, a local Ray instance's dashboard and runtime-env agents wait about a
minute on the dead GCS before they exit. ``start_reaper()`` (Linux; a no-op elsewhere) starts

    python -m safemanip.util.reaper PID

which, while PID lives, notes PID's descendants (pid and start time) every ``POLL_S`` seconds, and when PID is
gone sends SIGKILL to every one of them still running under the same start time (so a reused pid is never hit).
A last sweep when PID is gone adds what the noted processes started since the last poll (a Ray worker spawned
in the last quarter second before a kill would otherwise escape: the likely cause of a rare CI failure in which
two Ray processes outlived a kill -9 of an eval. Not proven: that test failed once in CI and once here, then
passed the seven runs here since this sweep went in).
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


def watch(root: int) -> None:
    me = os.getpid()
    root_started = _stat(root)
    seen: dict[int, int] = {}
    while root_started is not None and _stat(root) == root_started:
        seen.update(descendants(root))
        seen = {p: t for p, t in seen.items() if p != me and (_stat(p) or (0, -1))[1] == t}
        time.sleep(POLL_S)
    # a last sweep: what the noted processes (still running) started since the last poll
    seen.update(descendants(*seen))
    seen.pop(me, None)
    for pid, started in seen.items():
        info = _stat(pid)
        if info is not None and info[1] == started:
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass


def start_reaper() -> subprocess.Popen | None:
    """Start the watchdog for this process (Linux only; returns None elsewhere)."""
    if not sys.platform.startswith("linux"):
        return None
    return subprocess.Popen([sys.executable, "-m", "safemanip.util.reaper", str(os.getpid())],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


if __name__ == "__main__":
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C to the group is for the watched process
    watch(int(sys.argv[1]))

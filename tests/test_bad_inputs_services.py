"""Bad inputs, second round (issue 28): servers, secrets and workers. A server that drips its reply a byte a
second is cut off by --vlm-timeout and the time budgets (the whole request, not each read); a reply nested
100,000 deep or larger than any answer is a bad answer that falls back; a Ray address where no cluster answers
fails within seconds; the API key (in any letter case) and URL credentials never reach a message, a cache file
or render-query's output; a killed worker loses no finished episode and says how to go on.

The time bounds below only prove "did not hang": each is several times what the run needs."""

from __future__ import annotations

import csv
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from safemanip.cli import main
from safemanip.semantics import BackendError, ConstraintQuery, ObjectQuery, ResponseCache
from safemanip.semantics.guard import GuardedBackend
from safemanip.semantics.openai_backend import OpenAIBackend
from safemanip.semantics.selectors import DynamicVLMSelector, VLMConstraintSelector, dynamic_knn
from test_bad_inputs import assert_refused, run
from test_evaluation import make_policy
from test_semantics_openai import NAMES, FakeServer, completion, json_reply, pick_last_k, schema_of, view

SECRET = "sk-test-Secret-0123456789abcdef"
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}


class DripServer:
    """A TCP server that answers every request one byte a second: its headers (``mode="headers"``) or, after
    prompt headers, its body (``mode="body"``). No read ever waits long enough for a per-read timeout."""

    def __init__(self, mode: str = "body"):
        self.mode, self.stop = mode, threading.Event()
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(8)
        self.sock.settimeout(0.2)
        self.thread = threading.Thread(target=self._serve, daemon=True)

    @property
    def base_url(self) -> str:
        return f"http://127.0.0.1:{self.sock.getsockname()[1]}/v1"

    def _serve(self):
        while not self.stop.is_set():
            try:
                conn, _ = self.sock.accept()
            except OSError:
                continue
            threading.Thread(target=self._drip, args=(conn,), daemon=True).start()

    def _drip(self, conn):
        head = b"HTTP/1.1 200 OK\r\nContent-Type: application/json\r\nContent-Length: 100000\r\n\r\n"
        try:
            conn.settimeout(1.0)
            conn.recv(1 << 20)
            if self.mode == "body":
                conn.sendall(head)
                head = b" " * 100_000
            for i in range(len(head)):
                if self.stop.is_set():
                    break
                conn.sendall(head[i:i + 1])
                time.sleep(1.0)
        except OSError:
            pass
        finally:
            conn.close()

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.stop.set()
        self.thread.join(timeout=5)
        self.sock.close()


# ------------------------------------------------------------------------------------------ 4. time limits


def test_a_cache_entry_nested_deep_is_a_miss(tmp_path):
    def answer_for(req):
        labels = schema_of(req)["properties"]["constraints"]["required"]
        return {"constraints": {lbl: {"explanation": "x", "constraint": "no_contact"} for lbl in labels}}

    with FakeServer(json_reply(answer_for)) as server:
        backend = OpenAIBackend(model="m", base_url=server.base_url, timeout_s=5.0, cache=ResponseCache(tmp_path))
        backend.assign_constraints(ConstraintQuery(names=NAMES))
        (entry,) = tmp_path.glob("??/*.json")
        entry.write_text("[" * 100_000 + "]" * 100_000)
        cache_only = OpenAIBackend(model="m", base_url=server.base_url, cache=ResponseCache(tmp_path, "cache_only"))
        with pytest.raises(BackendError, match="nests 100,000 levels deep"):
            cache_only.assign_constraints(ConstraintQuery(names=NAMES))
        sent = len(server.requests)
        backend.assign_constraints(ConstraintQuery(names=NAMES))  # readwrite: a miss, asked again and stored
        assert len(server.requests) == sent + 1 and len(json.loads(entry.read_text())["answer"]["constraints"]) == 3


# ------------------------------------------------------------------------------------------ 4. Ray addresses
def _closed_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


class SilentPort:
    """Accepts connections and never answers (a filtered port, or a service that waits for its client)."""

    def __enter__(self):
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(8)
        self.address = f"127.0.0.1:{self.sock.getsockname()[1]}"
        return self

    def __exit__(self, *exc):
        self.sock.close()


def _ray_commands(tmp_path: Path, address: str) -> dict[str, list]:
    sweep = tmp_path / "s.json"
    sweep.write_text(json.dumps({"name": "s", "figure": "table", "episodes": 1, "judge": "conservative",
                                 "policies": ["policies/rarl-k2-conservative.safetensors"], "n_objects": [2],
                                 "selectors": ["full"]}))
    return {"eval": ["eval", "--policy", "rarl-k2-conservative", "--episodes", "1", "--backend", "ray", "--address",
                     address, "--out", tmp_path / "out"],
            "train": ["train", "--backend", "ray", "--address", address, "--out", tmp_path / "out", "--no-progress"],
            "sweep": ["sweep", sweep, "--backend", "ray", "--address", address, "--out", tmp_path / "out"]}


# ------------------------------------------------------------------------------------------ 6. secrets


def _echoing_answer(req: dict) -> dict:
    """A model that repeats the key (in upper case) in its explanation."""
    if "objects" in schema_of(req)["properties"]:
        return {**pick_last_k(req), "explanation": f"as told by {SECRET.upper()}"}
    labels = schema_of(req)["properties"]["constraints"]["required"]
    return {"constraints": {lbl: {"explanation": f"key {SECRET.upper()}", "constraint": "no_contact"} for lbl in labels}}


# ------------------------------------------------------------------------------------------ 7. workers
def _descendants(pid: int) -> set[int]:
    from test_processes import descendants

    return descendants(pid)


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def _journal_seeds(folder: Path) -> set[int]:
    seeds = set()
    for journal in folder.glob("safemanip-eval-*/worker-*.jsonl"):
        for line in journal.read_text().splitlines():
            try:
                seeds.add(json.loads(line)["seed"])
            except ValueError:
                pass
    return seeds



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
import shutil
import signal
import socket
import subprocess
import threading
import time
from pathlib import Path

import pytest

from safemanip.semantics import BackendError, ConstraintQuery, ObjectQuery, ResponseCache
from safemanip.semantics.guard import GuardedBackend
from safemanip.semantics.openai_backend import OpenAIBackend
from safemanip.semantics.selectors import DynamicVLMSelector, VLMConstraintSelector, dynamic_knn
from conftest import (SAFEMANIP, SUBPROCESS_ENV, TINY_TRAIN, VLM_NAMES, FakeServer, assert_refused, cmdline, completion,
                      descendants, json_reply, make_policy, pick_last_k, process_name, run_cli, schema_of, vlm_view)

SECRET = "sk-test-Secret-0123456789abcdef"


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
@pytest.mark.parametrize("mode", ["body", "headers"])
def test_vlm_timeout_bounds_the_whole_request_against_a_dripping_server(mode):
    with DripServer(mode) as server:
        backend = OpenAIBackend(model="m", base_url=server.base_url, timeout_s=2.0, attempts=1)
        start = time.monotonic()
        with pytest.raises(BackendError, match="no complete answer within 2.0 s"):
            backend.assign_constraints(ConstraintQuery(names=VLM_NAMES))
        elapsed = time.monotonic() - start
    assert elapsed < 10, elapsed  # 2 s asked for; without a whole-request deadline: hours (100,000 bytes, 1 a second)


def test_classify_constraints_is_cut_off_by_vlm_timeout(capsys):
    with DripServer() as server:
        start = time.monotonic()
        err = assert_refused(capsys, ["classify-constraints", "--vlm-backend", "openai", "--vlm-base-url",
                                      server.base_url, "--vlm-timeout", "2", "--vlm-attempts", "2", "mug"],
                             "no complete answer within 2.0 s")
        elapsed = time.monotonic() - start
    assert "too slow" in err and elapsed < 20, elapsed


def test_the_episode_budget_bounds_a_query_not_only_the_next_one():
    with DripServer() as server:
        inner = OpenAIBackend(model="m", base_url=server.base_url, timeout_s=30.0, attempts=3, backoff_s=0.01)
        guard = GuardedBackend(inner, episode_budget_s=1.5)
        guard.new_episode()
        start = time.monotonic()
        with pytest.raises(BackendError):
            guard.assign_constraints(ConstraintQuery(names=VLM_NAMES))
        elapsed = time.monotonic() - start
        with pytest.raises(BackendError, match="episode time budget"):  # the next query is not even sent
            guard.assign_constraints(ConstraintQuery(names=VLM_NAMES))
    assert elapsed < 10, elapsed  # 1.5 s of budget; the 30 s timeout x 3 attempts would take 90 s


def test_eval_against_a_dripping_server_finishes_on_the_fallback(capsys, tmp_path):
    policy = make_policy(tmp_path / "k2.safetensors", 2)
    out = tmp_path / "ev"
    with DripServer() as server:
        start = time.monotonic()
        code, text, err = run_cli(capsys, ["eval", "--policy", policy, "--n-objects", "3", "--selector", "dynamic-vlm",
                                           "--vlm-backend", "openai", "--vlm-base-url", server.base_url, "--vlm-timeout",
                                           "2", "--vlm-max-failures", "1", "--max-episode-steps", "40", "--episodes", "1",
                                           "--workers", "1", "--no-progress", "--out", out])
        elapsed = time.monotonic() - start
    assert code == 0, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["vlm_breaker_open_episodes"] == 1 and summary["selector_queries"]["object_fallbacks"] >= 1
    assert elapsed < 90, elapsed


@pytest.mark.parametrize("body,message", [
    (json.dumps(completion("[" * 100_000 + "]" * 100_000)).encode(), "nests 100,000 levels deep"),
    (b'{"choices": ' + b"[" * 100_000 + b"]" * 100_000 + b"}", "nests 100,001 levels deep"),
    (b'{"choices": [{"message": {"content": "{}"}}], "x": NaN}', "NaN"),
    (b" " * 5_000_000, "more than the 4,000,000"),
], ids=["deep-answer", "deep-reply", "nan-reply", "huge-reply"])
def test_a_deep_or_huge_vlm_reply_falls_back_like_any_bad_answer(body, message, caplog):
    with FakeServer(lambda req: (200, body, "application/json")) as server:
        backend = OpenAIBackend(model="m", base_url=server.base_url, timeout_s=5.0, attempts=1)
        with pytest.raises(BackendError, match=message):
            backend.assign_constraints(ConstraintQuery(names=VLM_NAMES))
        selector = DynamicVLMSelector(backend, query_interval=4)
        v = vlm_view()
        selector.reset(v, 2)
        assert selector.select(v, 2) == dynamic_knn(v, 2) and selector.stats.fallbacks == 1
        assert VLMConstraintSelector(backend).assign(v) == ["no_contact"] * len(VLM_NAMES)


def test_a_cache_entry_nested_deep_is_a_miss(tmp_path):
    def answer_for(req):
        labels = schema_of(req)["properties"]["constraints"]["required"]
        return {"constraints": {lbl: {"explanation": "x", "constraint": "no_contact"} for lbl in labels}}

    with FakeServer(json_reply(answer_for)) as server:
        backend = OpenAIBackend(model="m", base_url=server.base_url, timeout_s=5.0, cache=ResponseCache(tmp_path))
        backend.assign_constraints(ConstraintQuery(names=VLM_NAMES))
        (entry,) = tmp_path.glob("??/*.json")
        entry.write_text("[" * 100_000 + "]" * 100_000)
        cache_only = OpenAIBackend(model="m", base_url=server.base_url, cache=ResponseCache(tmp_path, "cache_only"))
        with pytest.raises(BackendError, match="nests 100,000 levels deep"):
            cache_only.assign_constraints(ConstraintQuery(names=VLM_NAMES))
        sent = len(server.requests)
        backend.assign_constraints(ConstraintQuery(names=VLM_NAMES))  # readwrite: a miss, asked again and stored
        assert len(server.requests) == sent + 1 and len(json.loads(entry.read_text())["answer"]["constraints"]) == 3



# ------------------------------------------------------------------------------------------ 4. an unwritable VLM cache
def _can_write_into(folder: Path) -> bool:
    try:
        (folder / "probe").write_text("x")
    except OSError:
        return False
    (folder / "probe").unlink()
    return True


@pytest.fixture
def unwritable_cache(tmp_path, request):
    """A --vlm-cache folder no answer can be stored in, even by root: the path is a regular file, or lies under
    one; or a folder without write permission, made immutable (chattr +i) where permissions do not stop this
    user (root); skipped only where neither stops it."""
    def make(case: str) -> Path:
        blocker = tmp_path / "not-a-folder"
        blocker.write_text("a file")
        if case == "a-file":
            return blocker
        if case == "under-a-file":
            return blocker / "cache"
        folder = tmp_path / "read-only"
        folder.mkdir()
        folder.chmod(0o555)
        request.addfinalizer(lambda: folder.chmod(0o755))
        if _can_write_into(folder) and shutil.which("chattr"):
            if subprocess.run(["chattr", "+i", str(folder)], capture_output=True).returncode == 0:
                request.addfinalizer(lambda: subprocess.run(["chattr", "-i", str(folder)], capture_output=True))
        if _can_write_into(folder):
            pytest.skip("this user can write into a read-only folder and cannot make one immutable here")
        return folder
    return make


def _constraints_for(req):
    labels = schema_of(req)["properties"]["constraints"]["required"]
    return {"constraints": {lbl: {"explanation": "x", "constraint": "soft_contact"} for lbl in labels}}


UNWRITABLE = ["a-file", "under-a-file", "read-only"]


@pytest.mark.parametrize("case", UNWRITABLE)
def test_classify_constraints_refuses_an_unwritable_vlm_cache_before_any_request(capsys, unwritable_cache, case):
    """It used to ask the server, then crash with an OSError when storing the answer (issue 44)."""
    cache = unwritable_cache(case)
    with FakeServer(json_reply(_constraints_for)) as server:
        err = assert_refused(capsys, ["classify-constraints", "--vlm-backend", "openai", "--vlm-base-url",
                                      server.base_url, "--vlm-cache", cache, "red mug"], "--vlm-cache")
    assert len(err.strip().splitlines()) == 1 and str(cache) in err
    assert server.requests == []  # refused up front: no answer was asked for and then lost
    # replaying stored answers only reads the folder: --vlm-cache-only is not refused for it
    code, _, err = run_cli(capsys, ["classify-constraints", "--vlm-backend", "openai", "--vlm-cache", cache,
                                    "--vlm-cache-only", "red mug"])
    assert code == 2 and "cache miss" in err


@pytest.mark.parametrize("case", UNWRITABLE)
@pytest.mark.parametrize("command", ["eval", "sweep"])
def test_eval_and_sweep_refuse_an_unwritable_vlm_cache_before_any_episode(capsys, tmp_path, unwritable_cache, case,
                                                                         command):
    cache = unwritable_cache(case)
    out = tmp_path / "out"
    vlm = ["--vlm-backend", "openai", "--vlm-base-url", "http://127.0.0.1:9/v1", "--vlm-cache", cache]
    if command == "eval":
        argv = ["eval", "--policy", make_policy(tmp_path / "k2.safetensors", 2), "--n-objects", "3", "--selector",
                "dynamic-vlm", "--episodes", "1", "--workers", "1", "--no-progress", "--out", out, *vlm]
    else:
        spec = tmp_path / "s.json"
        spec.write_text(json.dumps({"name": "s", "figure": "table", "episodes": 1, "judge": "conservative",
                                    "policies": ["policies/rarl-k2-conservative-s0.safetensors"], "n_objects": [3],
                                    "selectors": ["dynamic-vlm"]}))
        argv = ["sweep", spec, "--workers", "1", "--no-progress", "--out", out, *vlm]
    assert_refused(capsys, argv, "--vlm-cache")
    assert not out.exists()


def test_a_cache_write_that_fails_after_the_answer_warns_and_goes_on(tmp_path):
    """The folder was writable when the command started and is not when the answer comes (replaced by a file
    here; a full disk or a changed mount alike): the answer is printed, a warning says nothing is cached. A real
    process, so that the warning is seen as a user sees it on stderr."""
    cache = tmp_path / "cache"
    cache.mkdir()

    def answer(req):
        if cache.is_dir():
            cache.rmdir()
            cache.write_text("in the way")
        return _constraints_for(req)

    with FakeServer(json_reply(answer)) as server:
        done = subprocess.run([*SAFEMANIP, "classify-constraints", "--vlm-backend", "openai",
                               "--vlm-base-url", server.base_url, "--vlm-cache", str(cache), "red mug", "toy sheep"],
                              capture_output=True, text=True, timeout=120, env=SUBPROCESS_ENV)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout == "red mug\tsoft_contact\ntoy sheep\tsoft_contact\n" and len(server.requests) == 1
    assert "Traceback" not in done.stderr
    (warning,) = done.stderr.strip().splitlines()
    assert "going on without caching" in warning and str(cache) in warning


def test_a_cache_that_cannot_store_warns_once_and_every_query_is_still_answered(caplog, tmp_path):
    cache = ResponseCache(tmp_path / "file" / "cache")  # the API does not check the folder: every store fails
    (tmp_path / "file").write_text("in the way")
    with FakeServer(json_reply(_constraints_for)) as server:
        backend = OpenAIBackend(model="m", base_url=server.base_url, timeout_s=5.0, cache=cache)
        for names in (VLM_NAMES, VLM_NAMES[:2]):
            got = backend.assign_constraints(ConstraintQuery(names=names))
            assert got.constraints == ["soft_contact"] * len(names)
    warnings = [r for r in caplog.records if "going on without caching" in r.getMessage()]
    assert len(warnings) == 1 and len(server.requests) == 2 and cache.count() == 0


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
                                 "policies": ["policies/rarl-k2-conservative-s0.safetensors"], "n_objects": [2],
                                 "selectors": ["full"]}))
    return {"eval": ["eval", "--policy", "rarl-k2-conservative-s0", "--episodes", "1", "--backend", "ray", "--address",
                     address, "--out", tmp_path / "out"],
            "train": ["train", "--backend", "ray", "--address", address, "--out", tmp_path / "out", "--no-progress"],
            "sweep": ["sweep", sweep, "--backend", "ray", "--address", address, "--out", tmp_path / "out"]}


@pytest.mark.parametrize("command", ["eval", "train", "sweep"])
def test_a_closed_ray_address_fails_within_seconds(capsys, tmp_path, command):
    address = f"127.0.0.1:{_closed_port()}"
    start = time.monotonic()
    assert_refused(capsys, _ray_commands(tmp_path, address)[command],
                   f"--address {address}: cannot reach a Ray cluster there")
    assert time.monotonic() - start < 20 and not (tmp_path / "out").exists()


def test_a_port_that_never_answers_is_not_taken_for_a_ray_cluster(capsys, tmp_path):
    with SilentPort() as port:
        start = time.monotonic()
        assert_refused(capsys, _ray_commands(tmp_path, port.address)["eval"], "no Ray cluster answered within 5 s")
        elapsed = time.monotonic() - start
    assert elapsed < 20 and not (tmp_path / "out").exists()  # ray.init alone waits minutes here


def test_a_port_of_another_service_is_not_a_ray_cluster(capsys, tmp_path):
    with FakeServer(json_reply(pick_last_k)) as server:  # an HTTP/1 server: no gRPC
        address = server.base_url.split("//")[1].split("/")[0]
        assert_refused(capsys, _ray_commands(tmp_path, address)["train"], "is not a Ray cluster (it does not speak gRPC)")


@pytest.mark.parametrize("address", ["nohost", "host:port", "10.0.0.1:99999", "a b:1", "http://x:1/y"])
def test_a_malformed_ray_address_is_refused(capsys, tmp_path, address):
    assert_refused(capsys, _ray_commands(tmp_path, address)["eval"], "is not a Ray cluster address")


def test_ray_address_from_the_environment_is_checked_too(capsys, monkeypatch, tmp_path):
    monkeypatch.setenv("RAY_ADDRESS", f"127.0.0.1:{_closed_port()}")
    argv = [a for a in _ray_commands(tmp_path, "x")["eval"] if a not in ("--address", "x")]
    assert_refused(capsys, argv, "RAY_ADDRESS 127.0.0.1:")


# ------------------------------------------------------------------------------------------ 6. secrets
@pytest.mark.parametrize("text", [
    f"echo: {SECRET.upper()}", f"echo: {SECRET.lower()}", f"API-KEY: {SECRET}", f"apiKey={SECRET}",
    f'"X-Api-Key": "{SECRET}"', f"Openai_Api_Key={SECRET}", f"api key: {SECRET}", f"AUTHORIZATION: BEARER {SECRET}",
    f"https://bob:{SECRET}@example.org/v1",
])
def test_the_key_is_redacted_in_any_case_variant(monkeypatch, text):
    from safemanip.util.secrets import redact

    monkeypatch.setenv("OPENAI_API_KEY", SECRET)
    out = redact(text)
    assert SECRET.lower() not in out.lower() and "[redacted]" in out


def test_the_key_under_another_spelling_of_its_variable_is_redacted(monkeypatch):
    from safemanip.util.secrets import redact

    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    monkeypatch.setenv("openai_api_key", "plainword-42")
    assert redact("the server said PLAINWORD-42") == "the server said [redacted]"


def test_a_key_echoed_in_another_case_never_reaches_the_message(monkeypatch):
    monkeypatch.setenv("OPENAI_API_KEY", SECRET)
    body = json.dumps({"error": {"message": f"bad key {SECRET.upper()} / {SECRET.lower()}"}}).encode()
    with FakeServer(lambda req: (400, body, "application/json")) as server:
        with pytest.raises(BackendError) as err:
            OpenAIBackend(model="m", base_url=server.base_url, attempts=1).assign_constraints(ConstraintQuery(names=VLM_NAMES))
    assert "HTTP 400" in str(err.value) and SECRET.lower() not in str(err.value).lower()


def _echoing_answer(req: dict) -> dict:
    """A model that repeats the key (in upper case) in its explanation."""
    if "objects" in schema_of(req)["properties"]:
        return {**pick_last_k(req), "explanation": f"as told by {SECRET.upper()}"}
    labels = schema_of(req)["properties"]["constraints"]["required"]
    return {"constraints": {lbl: {"explanation": f"key {SECRET.upper()}", "constraint": "no_contact"} for lbl in labels}}


def test_the_key_is_never_stored_in_the_vlm_cache(monkeypatch, tmp_path):
    monkeypatch.setenv("OPENAI_API_KEY", SECRET)
    with FakeServer(json_reply(_echoing_answer)) as server:
        backend = OpenAIBackend(model="m", base_url=server.base_url, cache=ResponseCache(tmp_path))
        got = backend.assign_constraints(ConstraintQuery(names=VLM_NAMES))
        answer = backend.select_objects(ObjectQuery(view=vlm_view(), k=2, order=[0, 1, 2]))
    stored = "".join(p.read_text() for p in tmp_path.rglob("*.json"))
    assert stored and SECRET.lower() not in stored.lower() and "[redacted]" in stored
    assert SECRET.lower() not in (json.dumps(got.raw) + answer.explanation).lower()


def test_credentials_in_the_base_url_are_masked_in_every_message(capsys, monkeypatch):
    monkeypatch.setenv("OPENAI_API_KEY", SECRET)
    url = f"http://alice:hunter2@127.0.0.1:{_closed_port()}/v1"
    code, out, err = run_cli(capsys, ["classify-constraints", "--vlm-backend", "openai", "--vlm-base-url", url,
                                      "--vlm-attempts", "1", "--vlm-timeout", "2", "mug"])
    assert code == 2 and "cannot reach http://[redacted]@127.0.0.1" in err
    assert "hunter2" not in out + err and "alice" not in out + err
    backend = OpenAIBackend(model="m", base_url=url)
    assert "hunter2" not in repr(backend) + json.dumps(backend.describe())


def test_eval_results_never_hold_url_credentials(capsys, tmp_path):
    policy = make_policy(tmp_path / "k2.safetensors", 2)
    out = tmp_path / "ev"
    url = f"http://alice:hunter2@127.0.0.1:{_closed_port()}/v1"
    code, text, err = run_cli(capsys, ["eval", "--policy", policy, "--n-objects", "3", "--selector", "dynamic-vlm",
                                       "--vlm-backend", "openai", "--vlm-base-url", url, "--vlm-timeout", "2",
                                       "--vlm-max-failures", "1", "--max-episode-steps", "20", "--episodes", "1",
                                       "--workers", "1", "--no-progress", "--json", "--out", out])
    assert code == 0, err
    written = (out / "summary.json").read_text()
    assert "hunter2" not in written + text + err and "[redacted]@127.0.0.1" in written


def test_render_query_output_holds_no_key_and_no_url_credentials(capsys, monkeypatch, tmp_path, gl):
    monkeypatch.setenv("OPENAI_API_KEY", SECRET)
    with FakeServer(json_reply(_echoing_answer)) as server:
        url = server.base_url.replace("http://", "http://alice:hunter2@")
        code, out, err = run_cli(capsys, ["render-query", "--seed", "4", "--steps", "4", "--vlm-backend", "openai",
                                          "--vlm-base-url", url, "--vlm-model", "m", "--out", tmp_path / "q"])
    assert code == 0, err
    files = "".join(p.read_text() for p in (tmp_path / "q").glob("*.*") if p.suffix in (".json", ".txt"))
    everything = (out + err + files).lower()
    assert SECRET.lower() not in everything and "hunter2" not in everything
    assert "[redacted]" in files  # the echoed key and the URL's credentials were there, and are masked


# ------------------------------------------------------------------------------------------ 7. workers
def _journal_seeds(folder: Path) -> set[int]:
    seeds = set()
    for journal in folder.glob("safemanip-eval-*/worker-*.jsonl"):
        for line in journal.read_text().splitlines():
            try:
                seeds.add(json.loads(line)["seed"])
            except ValueError:
                pass
    return seeds


@pytest.mark.slow
def test_a_killed_eval_worker_loses_no_finished_episode(tmp_path):
    """Two workers, one chunk of 200 episodes each; one is killed -9 after it finished some episodes of its chunk.
    Every episode finished before the kill is written, the run says which seeds failed and exits with 1."""
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    out = tmp_path / "ev"
    proc = subprocess.Popen([*SAFEMANIP, "eval", "--policy", "rarl-k2-conservative-s0",
                             "--episodes", "400", "--workers", "2", "--chunk-size", "200", "--no-progress", "--out", out],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path,
                            env={**SUBPROCESS_ENV, "TMPDIR": str(scratch)}, start_new_session=True)
    try:
        deadline, victim = time.time() + 240, None
        while time.time() < deadline and victim is None:
            for journal in scratch.glob("safemanip-eval-*/worker-*.jsonl"):
                if journal.read_text().count("\n") >= 3:
                    victim = int(journal.stem.split("-")[1])
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.2)
        assert victim is not None, "no worker finished three episodes within 240 s"
        finished = _journal_seeds(scratch)
        os.kill(victim, signal.SIGKILL)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 1, stderr[-2000:]
    assert "Traceback" not in stderr and "error: a worker process was killed by SIGKILL" in stderr
    with open(out / "episodes.csv", newline="") as f:
        written = {int(r["seed"]) for r in csv.DictReader(f)}
    summary = json.loads((out / "summary.json").read_text())
    assert finished <= written  # the victim's own finished episodes too: its chunk never returned
    assert summary["episodes"] == len(written) < 400
    assert sorted(summary["failed"]["seeds_failed"]) == sorted(set(range(400)) - written)
    assert "rerun the evaluation" in stderr and not list(scratch.glob("safemanip-eval-*"))


@pytest.mark.slow
def test_a_killed_rollout_worker_ends_train_with_one_line_and_the_resume_command(tmp_path):
    from safemanip.rl.checkpoint import find_checkpoint

    cfg = tmp_path / "tiny.json"
    cfg.write_text(json.dumps({**TINY_TRAIN, "minutes": 2.0, "total_env_steps": 10**7}))
    run_dir = tmp_path / "run"
    proc = subprocess.Popen([*SAFEMANIP, "train", "--config", cfg, "--out", run_dir,
                             "--no-progress"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path,
                            env=SUBPROCESS_ENV, start_new_session=True)
    try:
        deadline, worker = time.time() + 120, None
        while time.time() < deadline and worker is None:
            assert proc.poll() is None, proc.communicate()
            if (run_dir / "scalars.csv").exists():  # the training loop runs
                # the run's two spawned children: the evaluation process (once it has named itself) and the
                # rollout worker, the one to kill
                spawned = [p for p in descendants(proc.pid) if "spawn_main" in cmdline(p)]
                named = [p for p in spawned if process_name(p) == "safemanip-eval"]
                workers = [p for p in spawned if p not in named]
                worker = workers[0] if workers and named else None
            time.sleep(0.2)
        assert worker is not None, "no rollout worker within 120 s"
        os.kill(worker, signal.SIGKILL)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 1, stdout[-2000:] + stderr[-2000:]
    errors = [line for line in stderr.splitlines() if line.startswith("safemanip train: error:")]
    assert len(errors) == 1, stderr[-2000:]
    assert errors[0].startswith("safemanip train: error: a rollout worker was killed by SIGKILL; the run stopped after ")
    assert errors[0].endswith(f"continue with: safemanip train --resume {run_dir}")
    assert "Traceback" not in stdout + stderr
    assert find_checkpoint(run_dir) is not None and (run_dir / "policy.safetensors").exists()
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["worker_failed"] == "a rollout worker was killed by SIGKILL"

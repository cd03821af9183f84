"""The openai backend under faults: a key echoed by the server never reaches a message, a failing or slow
server trips the circuit breaker or the time budgets (and the results say so), and cached answers recorded
under another prompt or schema version are not used."""

from __future__ import annotations

import json

import pytest

from safemanip.semantics import BackendError, ConstraintQuery, ResponseCache
from safemanip.semantics.guard import GuardedBackend
from safemanip.semantics.openai_backend import OpenAIBackend, redact
from conftest import VLM_NAMES, FakeServer, backend_for, json_reply, make_policy, schema_of, vlm_view

SECRET = "sk-test-SECRET-0123456789abcdef"


class EchoAuth(FakeServer):
    """Answers HTTP 400 with the request's Authorization header in the error body (as some proxies do)."""

    def __init__(self):
        super().__init__(lambda req: (400, b"", "application/json"))
        outer = self
        self.reply = lambda req: (400, json.dumps({"error": {"message": "bad request from " + auth(outer.headers[-1]),
                                                             "type": "invalid_request_error"}}).encode(),
                                  "application/json")


def auth(headers: dict) -> str:
    return next(v for k, v in headers.items() if k.lower() == "authorization")


def test_the_api_key_echoed_by_the_server_is_redacted(monkeypatch, caplog, capsys):
    monkeypatch.setenv("OPENAI_API_KEY", SECRET)
    with EchoAuth() as server:
        backend = backend_for(server)
        with pytest.raises(BackendError) as err:
            backend.assign_constraints(ConstraintQuery(names=VLM_NAMES))
    assert server.headers and SECRET in auth(server.headers[-1])  # the server did see the key and echoed it
    text = str(err.value) + caplog.text + "".join(capsys.readouterr())
    assert "HTTP 400" in str(err.value) and "[redacted]" in str(err.value)
    assert SECRET not in text and SECRET[:12] not in text


def test_cli_never_prints_the_key(monkeypatch, capsys):
    from safemanip.cli import main

    monkeypatch.setenv("OPENAI_API_KEY", SECRET)
    with EchoAuth() as server:
        code = main(["classify-constraints", "--vlm-backend", "openai", "--vlm-base-url", server.base_url, "mug"])
    out, err = capsys.readouterr()
    assert code == 2 and "error:" in err and SECRET not in out + err


@pytest.mark.parametrize("text", [f"Authorization: Bearer {SECRET}", f'{{"api_key": "{SECRET}"}}', f"key={SECRET}",
                                  "Bearer abc.def-123"])
def test_redact_removes_credentials(monkeypatch, text):
    monkeypatch.setenv("OPENAI_API_KEY", SECRET)
    out = redact(text)
    assert SECRET not in out and "[redacted]" in out and "abc.def-123" not in out


class Failing:
    name = "failing"
    needs_images = False

    def __init__(self, seconds=0.0, clock=None):
        self.calls, self.seconds, self.clock = 0, seconds, clock

    def describe(self):
        return {"backend": "failing"}

    def prepare(self, names):
        pass

    def assign_constraints(self, query):
        self.calls += 1
        if self.clock is not None:
            self.clock.now += self.seconds
        raise BackendError("server down")

    select_objects = assign_constraints


class Clock:
    now = 0.0

    def __call__(self):
        return self.now


def test_circuit_breaker_opens_after_repeated_failures_and_stays_open():
    inner = Failing()
    guard = GuardedBackend(inner, max_failures=3)
    for _ in range(3):
        with pytest.raises(BackendError, match="server down"):
            guard.assign_constraints(ConstraintQuery(names=VLM_NAMES))
    for _ in range(5):
        with pytest.raises(BackendError, match="circuit breaker open"):
            guard.assign_constraints(ConstraintQuery(names=VLM_NAMES))
    assert inner.calls == 3 and guard.status()["breaker_open"]
    assert "3 consecutive failed queries" in guard.status()["reason"]


def test_episode_and_run_budgets():
    clock = Clock()
    inner = Failing(seconds=4.0, clock=clock)
    guard = GuardedBackend(inner, max_failures=100, episode_budget_s=10.0, run_budget_s=25.0, clock=clock)
    for episode in range(3):
        guard.new_episode()
        for _ in range(5):
            with pytest.raises(BackendError):
                guard.assign_constraints(ConstraintQuery(names=VLM_NAMES))
    # 3 calls (12 s) fit the first episode's 10 s budget, 3 the second's, then the run's 25 s are used up
    assert inner.calls == 7 and guard.status()["breaker_open"] and "run time budget" in guard.status()["reason"]


def test_selectors_fall_back_when_the_breaker_is_open():
    from safemanip.semantics.selectors import VLMConstraintSelector

    sel = VLMConstraintSelector(GuardedBackend(Failing(), max_failures=1))
    for _ in range(3):
        sel.reset()
        assert sel.assign(vlm_view()) == ["no_contact"] * len(VLM_NAMES)
    assert sel.stats.fallbacks == 3 and sel.backend.inner.calls == 1


def test_eval_records_the_open_breaker(capsys, tmp_path):
    """A dead server: eval still finishes, every query falls back, and the results say the breaker opened."""
    from safemanip.cli import main

    out = tmp_path / "ev"
    policy = make_policy(tmp_path / "k2-all.safetensors", 2, constraints="all")
    code = main(["eval", "--policy", policy, "--semantics", "1 fragile, 1 soft, 1 durable", "--selector",
                 "dynamic-vlm", "--constraint-selector", "vlm", "--vlm-backend", "openai", "--vlm-base-url",
                 "http://127.0.0.1:9/v1", "--vlm-timeout", "0.5", "--vlm-max-failures", "2", "--episodes", "2",
                 "--workers", "1", "--no-progress", "--out", str(out)])
    text = capsys.readouterr().out
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["vlm_breaker_open_episodes"] == 2 and "circuit breaker open" in text
    assert summary["request"]["vlm_max_failures"] == 2


def test_cache_entries_of_another_prompt_or_schema_version_are_not_used(tmp_path):
    def answer(req):
        labels = schema_of(req)["properties"]["constraints"]["required"]
        return {"constraints": {label: {"explanation": "x", "constraint": "no_contact"} for label in labels}}

    with FakeServer(json_reply(answer)) as server:
        cache = ResponseCache(tmp_path)
        first = backend_for(server, cache=cache)
        first.assign_constraints(ConstraintQuery(names=VLM_NAMES))
        sent = len(server.requests)
        backend_for(server, cache=ResponseCache(tmp_path)).assign_constraints(ConstraintQuery(names=VLM_NAMES))
        assert len(server.requests) == sent  # same versions: a cache hit
        (entry,) = list(tmp_path.glob("??/*.json"))
        stored = json.loads(entry.read_text())
        stored["meta"]["schema_version"] = "0"
        entry.write_text(json.dumps(stored))
        backend_for(server, cache=ResponseCache(tmp_path)).assign_constraints(ConstraintQuery(names=VLM_NAMES))
        assert len(server.requests) == sent + 1  # recorded under another schema version: asked again
        with pytest.raises(BackendError, match="schema_version"):
            stored["meta"]["schema_version"] = "0"
            entry.write_text(json.dumps(stored))
            backend_for(server, cache=ResponseCache(tmp_path, mode="cache_only")).assign_constraints(
                ConstraintQuery(names=VLM_NAMES))


def test_sweep_takes_the_vlm_limits_and_records_the_open_breaker(capsys, tmp_path):
    """The same flags on sweep: they reach the cells that query the backend (and only those)."""
    from safemanip.cli import main

    policy = make_policy(tmp_path / "rarl-k2-all.safetensors", 2, constraints="all")
    cfg = {"name": "mini-vlm", "title": "mini", "figure": "fig5", "episodes": 2, "seed": 0, "judge": "ground-truth",
           "policies": [policy], "n_objects": [3], "semantics": ["1 fragile, 1 soft, 1 durable"],
           "pairs": [["dynamic-vlm", "vlm"], ["dynamic-knn", "ground-truth"]],
           "table": {"rows": ["k"], "columns": ["n_objects", "selector"]}}
    path = tmp_path / "mini.json"
    path.write_text(json.dumps(cfg))
    out = tmp_path / "sw"
    code = main(["sweep", str(path), "--out", str(out), "--vlm-backend", "openai", "--vlm-base-url",
                 "http://127.0.0.1:9/v1", "--vlm-timeout", "0.5", "--vlm-max-failures", "2", "--workers", "1",
                 "--no-progress"])
    capsys.readouterr()
    assert code == 0
    stored = {p.name: json.loads(p.read_text()) for p in (out / "cells").glob("*.json")}
    vlm_cell = next(v for k, v in stored.items() if "dynamic-vlm" in k)
    plain = next(v for k, v in stored.items() if "dynamic-knn" in k)
    assert vlm_cell["cell"]["vlm"] == "openai:gpt-4o" and plain["cell"]["vlm"] is None
    assert vlm_cell["summary"]["vlm_breaker_open_episodes"] == 2


@pytest.mark.parametrize("extra, message", [
    (["--vlm-timeout", "5"], "apply to --vlm-backend openai"),
    (["--vlm-backend", "openai", "--vlm-timeout", "nan"], "--vlm-timeout"),
    (["--vlm-backend", "openai", "--vlm-cache-only"], "--vlm-cache-only needs --vlm-cache"),
])
def test_sweep_refuses_bad_vlm_options_before_any_cell(capsys, tmp_path, extra, message):
    from safemanip.cli import main

    out = tmp_path / "sw"
    code = main(["sweep", "table2", "--episodes", "1", "--out", str(out), "--no-progress", *extra])
    err = capsys.readouterr().err
    assert code == 2 and message in err and not out.exists()


def test_sweep_refuses_vlm_options_when_no_cell_queries_the_backend(capsys, tmp_path):
    from safemanip.cli import main

    code = main(["sweep", "fig5", "--out", str(tmp_path / "sw"), "--vlm-backend", "openai", "--no-progress"])
    assert code == 2 and "no cell that queries the semantic backend" in capsys.readouterr().err

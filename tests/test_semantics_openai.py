"""Protocol tests: OpenAIBackend against a local chat-completions server on 127.0.0.1.

The server is a plain http.server in a thread (``conftest.FakeServer``, shared with the other openai tests); each
test scripts how it answers (structured answer, HTTP 500, garbage, or hanging past the client's timeout).
"""

from __future__ import annotations

import base64
import json
import logging
import threading
from typing import Callable

import pytest

from safemanip.semantics import BackendError, ConstraintQuery, ObjectQuery, ResponseCache
from safemanip.semantics.openai_backend import OpenAIBackend
from safemanip.semantics.selectors import DynamicVLMSelector, VLMConstraintSelector, dynamic_knn
from conftest import VLM_NAMES, FakeServer, backend_for, completion, json_reply, pick_last_k, schema_of, vlm_view

pytestmark = pytest.mark.protocol


def test_object_selection_round_trip_sends_schema_images_and_sorted_labels():
    png = b"\x89PNG fake bytes"
    with FakeServer(json_reply(pick_last_k)) as server:
        backend = backend_for(server)
        v = vlm_view()
        answer = backend.select_objects(ObjectQuery(view=v, k=2, order=[2, 0, 1], images=[png]))
    assert answer.ids == [0, 1]  # labels[-2:] of the order [2, 0, 1]
    assert answer.image_description.startswith("two frames")
    (req,) = server.requests
    assert req["path"] == "/v1/chat/completions"
    assert req["model"] == "test-model"
    rf = req["response_format"]
    assert rf["type"] == "json_schema" and rf["json_schema"]["strict"] is True
    assert schema_of(req)["properties"]["objects"]["items"]["enum"] == ["2: soda can", "0: red mug", "1: toy sheep"]
    assert req["messages"][0]["role"] == "system" and "black" in req["messages"][0]["content"]
    parts = req["messages"][1]["content"]
    text = parts[0]["text"]
    assert text.index("position 0: 2: soda can") < text.index("position 1: 0: red mug")
    url = parts[1]["image_url"]["url"]
    assert url.startswith("data:image/png;base64,") and base64.b64decode(url.split(",", 1)[1]) == png


def test_constraint_round_trip_and_api_key_not_leaked(monkeypatch, caplog):
    monkeypatch.setenv("OPENAI_API_KEY", "sk-test-secret-123")
    kinds = {"red mug": "no_contact", "toy sheep": "any_contact", "soda can": "soft_contact"}

    def answer(req):
        labels = schema_of(req)["properties"]["constraints"]["required"]
        return {"constraints": {lbl: {"explanation": "because", "constraint": kinds[lbl.split(": ", 1)[1]]}
                                for lbl in labels}}

    with FakeServer(json_reply(answer)) as server, caplog.at_level(logging.DEBUG):
        backend = backend_for(server)
        got = backend.assign_constraints(ConstraintQuery(names=VLM_NAMES))
    assert got.constraints == ["no_contact", "any_contact", "soft_contact"]
    auth = {k.lower(): v for k, v in server.headers[0].items()}.get("authorization")
    assert auth == "Bearer sk-test-secret-123", sorted(server.headers[0])
    assert "sk-test-secret" not in caplog.text + repr(backend) + json.dumps(backend.describe())


def test_cache_round_trip_then_cache_only_serves_without_server(tmp_path):
    with FakeServer(json_reply(pick_last_k)) as server:
        backend = backend_for(server, cache=ResponseCache(tmp_path))
        q = ObjectQuery(view=vlm_view(), k=2, order=[0, 1, 2])
        first = backend.select_objects(q)
        second = backend.select_objects(q)
    assert len(server.requests) == 1 and not first.cached and second.cached and first.ids == second.ids
    # server gone: a cache_only backend still answers the recorded query and refuses new ones
    offline = OpenAIBackend(model="test-model", base_url="http://127.0.0.1:9/v1",
                            cache=ResponseCache(tmp_path, mode="cache_only"))
    assert offline.select_objects(q).ids == first.ids
    with pytest.raises(BackendError, match="cache miss"):
        offline.select_objects(ObjectQuery(view=vlm_view(), k=1, order=[0, 1, 2]))
    assert offline.calls == 0


def test_retry_after_500_then_success():
    state = {"n": 0}

    def reply(req):
        state["n"] += 1
        if state["n"] == 1:
            return 500, b'{"error": {"message": "boom"}}', "application/json"
        return json_reply(pick_last_k)(req)

    with FakeServer(reply) as server:
        answer = backend_for(server, attempts=3).select_objects(ObjectQuery(view=vlm_view(), k=1, order=[0, 1, 2]))
    assert answer.ids == [2] and len(server.requests) == 2


def test_out_of_schema_answer_is_retried_then_rejected():
    bad = {"image_description": "", "explanation": "", "objects": ["9: piano"]}
    with FakeServer(json_reply(lambda req: bad)) as server:
        with pytest.raises(BackendError, match="piano"):
            backend_for(server, attempts=2).select_objects(ObjectQuery(view=vlm_view(), k=1, order=[0, 1, 2]))
    assert len(server.requests) == 2


@pytest.mark.parametrize("reply", [
    lambda req: (500, b"internal error", "text/plain"),
    lambda req: (200, b"this is not json at all", "application/json"),
    lambda req: (200, json.dumps(completion("not json either")).encode(), "application/json"),
], ids=["http500", "garbage-body", "garbage-content"])
def test_server_failures_fall_back_and_are_counted(reply):
    with FakeServer(reply) as server:
        selector = DynamicVLMSelector(backend_for(server, attempts=2), query_interval=4)
        v = vlm_view()
        selector.reset(v, 2)
        ids = selector.select(v, 2)
        assert ids == dynamic_knn(v, 2)
        cons = VLMConstraintSelector(backend_for(server, attempts=1))
        assert cons.assign(v) == ["no_contact"] * 3
    assert selector.stats.queries == 1 and selector.stats.fallbacks == 1
    assert cons.stats.fallbacks == 1


def test_hanging_server_hits_timeout_and_falls_back():
    release = threading.Event()

    def hang(req):
        release.wait(3.0)  # longer than the client's timeout
        return json_reply(pick_last_k)(req)

    with FakeServer(hang) as server:
        backend = backend_for(server, timeout_s=0.3, attempts=2)
        selector = DynamicVLMSelector(backend)
        v = vlm_view()
        selector.reset(v, 1)
        ids = selector.select(v, 1)
        release.set()
    # had either attempt waited for the server, it would have got a valid answer (after 3 s) and not fallen back
    assert ids == dynamic_knn(v, 1)
    assert selector.stats.fallbacks == 1 and backend.calls == 2


def test_http_401_is_not_retried_and_says_what_to_fix():
    with FakeServer(lambda req: (401, b'{"error": {"message": "bad key"}}', "application/json")) as server:
        backend = backend_for(server, attempts=3)
        with pytest.raises(BackendError, match="OPENAI_API_KEY"):
            backend.assign_constraints(ConstraintQuery(names=VLM_NAMES))
    assert len(server.requests) == 1


# ------------------------------------------------------------------ answers the way served models write them


def content_reply(content_for: Callable[[dict], str]) -> Callable[[dict], tuple[int, bytes, str]]:
    return lambda req: (200, json.dumps(completion(content_for(req))).encode(), "application/json")


@pytest.mark.parametrize("content, expected", [
    # prose around a fenced answer, objects by name and by bare id (a model without grammar-constrained decoding)
    ('Sure! Looking at the frames, the box moves right.\n```json\n{"objects": ["Soda Can", "1"], '
     '"explanation": "closest"}\n```\nLet me know if you need more.', [2, 1]),
    # the same object twice, then a third: repeats are one object
    ('{"image_description": "", "explanation": "", "objects": ["0: red mug", "0: red mug", "2: soda can"]}', [0, 2]),
    # ids as numbers and "object N (name)" forms
    ('{"objects": [2, "object 0 (red mug)"], "explanation": "x", "image_description": "y", "confidence": 0.9}', [2, 0]),
], ids=["prose-and-names", "duplicated-ids", "numbers-and-extra-keys"])
def test_answers_written_loosely_by_a_served_model_are_read_right(content, expected):
    with FakeServer(content_reply(lambda req: content)) as server:
        selector = DynamicVLMSelector(backend_for(server, attempts=1), query_interval=4)
        v = vlm_view()
        selector.reset(v, 2)
        assert selector.select(v, 2) == expected
    assert selector.stats.fallbacks == 0


@pytest.mark.parametrize("content", [
    '{"objects": ["red mugg", "toy sheep"]}',  # a misspelt name is not guessed
    '{"objects": ["toy sheep"]}',  # one object where two were asked for
    '{"objects": ["1: toy sheep", "1: toy sheep"]}',  # two entries, one object
    '{"objects": ["0: red mug", "1: toy sheep", "2: soda can"]}',  # three where two were asked for
    '{"objects": ["7", "1"]}',  # an id the scene does not have
    "I'm sorry, but I can't help with identifying objects in these images.",  # a refusal in prose
], ids=["misspelt", "partial", "duplicate-only", "too-many", "unknown-id", "prose-refusal"])
def test_answers_that_name_the_wrong_objects_fall_back_and_are_counted(content):
    with FakeServer(content_reply(lambda req: content)) as server:
        selector = DynamicVLMSelector(backend_for(server, attempts=2), query_interval=4)
        v = vlm_view()
        selector.reset(v, 2)
        assert selector.select(v, 2) == dynamic_knn(v, 2)
    assert selector.stats.fallbacks == 1 and len(server.requests) == 2  # retried once, then the fallback


def test_a_refusal_field_is_not_retried_and_falls_back():
    refusal = {"id": "x", "object": "chat.completion", "created": 0, "model": "m",
               "choices": [{"index": 0, "finish_reason": "stop",
                            "message": {"role": "assistant", "content": None, "refusal": "I can't assist with that."}}]}
    with FakeServer(lambda req: (200, json.dumps(refusal).encode(), "application/json")) as server:
        cons = VLMConstraintSelector(backend_for(server, attempts=3))
        assert cons.assign(vlm_view()) == ["no_contact"] * 3
    assert cons.stats.fallbacks == 1 and len(server.requests) == 1


def test_constraints_keyed_by_name_and_written_loosely_are_read_right():
    loose = ('Here are the constraints:\n{"constraints": {"Red mug": "No contact", '
             '"1": {"constraint": "any-contact"}, "soda can": {"constraint": "Soft_Contact", "explanation": "plastic"}}}')
    with FakeServer(content_reply(lambda req: loose)) as server:
        cons = VLMConstraintSelector(backend_for(server, attempts=1))
        assert cons.assign(vlm_view()) == ["no_contact", "any_contact", "soft_contact"]
        missing = '{"constraints": {"red mug": "no contact", "toy sheep": "any contact"}}'  # the can is left out
    with FakeServer(content_reply(lambda req: missing)) as server:
        cons = VLMConstraintSelector(backend_for(server, attempts=1))
        assert cons.assign(vlm_view()) == ["no_contact"] * 3 and cons.stats.fallbacks == 1

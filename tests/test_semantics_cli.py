"""The semantics sub-commands through ``safemanip.cli.main``: output format, exit codes, files written.

The semantic backend runs for real (the shipped model; one load per test process). The openai
backend is exercised against the local chat-completions server of the protocol tests.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from safemanip.cli import main
from safemanip.scene.catalog import CONSTRAINT_TYPES
from safemanip.semantics.semantic_backend import DEFAULT_EXAMPLES
from conftest import FakeServer, json_reply, run_cli, schema_of


def test_classify_constraints_prints_name_tab_constraint_for_any_names(capsys):
    code, out, err = run_cli(capsys, ["classify-constraints", "red mug", "toy sheep", "plastic water bottle",
                                      "a porcelain teacup with gold rim"])
    assert code == 0, err
    lines = [line.split("\t") for line in out.strip().splitlines()]
    assert [n for n, _ in lines] == ["red mug", "toy sheep", "plastic water bottle", "a porcelain teacup with gold rim"]
    assert [c for _, c in lines] == ["no_contact", "any_contact", "soft_contact", "no_contact"]
    assert "Loading weights" not in err


def test_v1_examples_selectable(capsys):
    code, out, _ = run_cli(capsys, ["classify-constraints", "--semantic-examples", "v1", "glass jar"])
    assert code == 0 and out == "glass jar\tsoft_contact\n"  # v1's known error; v2 says no_contact
    code, out, _ = run_cli(capsys, ["classify-constraints", "glass jar"])
    assert code == 0 and out == "glass jar\tno_contact\n"


@pytest.mark.parametrize("argv,message", [
    (["classify-constraints", " "], "at least one object name"),
    (["classify-constraints", "--semantic-examples", "v9", "mug"], "no class-example file"),
    (["classify-constraints", "--vlm-model", "gpt-4o", "mug"], "--vlm-backend openai only"),
    (["classify-constraints", "--vlm-backend", "openai", "mug"], "OPENAI_API_KEY"),
    (["classify-constraints", "--vlm-backend", "openai", "--vlm-cache-only", "mug"], "needs --vlm-cache"),
    (["constraint-matrix", "--trials", "0"], "argument --trials: must be in 1..100,000, got 0"),
    (["render-query", "--steps", "-1", "--vlm-backend", "none"], "argument --steps: must be in 0..10,000, got -1"),
    (["classify-constraints", "--backend", "openai", "mug"], "the semantic backend is chosen with --vlm-backend"),
])
def test_input_errors_exit_2_with_one_line(capsys, monkeypatch, argv, message):
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    code, out, err = run_cli(capsys, argv)
    assert code == 2 and message in err and "Traceback" not in err
    assert err.startswith(f"safemanip {argv[0]}: error:")


@pytest.mark.parametrize("argv", [["classify-constraints", "--vlm-backend", "gemini", "mug"], ["classify-constraints"]])
def test_argparse_errors_exit_2(capsys, argv):
    assert main(argv) == 2
    assert "error:" in capsys.readouterr().err


def test_openai_server_down_or_cache_miss_exit_2(capsys, tmp_path):
    code, _, err = run_cli(capsys, ["classify-constraints", "--vlm-backend", "openai", "--vlm-base-url", "http://127.0.0.1:9/v1",
                                    "--vlm-attempts", "1", "--vlm-timeout", "2", "mug"])
    assert code == 2 and "cannot reach" in err and "Traceback" not in err
    code, _, err = run_cli(capsys, ["classify-constraints", "--vlm-backend", "openai", "--vlm-cache", str(tmp_path),
                                    "--vlm-cache-only", "mug"])
    assert code == 2 and "cache miss" in err


@pytest.mark.protocol
def test_openai_classify_against_local_server_then_replay_from_cache(capsys, tmp_path):

    def answer(req):
        labels = schema_of(req)["properties"]["constraints"]["required"]
        return {"constraints": {lbl: {"explanation": "test", "constraint": "soft_contact"} for lbl in labels}}

    with FakeServer(json_reply(answer)) as server:
        code, out, err = run_cli(capsys, ["classify-constraints", "--vlm-backend", "openai", "--vlm-base-url", server.base_url,
                                          "--vlm-model", "test-model", "--vlm-cache", str(tmp_path), "red mug", "toy sheep"])
    assert code == 0, err
    assert out == "red mug\tsoft_contact\ntoy sheep\tsoft_contact\n" and len(server.requests) == 1
    code, out2, err = run_cli(capsys, ["classify-constraints", "--vlm-backend", "openai", "--vlm-model", "test-model",
                                       "--vlm-cache", str(tmp_path), "--vlm-cache-only", "red mug", "toy sheep"])
    assert code == 0 and out2 == out, err


def test_constraint_matrix_prints_both_tables_and_json(capsys, tmp_path):
    path = tmp_path / "m.json"
    code, out, err = run_cli(capsys, ["constraint-matrix", "--trials", "20", "--seed", "1", "--json", str(path)])
    assert code == 0, err
    assert "Table III" in out and "Table IV" in out and "no_contact (GT)" in out
    result = json.loads(path.read_text())
    assert result["trials"] == 20 and result["backend"]["examples_file"] == DEFAULT_EXAMPLES
    assert result["objects"] == "catalog"
    for row in result["table3"].values():
        assert abs(sum(row[c] for c in CONSTRAINT_TYPES) - 100.0) < 0.2
    code, out, err = run_cli(capsys, ["constraint-matrix", "--trials", "5", "--objects", "paper", "--objects-per-scene", "8"])
    assert code == 0 and "(paper set)" in out, err
    assert sum(1 for line in out.splitlines() if line.rstrip().endswith(" 5")) == 8  # 8 objects, 5 appearances each


def test_render_query_writes_annotated_pair_and_sorted_list(capsys, tmp_path, gl):
    code, out, err = run_cli(capsys, ["render-query", "--seed", "4", "--out", str(tmp_path), "--n-objects", "4",
                                      "--steps", "8", "--vlm-backend", "none"])
    assert code == 0, err
    meta = json.loads((tmp_path / "query_t008.json").read_text())
    assert meta["query_t"] == 8 and meta["frames_from_queries_at_t"] == [4, 8]
    image = np.asarray(Image.open(tmp_path / "query_t008.png"))
    h, w = 480, 640  # the env's render size; two frames and a 4-pixel gap
    assert image.shape == (h, 2 * w + 4, 3)
    objects = meta["objects_by_distance_to_ee"]
    dist = [o["distance_to_ee_m"] for o in objects]
    assert dist == sorted(dist) and sorted(o["id"] for o in objects) == [0, 1, 2, 3]
    assert all(o["label"] == f"{o['id']}: {o['name']}" for o in objects)
    assert meta["selected"]["ids"] == [objects[0]["id"], objects[1]["id"]]  # no backend: the two nearest
    assert "position 0: " + objects[0]["label"] in (tmp_path / "query_t008.txt").read_text()
    # the past path is drawn as a black line: every interior point of it is black in the newest frame
    path = np.asarray(meta["ee_path_px_in_last_frame"])
    assert len(path) == 9
    newest = image[:, w + 4:]
    mids = ((path[1:] + path[:-1]) / 2)[np.linalg.norm(path[1:] - path[:-1], axis=1) > 3]
    assert len(mids) >= 5  # the scripted pull and the start of the slide move the hand visibly
    for x, y in mids:
        assert newest[int(round(y)), int(round(x))].max() < 40, (x, y)
    assert "query at t = 8" in out

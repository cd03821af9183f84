"""Bad inputs, second round (issue 28): files. Every file the package reads goes through one bounded JSON reader
(size and nesting depth checked before parsing, no NaN/Infinity, no key twice) and the checks of what it holds,
so a safetensors header the Rust loader would refuse, JSON nested 100,000 deep, metadata of the wrong types, a
sweep spec outside its schema, an edited or damaged run folder and a Ray address in a file are all answered with
exit code 2 and one line that says what is wrong and what to do, before any work; never a traceback."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest

from safemanip.rl.checkpoint import POLICY_FORMAT
from conftest import assert_refused, fake_summary, make_policy, policy_file, run_cli

DEEP = "[" * 100_000 + "]" * 100_000
"""JSON nested 100,000 levels deep: Python's parser would end in a RecursionError."""


def raw_safetensors(path: Path, header_text: str, data: bytes) -> str:
    head = header_text.encode()
    path.write_bytes(struct.pack("<Q", len(head)) + head + data)
    return str(path)


def _good_parts(tmp: Path) -> tuple[dict, bytes, str]:
    """(header, tensor bytes, header text) of a valid one-layer policy file."""
    good = Path(policy_file(tmp / "good.safetensors"))
    data = good.read_bytes()
    (n,) = struct.unpack("<Q", data[:8])
    text = data[8:8 + n].decode().rstrip()  # the writer pads the header with spaces
    return json.loads(text), data[8 + n:], text


# ------------------------------------------------------------------------------------------ 1. safetensors headers
def _rust_refused_headers(tmp: Path) -> dict[str, tuple[str, str]]:
    header, body, text = _good_parts(tmp)
    name = next(k for k in header if k != "__metadata__")
    out = {}

    def variant(case: str, new_text: str, message: str):
        out[case] = (raw_safetensors(tmp / f"{case}.safetensors", new_text, body), message)

    floats = {**header, name: {**header[name], "data_offsets": [float(x) for x in header[name]["data_offsets"]]}}
    variant("float-offsets", json.dumps(floats), "invalid entry")
    variant("float-shape", json.dumps({**header, name: {**header[name], "shape": [float(x) for x in header[name]["shape"]]}}),
            "invalid entry")
    variant("bool-shape", json.dumps({**header, name: {**header[name], "shape": [True] * len(header[name]["shape"])}}),
            "invalid entry")
    variant("nan-token", text.replace(f'"{name}":{{', f'"{name}":{{"x":NaN,', 1), "holds NaN")
    variant("infinity-token", text.replace(f'"{name}":{{', f'"{name}":{{"x":-Infinity,', 1), "holds -Infinity")
    variant("duplicate-metadata", '{"__metadata__":{"format":"other/1"},' + text[1:], "key '__metadata__' twice")
    variant("duplicate-tensor", text[:-1] + f',"{name}":' + json.dumps(header[name]) + "}", f"key '{name}' twice")
    variant("extra-entry-field", json.dumps({**header, name: {**header[name], "scale": 2}}), "invalid entry")
    variant("deep-header", '{"__metadata__":' + "[" * 5000 + "]" * 5000 + "}", "nests 5,001 levels")
    return out


RUST_REFUSED = ["float-offsets", "float-shape", "bool-shape", "nan-token", "infinity-token", "duplicate-metadata",
                "duplicate-tensor", "extra-entry-field", "deep-header"]


@pytest.mark.parametrize("case", RUST_REFUSED)
def test_eval_refuses_a_safetensors_header_the_rust_loader_would_refuse(capsys, tmp_path, case):
    path, message = _rust_refused_headers(tmp_path)[case]
    out = tmp_path / "out"
    err = assert_refused(capsys, ["eval", "--policy", path, "--episodes", "1", "--workers", "1", "--out", out], message)
    assert "SafetensorError" not in err and not out.exists()


def test_the_rust_loader_does_refuse_those_headers(tmp_path):
    """The premise of the cases above: Python's json accepts these headers, the Rust loader does not."""
    from safetensors.numpy import load_file

    files = _rust_refused_headers(tmp_path)
    for case in ("float-offsets", "float-shape", "bool-shape", "nan-token", "duplicate-metadata"):
        with pytest.raises(Exception, match="(?i)header"):
            load_file(files[case][0])


def test_demo_refuses_a_float_offset_header(capsys, tmp_path):
    path, message = _rust_refused_headers(tmp_path)["float-offsets"]
    assert_refused(capsys, ["demo", "--policy", path, "--no-video", "--out", tmp_path / "d"], message)


# ------------------------------------------------------------------------------------------ 1. JSON 100k deep
def test_policy_metadata_nested_100k_deep_is_refused(capsys, tmp_path):
    path = policy_file(tmp_path / "deep.safetensors", raw_meta=DEEP)
    err = assert_refused(capsys, ["eval", "--policy", path, "--episodes", "1", "--workers", "1"],
                         "metadata is not valid JSON")
    assert "nests 100,000 levels deep" in err


def test_a_config_file_nested_100k_deep_is_refused(capsys, tmp_path):
    cfg = tmp_path / "c.json"
    cfg.write_text('{"hidden": ' + DEEP + "}")
    assert_refused(capsys, ["train", "--config", cfg, "--out", tmp_path / "run"], "nests 100,001 levels deep")
    assert not (tmp_path / "run").exists()


def test_a_sweep_spec_nested_100k_deep_is_refused(capsys, tmp_path):
    spec = tmp_path / "s.json"
    spec.write_text('{"name": "s", "policies": ' + DEEP + "}")
    assert_refused(capsys, ["sweep", spec, "--out", tmp_path / "o"], "nests 100,001 levels deep")
    assert not (tmp_path / "o").exists()


def test_the_bounded_reader_checks_size_and_depth_before_parsing(tmp_path):
    from safemanip.util.files import JSONInputError, json_depth, parse_json, read_json_file

    assert json_depth('{"a": ["[[[", {"b": "]]"}]}') == 3  # brackets inside strings do not count
    for text, reason in ((DEEP, "nests 100,000"), ('{"a": NaN}', "NaN"), ('{"a": 1, "a": 2}', "twice"),
                         ("x" * 20, "more than the 10"), (b"\xff\xfe", "not UTF-8")):
        with pytest.raises(JSONInputError, match=reason):
            parse_json(text, "doc", max_bytes=10 if reason.startswith("more") else 10_000_000)
    big = tmp_path / "big.json"
    big.write_bytes(b" " * 2000)
    with pytest.raises(JSONInputError, match="2,000 bytes"):
        read_json_file(big, max_bytes=1000)


# ------------------------------------------------------------------------------------------ 1. metadata types
GOOD_META = {"algorithm": "rarl", "k": 1, "constraints": "conservative", "obs_dim": 26, "act_dim": 3, "hidden": [8],
             "env_kwargs": {"n_objects": 1, "max_episode_steps": 300, "embodiment": "panda"}}


@pytest.mark.parametrize("change,message", [
    ({"env_kwargs": {"near_path_fraction": "x"}}, "env_kwargs: invalid env settings: near_path_fraction must be a "
                                                  "number in [0, 1] (or None), got 'x'"),
    ({"env_kwargs": {"near_path_fraction": 7}}, "near_path_fraction must be a number in [0, 1] (or None), got 7"),
    ({"env_kwargs": {"action_curve": [1, 2]}}, "action_curve must be a number from 1 (linear) to 4, got [1, 2]"),
    ({"env_kwargs": {"clear_route": "no"}}, "clear_route must be true or false, got 'no'"),
    ({"env_kwargs": {"object_size": 1}}, "object_size must be true or false, got 1"),
    ({"env_kwargs": {"layout": 5}}, "layout must be one of 'route', 'narrow', 'gate', 'exit', got 5"),
    ({"env_kwargs": {"max_episode_steps": 1.5}}, "max_episode_steps must be an integer from 1 to 100000, got 1.5"),
    ({"env_kwargs": {"max_episode_steps": True}}, "max_episode_steps must be an integer from 1 to 100000, got True"),
    ({"env_kwargs": {"factory": "os:system"}}, "env_kwargs: unknown setting(s) ['factory']"),
    ({"train_config": {"k": 1, "layout": "exit"}}, "train_config: layout at the top level of a training config: that "
                                                   "is the format written before 2026-12-08"),
    ({"k": True}, "k=True is not a slot count"),
    ({"hidden": ["8"]}, "hidden=['8'] is not a list of layer widths"),
    ({"network": "transformer"}, "network='transformer' is not 'mlp' or 'set'"),
    ({"env_kwargs": ["n_objects", 1]}, "env_kwargs=['n_objects', 1] is not an object"),
])
def test_eval_refuses_policy_metadata_of_the_wrong_types(capsys, tmp_path, change, message):
    meta = json.loads(json.dumps(GOOD_META))
    for key, value in change.items():
        if isinstance(value, dict):
            meta.setdefault(key, {}).update(value)
        else:
            meta[key] = value
    path = policy_file(tmp_path / "p.safetensors", meta=meta)
    out = tmp_path / "out"
    assert_refused(capsys, ["eval", "--policy", path, "--episodes", "1", "--workers", "1", "--out", out], message)
    assert not out.exists()


# ------------------------------------------------------------------------------------------ 2. sweep schema
def _spec(tmp_path: Path, **change) -> Path:
    policy = make_policy(tmp_path / "rarl-k2-conservative.safetensors", 2)
    spec = {"name": "s", "title": "t", "figure": "table", "episodes": 1, "seed": 0, "judge": "conservative",
            "policies": [policy], "n_objects": [2], "selectors": ["full"],
            "table": {"rows": ["k"], "columns": ["selector"]}}
    for key, value in change.items():
        if value is ...:
            spec.pop(key)
        else:
            spec[key] = value
    path = tmp_path / "spec.json"
    path.write_text(json.dumps(spec))
    return path


@pytest.mark.parametrize("text,message", [
    ("5", "a sweep spec is a JSON object"), ("null", "a sweep spec is a JSON object"),
    ('["3"]', "a sweep spec is a JSON object"), ('"fig5"', "a sweep spec is a JSON object"),
])
def test_sweep_refuses_a_spec_that_is_not_an_object(capsys, tmp_path, text, message):
    spec = tmp_path / "s.json"
    spec.write_text(text)
    assert_refused(capsys, ["sweep", spec, "--out", tmp_path / "o"], message)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("change,message", [
    ({"layout": "narrow"}, "unknown key(s) 'layout'"),
    ({"seeds": 3}, "unknown key(s) 'seeds'"),
    ({"policies": 5}, "policies must be a non-empty list"),
    ({"policies": []}, "policies must be a non-empty list"),
    ({"policies": [5]}, "policy entry 5 must be a path"),
    ({"policies": [{"path": "policies/rarl-k2-conservative.safetensors", "k": 2}]}, "must be a path or"),
    ({"episodes": 0}, "episodes must be an integer 1..100000"),
    ({"episodes": 10**9}, "episodes must be an integer 1..100000"),
    ({"episodes": "10"}, "episodes must be an integer"),
    ({"episodes": True}, "episodes must be an integer"),
    ({"seed": -1}, "seed (the episode seed block) must be an integer"),
    ({"seed": 2.5}, "seed (the episode seed block) must be an integer"),
    ({"n_objects": [99]}, "n_objects must be a non-empty list of object counts 0..8"),
    ({"n_objects": ["3"]}, "n_objects must be a non-empty list of object counts"),
    ({"n_objects": 3}, "n_objects must be a non-empty list of object counts"),
    ({"selectors": "full"}, "selectors must be a non-empty list"),
    ({"selectors": ["nearest"]}, "unknown selector 'nearest'"),
    ({"constraints": [None]}, "constraints must be a non-empty list"),
    ({"semantics": [3]}, "semantics must be a non-empty list"),
    ({"semantics": ["3 squishy"]}, "cannot read"),
    ({"pairs": [["full"]]}, "pairs must be a non-empty list of [selector, constraints] pairs"),
    ({"judge": ["conservative"]}, "judge must be one of"),
    ({"figure": "fig9"}, "figure must be one of"),
    ({"title": 5}, "title must be a string"),
    ({"table": {"rows": ["k"], "columns": ["selector"], "colour": "red"}}, "table must be {'rows'"),
    ({"table": {"rows": ["speed"], "columns": ["selector"]}}, "table rows: unknown cell field(s) 'speed'"),
    ({"table": {"rows": ["k"], "columns": ["selector", 3]}}, "table columns must be a non-empty list"),
    ({"table": {"rows": ["k"], "columns": ["k"]}}, "table rows and columns both name k"),
    ({"k_equals_n_selector": 4}, "unknown k_equals_n_selector 4"),
    ({"name": "../escaped"}, "name must be a plain file name"),
    ({"name": "/tmp/abs"}, "name must be a plain file name"),
    ({"name": "a/b"}, "name must be a plain file name"),
    ({"name": ".."}, "name must be a plain file name"),
    ({"name": 5}, "name must be a plain file name"),
    ({"judge": ...}, "missing key 'judge'"),
])
def test_sweep_refuses_a_spec_outside_its_schema_before_the_output_folder_exists(capsys, tmp_path, change, message):
    out = tmp_path / "o"
    assert_refused(capsys, ["sweep", _spec(tmp_path, **change), "--out", out], message)
    assert not out.exists()


def test_a_sweep_name_never_writes_outside_the_output_folder(capsys, tmp_path):
    """A name such as ../x or an absolute path is refused before anything is written anywhere."""
    before = sorted(p.name for p in tmp_path.iterdir())
    assert_refused(capsys, ["sweep", _spec(tmp_path, name="../escaped"), "--out", tmp_path / "o", "--render-only"],
                   "plain file name")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(before + ["spec.json", "rarl-k2-conservative.safetensors"])


def test_two_policies_of_the_same_k_are_both_shown(tmp_path):
    from safemanip.evaluation.sweep.grid import cells_of
    from safemanip.evaluation.sweep.render import markdown_table
    from safemanip.evaluation.sweep.spec import load_config

    rarl = make_policy(tmp_path / "rarl-k2-conservative.safetensors", 2)
    vanilla = make_policy(tmp_path / "vanilla-k2-conservative.safetensors", 2)
    path = _spec(tmp_path, policies=[rarl, vanilla])
    cfg = load_config(str(path))
    cells = cells_of(cfg)
    assert len(cells) == 2
    results = [{"cell": cell.record(), "summary": fake_summary(rate)} for cell, rate in zip(cells, (0.25, 0.75))]
    table = markdown_table(cfg, results)
    assert "25.0 [" in table and "75.0 [" in table  # one row each, neither hidden behind the other
    assert "rarl-k2-conservative" in table and "vanilla-k2-conservative" in table


def test_a_damaged_or_deep_cell_result_is_redone_not_fatal(capsys, tmp_path):
    from safemanip.evaluation.sweep.grid import cells_of
    from safemanip.evaluation.sweep.spec import load_config
    from safemanip.evaluation.sweep.store import is_done, load_results

    cfg = load_config(str(_spec(tmp_path)))
    (cell,) = cells_of(cfg)
    cells = tmp_path / "o" / "cells"
    cells.mkdir(parents=True)
    path = cells / f"{cell.id}.json"
    for text in (DEEP, json.dumps({"cell": cell.record(), "summary": {"success": 5}}), json.dumps([1, 2]),
                 json.dumps({"cell": {**cell.record(), "k": "2"}, "summary": fake_summary(0.5)})):
        path.write_text(text)
        assert not is_done(path, cell)
        assert load_results(tmp_path / "o") == []
    assert "ignoring unreadable result" in capsys.readouterr().err
    path.write_text(json.dumps({"cell": cell.record(), "summary": fake_summary(0.5)}))
    assert is_done(path, cell) and len(load_results(tmp_path / "o")) == 1


# ------------------------------------------------------------------------------------------ 3. resume
def fake_run(tmp_path: Path, **config) -> Path:
    """A run folder with a real (untrained) checkpoint, written as the training loop writes it, without training."""
    from safemanip.env.observation import observation_dim
    from safemanip.rl.buffer import ReplayBuffer
    from safemanip.rl.checkpoint import write_checkpoint
    from safemanip.rl.config import TrainConfig
    from safemanip.rl.learner import Learner

    run_dir = tmp_path / "run"
    run_dir.mkdir()
    cfg = TrainConfig(**{"k": 1, "hidden": (16, 16), "batch_size": 8, "buffer_size": 200, "learning_starts": 8,
                         "random_steps": 8, "out_dir": str(run_dir), "precision": "fp32", "device": "cpu", **config})
    obs_dim = observation_dim(cfg.k, cfg.env.object_size)
    learner = Learner(obs_dim, 3, cfg)
    buffer = ReplayBuffer(cfg.buffer_size, obs_dim, 3)
    rng = np.random.default_rng(0)
    buffer.add_many({"obs": rng.normal(size=(20, obs_dim)).astype(np.float32),
                     "act": rng.uniform(-1, 1, (20, 3)).astype(np.float32),
                     "next_obs": rng.normal(size=(20, obs_dim)).astype(np.float32),
                     **{k: rng.normal(size=20).astype(np.float32) for k in ("l", "g", "next_l", "next_g")},
                     "terminated": np.zeros(20, bool)})
    write_checkpoint(run_dir, learner.state_tensors(), buffer,
                     {"env_steps": 20, "updates": 0, "elapsed_s": 1.0, "restarts": 0, "best": {"success": -1.0},
                      "config": json.loads(cfg.to_json())})
    (run_dir / "config.json").write_text(cfg.to_json())
    return run_dir


def _edit_config(run_dir: Path, **change) -> None:
    cfg = json.loads((run_dir / "config.json").read_text())
    cfg.update({**change, "env": {**cfg["env"], **change.get("env", {})}})
    (run_dir / "config.json").write_text(json.dumps(cfg))


@pytest.mark.parametrize("change,message", [
    ({"k": 2}, "k is 2 in config.json but 1 in the checkpoint"),
    ({"network": "set"}, "network is 'set' in config.json but 'mlp' in the checkpoint"),
    ({"hidden": [32, 32]}, "hidden is [32, 32] in config.json but [16, 16] in the checkpoint"),
    ({"env": {"embodiment": "hand"}}, "env.embodiment is 'hand' in config.json but 'panda' in the checkpoint"),
    ({"algorithm": "vanilla"}, "algorithm is 'vanilla' in config.json but 'rarl' in the checkpoint"),
    ({"env": {"layout": "narrow"}}, "env.layout is 'narrow' in config.json but 'route' in the checkpoint"),
    ({"env": {"constraints": "random"}}, "env.constraints is 'random' in config.json but 'conservative' in the checkpoint"),
    ({"env": {"object_size": True}}, "env.object_size is True in config.json but False in the checkpoint"),
    ({"env": {"action_curve": 3.0}}, "env.action_curve is 3.0 in config.json but 2.0 in the checkpoint"),
])
def test_resume_refuses_a_run_whose_config_was_edited(capsys, tmp_path, change, message):
    run_dir = fake_run(tmp_path)
    _edit_config(run_dir, **change)
    before = (run_dir / "config.json").read_text()
    err = assert_refused(capsys, ["train", "--resume", run_dir, "--no-progress"], message)
    assert "Restore config.json" in err and "start a new run with --out" in err
    assert (run_dir / "config.json").read_text() == before and not (run_dir / "scalars.csv").exists()


def test_resume_refuses_a_truncated_replay_buffer_and_says_how_to_recover(capsys, tmp_path):
    from safemanip.rl.config import TrainConfig
    from safemanip.rl.train import warm_start

    run_dir = fake_run(tmp_path)
    replay = run_dir / "checkpoint" / "replay.npz"
    replay.write_bytes(replay.read_bytes()[:300])
    err = assert_refused(capsys, ["train", "--resume", run_dir, "--no-progress"], "replay buffer cannot be restored")
    assert "truncated or damaged" in err and f"--init-from {run_dir}" in err
    # the recovery it names works: a new run can start from the checkpoint's networks
    cfg = TrainConfig.from_file(run_dir / "config.json")
    networks, provenance = warm_start(TrainConfig.from_dict({**cfg.__dict__, "init_from": str(run_dir),
                                                             "out_dir": str(tmp_path / "new")}))
    assert networks and provenance["run"] == str(run_dir)


@pytest.mark.parametrize("meta_text,message", [
    (DEEP, "nests 100,000 levels deep"),
    ("{not json", "is not valid JSON"),
    ('{"updates": "x", "env_steps": 1, "elapsed_s": 1.0}', "updates missing or of the wrong type"),
    ('{"updates": 1, "env_steps": 1, "elapsed_s": NaN}', "holds NaN"),
    ('{"updates": 1, "env_steps": 1, "elapsed_s": 1.0, "config": [1]}', "config missing or of the wrong type"),
])
def test_resume_refuses_a_bad_meta_json_and_says_how_to_recover(capsys, tmp_path, meta_text, message):
    run_dir = fake_run(tmp_path)
    (run_dir / "checkpoint" / "meta.json").write_text(meta_text)
    err = assert_refused(capsys, ["train", "--resume", run_dir, "--no-progress"], message)
    assert "no usable checkpoint" in err and "Restore the damaged file from a backup" in err
    assert f"--config {run_dir / 'config.json'} --out NEW_FOLDER" in err


def test_evals_jsonl_lines_nested_deep_are_dropped_not_fatal(tmp_path):
    from safemanip.rl.train import truncate_logs

    (tmp_path / "evals.jsonl").write_text(json.dumps({"env_steps": 10, "success": 0.5}) + "\n" + DEEP + "\n"
                                          + '{"env_steps": NaN}\n' + json.dumps({"env_steps": "5"}) + "\n")
    truncate_logs(tmp_path, 100)
    assert [json.loads(x)["env_steps"] for x in (tmp_path / "evals.jsonl").read_text().splitlines()] == [10]


# ------------------------------------------------------------------------------------------ 5. no Ray address from files
def test_a_config_file_naming_a_ray_cluster_is_refused(capsys, tmp_path):
    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps({"backend": "ray", "address": "10.0.0.1:6379"}))
    assert_refused(capsys, ["train", "--config", cfg, "--out", tmp_path / "run"],
                   "a config file may not name a Ray cluster ('address'): the address comes from --address")
    assert not (tmp_path / "run").exists()


def test_the_address_is_never_written_and_dropped_from_a_run_config_on_resume(capsys, tmp_path):
    from safemanip.rl.config import TrainConfig, load_run_config

    cfg = TrainConfig(backend="ray", address="10.0.0.1:6379")
    assert "address" not in json.loads(cfg.to_json())  # config.json, checkpoints and policies never hold it
    run_dir = fake_run(tmp_path)
    _edit_config(run_dir, backend="ray", address="10.9.9.9:6379")  # what an older version (or an attacker) wrote
    loaded, dropped = load_run_config(run_dir / "config.json")
    assert loaded.address is None and dropped == "10.9.9.9:6379"
    _edit_config(run_dir, k=2)  # stop the resume right after the config is read, before any work
    err = assert_refused(capsys, ["train", "--resume", run_dir, "--no-progress"], "k is 2 in config.json")
    assert "records a Ray cluster address ('10.9.9.9:6379'); it is ignored" in err


def test_resume_takes_address_from_the_flag_only(capsys, tmp_path):
    """--address is allowed on --resume (where the workers run is not a setting of the run), and checked."""
    run_dir = fake_run(tmp_path, backend="ray")
    err = assert_refused(capsys, ["train", "--resume", run_dir, "--address", "127.0.0.1:1", "--no-progress"],
                         "--address 127.0.0.1:1: cannot reach a Ray cluster there")
    assert "flags differ" not in err


# ------------------------------------------------------------------------------------------ 9. --semantic-examples
SECRET_LINE = "root:x:0:0:TOP-SECRET-CONTENT:/root:/bin/bash"


@pytest.mark.parametrize("value", ["heldout_names_v1.json", "heldout-v2", "/etc/passwd", "../../../../etc/passwd",
                                   "data/class_examples_v3.json", "class_examples_v3.json/..", "FOREIGN", "v3.json",
                                   "class_examples_v3.txt"])
def test_semantic_examples_accepts_only_its_documented_format(capsys, tmp_path, value):
    foreign = tmp_path / "foreign.json"
    foreign.write_text(json.dumps({"classes": {"a": [SECRET_LINE]}, "decision": {"rule": SECRET_LINE}}))
    value = value.replace("FOREIGN", str(foreign))
    err = assert_refused(capsys, ["classify-constraints", "--semantic-examples", value, "mug"], "is not an example set")
    assert "class_examples_<version>.json" in err and SECRET_LINE not in err


def test_semantic_examples_never_echoes_a_files_content(monkeypatch, tmp_path):
    """A class-example file of the wrong shape is refused by what is wrong, not by quoting it."""
    from importlib import resources

    from safemanip.semantics import semantic_backend

    data = tmp_path / "data"
    data.mkdir()
    (data / "class_examples_vx.json").write_text(json.dumps({"classes": {SECRET_LINE: ["x"]}}))
    (data / "class_examples_vy.json").write_text(json.dumps({"classes": {"fragile": ["a"], "soft": ["b"], "durable": ["c"]},
                                                             "decision": {"rule": SECRET_LINE}}))
    (data / "class_examples_vz.json").write_text("[" * 50 + "]" * 50)

    class Files:
        def joinpath(self, name):
            return data if name == "data" else data / name

    monkeypatch.setattr(resources, "files", lambda package: Files())
    for name, message in (("class_examples_vx.json", "must list exactly"), ("class_examples_vy.json", "decision rule"),
                          ("class_examples_vz.json", "nests 50 levels")):
        with pytest.raises(ValueError, match=message) as err:
            semantic_backend.load_class_examples(name) if "vy" not in name else semantic_backend.load_decision_rule(name)
        assert SECRET_LINE not in str(err.value)


def test_semantic_examples_versions_and_file_names_still_work(capsys):
    for value in ("v1", "class_examples_v2.json"):
        code, out, err = run_cli(capsys, ["classify-constraints", "--semantic-examples", value, "glass jar"])
        assert code == 0 and out.startswith("glass jar\t"), err


def test_policy_format_tag_is_still_checked(capsys, tmp_path):
    path = policy_file(tmp_path / "p.safetensors", fmt="x/1")
    assert_refused(capsys, ["eval", "--policy", path, "--episodes", "1", "--workers", "1"], "not a safemanip policy")
    assert POLICY_FORMAT == "safemanip-policy/2"


def test_a_policy_of_the_retired_flat_format_is_refused_with_what_to_do(capsys, tmp_path):
    """Format 1 (before 2026-12-08) kept the env's settings flat in the training config; retired in issue 43."""
    path = policy_file(tmp_path / "old.safetensors", fmt="safemanip-policy/1")
    assert_refused(capsys, ["eval", "--policy", path, "--episodes", "1", "--workers", "1"],
                   "is a policy of the retired format 'safemanip-policy/1' (written before 2026-12-08, with the env's "
                   "settings flat in its training config; retired in issue 43); this version reads "
                   "'safemanip-policy/2' only. Re-train it")

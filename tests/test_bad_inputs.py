"""Bad inputs, as a new user or an attacker would type them: every one is answered with exit code 2 and
a one-line message that says what is wrong, before any work is done (no episode, no training step, no
file written), and never with a traceback. In-process through ``safemanip.cli.main`` (fast); the
code-execution cases also as real subprocesses."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from safemanip.rl.policy_index import PACKAGE_POLICIES
from conftest import SUBPROCESS_ENV, assert_refused, make_policy, policy_file, run_cli, run_safemanip

POLICY = str(PACKAGE_POLICIES / "rarl-k2-conservative-s0.safetensors")
EVAL = ["eval", "--policy", POLICY, "--episodes", "1", "--workers", "1", "--no-progress"]


# ------------------------------------------------------------------------------------------ files to refuse
def _bad_policies(tmp: Path) -> dict[str, tuple[str, str]]:
    good = policy_file(tmp / "good.safetensors")
    data = Path(good).read_bytes()
    files = {}

    def write(name, content):
        (tmp / name).write_bytes(content)
        return str(tmp / name)

    files["truncated"] = (write("truncated.safetensors", data[: len(data) - 40]), "truncated or damaged")
    files["empty"] = (write("empty.safetensors", b""), "too short for a header")
    files["text"] = (write("text.safetensors", b"this is not a tensor file at all, just words\n"), "header length")
    files["huge-header"] = (write("huge.safetensors", struct.pack("<Q", 2**62) + b"{}"), "header length")
    files["header-not-json"] = (write("notjson.safetensors", struct.pack("<Q", 4) + b"{{{{"), "header is not JSON")
    header = json.dumps({"a": {"dtype": "F32", "shape": [1000], "data_offsets": [0, 16]}}).encode()
    files["bad-offsets"] = (write("offsets.safetensors", struct.pack("<Q", len(header)) + header + b"\0" * 16),
                            "invalid entry")
    rng = np.random.default_rng(1)
    files["not-a-policy"] = (policy_file(tmp / "other.safetensors", fmt="something-else/1"), "not a safemanip policy")
    files["missing-key"] = (policy_file(tmp / "missing.safetensors", tensors={
        "layer0.weight": rng.normal(size=(8, 26)).astype(np.float32), "layer0.bias": np.zeros(8, np.float32),
        "layer1.weight": rng.normal(size=(3, 8)).astype(np.float32)}), "expected tensors")
    files["meta-not-json"] = (policy_file(tmp / "metajson.safetensors", raw_meta="{k: 1"), "metadata is not valid JSON")
    files["meta-nan"] = (policy_file(tmp / "metanan.safetensors", raw_meta='{"k": NaN}'), "metadata is not valid JSON")
    nan = {"layer0.weight": np.full((8, 26), np.nan, np.float32), "layer0.bias": np.zeros(8, np.float32),
           "layer1.weight": rng.normal(size=(3, 8)).astype(np.float32), "layer1.bias": np.zeros(3, np.float32)}
    files["nan-weights"] = (policy_file(tmp / "nan.safetensors", tensors=nan), "non-finite")
    chain = {"layer0.weight": rng.normal(size=(8, 26)).astype(np.float32), "layer0.bias": np.zeros(8, np.float32),
             "layer1.weight": rng.normal(size=(3, 9)).astype(np.float32), "layer1.bias": np.zeros(3, np.float32)}
    files["shapes-do-not-chain"] = (policy_file(tmp / "chain.safetensors", tensors=chain), "do not chain")
    files["meta-shape-mismatch"] = (policy_file(tmp / "dims.safetensors", meta={
        "k": 1, "constraints": "conservative", "obs_dim": 40, "act_dim": 3, "env_kwargs": {}}),
        "metadata does not match the weights")
    files["meta-lacks-k"] = (policy_file(tmp / "nok.safetensors", meta={"constraints": "conservative", "env_kwargs": {}}),
                             "metadata lacks")
    files["meta-k-not-int"] = (policy_file(tmp / "kstr.safetensors", meta={
        "k": "two", "constraints": "conservative", "env_kwargs": {}}), "not a slot count")
    files["toy-policy"] = (policy_file(tmp / "toy.safetensors", meta={
        "k": 0, "constraints": "conservative", "env_kwargs": {"env": "toy-double-integrator"}}), "not the slide-out task")
    files["policy-from-before-the-arm"] = (make_policy(tmp / "legacy.safetensors", 2, embodiment=None),
                                           "predates the Panda arm")
    # env settings the env does not take (the retired format's env_kwargs.factory among them): never imported
    good = {"algorithm": "rarl", "k": 1, "constraints": "conservative", "obs_dim": 26, "act_dim": 3, "hidden": [8],
            "env_kwargs": {"n_objects": 1, "max_episode_steps": 300, "embodiment": "panda"}}
    files["unknown-env-setting"] = (policy_file(tmp / "factory.safetensors", meta={
        **good, "env_kwargs": {"factory": "safemanip.env.slide_out:SlideOutEnv", "n_objects": 1}}),
        "env_kwargs: unknown setting(s) ['factory']")
    # the format written before 2026-12-08 (env settings flat in the training config), retired in issue 43
    files["retired-format"] = (policy_file(tmp / "flat.safetensors", meta=good, fmt="safemanip-policy/1"),
                               "is a policy of the retired format 'safemanip-policy/1'")
    files["missing-file"] = (str(tmp / "nowhere.safetensors"), "no policy file")
    files["folder-without-policy"] = (str(tmp), "holds no policy.safetensors")
    return files


BAD_POLICIES = ["truncated", "empty", "text", "huge-header", "header-not-json", "bad-offsets", "not-a-policy",
                "missing-key", "meta-not-json", "meta-nan", "nan-weights", "shapes-do-not-chain",
                "meta-shape-mismatch", "meta-lacks-k", "meta-k-not-int", "toy-policy", "policy-from-before-the-arm",
                "unknown-env-setting", "retired-format", "missing-file", "folder-without-policy"]


@pytest.mark.parametrize("case", BAD_POLICIES)
def test_eval_refuses_a_bad_policy_file(capsys, tmp_path, case):
    path, message = _bad_policies(tmp_path)[case]
    out = tmp_path / "out"
    assert_refused(capsys, ["eval", "--policy", path, "--episodes", "1", "--workers", "1", "--out", out], message)
    assert not out.exists()


@pytest.mark.parametrize("case", ["truncated", "nan-weights", "missing-key", "policy-from-before-the-arm",
                                  "retired-format"])
def test_demo_refuses_a_bad_policy_file(capsys, tmp_path, case):
    path, message = _bad_policies(tmp_path)[case]
    assert_refused(capsys, ["demo", "--policy", path, "--no-video", "--out", tmp_path / "d"], message)


@pytest.mark.parametrize("command", ["eval", "demo"])
def test_a_policy_from_another_embodiment_is_refused(capsys, tmp_path, command):
    """A Panda policy asked to drive the hand (and back) is refused before anything runs, saying why and what to do."""
    for trained, wanted in (("panda", "hand"), ("hand", "panda")):
        path = make_policy(tmp_path / f"{trained}.safetensors", 2, embodiment=trained)
        out = tmp_path / f"out-{trained}"
        extra = ["--episodes", "1", "--workers", "1"] if command == "eval" else ["--no-video"]
        assert_refused(capsys, [command, "--policy", path, "--embodiment", wanted, "--out", out, *extra],
                       f"was trained on the '{trained}' embodiment and cannot drive the '{wanted}'")
        assert not out.exists()


# ------------------------------------------------------------------------------------------ eval flags
@pytest.mark.parametrize("extra,message", [
    (["--episodes", "0"], "argument --episodes"),
    (["--episodes", "-5"], "argument --episodes"),
    (["--episodes", "1e3"], "expected an integer"),
    (["--seed", "-1"], "argument --seed"),
    (["--semantics", "99999999999999999999 fragile"], "at most 8 objects"),
    (["--semantics", "three fragile"], "cannot read"),
    (["--max-episode-steps", "1e12"], "argument --max-episode-steps"),
    (["--max-episode-steps", "1000000000000"], "max_episode_steps must be an integer from 1 to 100000"),
    (["--gate-share", "2"], "gate_share"),
    (["--n-objects", "99"], "argument --n-objects"),
    (["--workers", "0"], "argument --workers"),
    (["--interval", "0"], "argument --interval"),
    (["--chunk-size", "-1"], "argument --chunk-size"),
    (["--selector", "bogus"], "argument --selector: invalid choice"),
    (["--constraint-selector", "bogus"], "argument --constraint-selector: invalid choice"),
    (["--constraints", "vlm"], "unrecognized arguments: --constraints vlm"),  # the retired spelling is gone
    (["--judge", "bogus"], "argument --judge"),
    (["--backend", "semantic"], "argument --backend"),
    (["--address", "127.0.0.1:1"], "--address only applies to --backend ray"),
    (["--vlm-timeout", "nan"], "argument --vlm-timeout"),
    (["--vlm-timeout", "5"], "only appl"),
    (["--vlm-max-failures", "0"], "argument --vlm-max-failures"),
    (["--selector", "dynamic-vlm", "--n-objects", "3", "--vlm-timeout", "5"], "apply to --vlm-backend openai"),
    (["--vlm-cache-only"], "only appl"),
])
def test_eval_refuses_bad_flags(capsys, extra, message):
    assert_refused(capsys, EVAL + extra, message)


def test_eval_checks_out_before_running_episodes(capsys, tmp_path):
    a_file = tmp_path / "file.txt"
    a_file.write_text("x")
    assert_refused(capsys, EVAL + ["--out", a_file], "is a file")
    assert_refused(capsys, EVAL + ["--out", a_file / "sub"], "is a file")
    if os.geteuid() != 0:  # root writes anywhere
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o500)
        try:
            assert_refused(capsys, EVAL + ["--out", ro / "x"], "not writable")
        finally:
            ro.chmod(0o700)


def test_eval_refuses_an_out_held_by_a_live_process(capsys, tmp_path):
    out = tmp_path / "busy"
    holder = subprocess.Popen([sys.executable, "-c", "import sys, time; from safemanip.util.files import OutputLock; "
                               f"OutputLock({str(out)!r}).acquire(); print('held', flush=True); time.sleep(60)"],
                              stdout=subprocess.PIPE, text=True, env=SUBPROCESS_ENV)
    try:
        assert holder.stdout.readline().strip() == "held"
        assert_refused(capsys, EVAL + ["--out", out], "in use by a running process")
        assert not (out / "summary.json").exists()
    finally:
        holder.kill()
        holder.wait()
    code, _, err = run_cli(capsys, EVAL + ["--out", out])  # a dead holder's lock is gone with it
    assert code == 0, err
    assert (out / "summary.json").exists()


# ------------------------------------------------------------------------------------------ train
TRAIN = ["train", "--no-progress"]


@pytest.mark.parametrize("extra,message", [
    (["--minutes", "nan"], "argument --minutes"),
    (["--minutes", "-1"], "argument --minutes"),
    (["--minutes", "inf"], "argument --minutes"),
    (["--checkpoint-every-s", "nan"], "argument --checkpoint-every-s"),
    (["--checkpoint-every-s", "0"], "argument --checkpoint-every-s"),
    (["--env-steps-per-update", "nan"], "argument --env-steps-per-update"),
    (["--env-steps-per-update", "0"], "argument --env-steps-per-update"),
    (["--eval-episodes", "-5"], "argument --eval-episodes"),
    (["--eval-episodes", "0"], "argument --eval-episodes"),
    (["--eval-every-s", "-3"], "argument --eval-every-s"),
    (["--seed", "-1"], "argument --seed"),
    (["--max-episode-steps", "1e12"], "argument --max-episode-steps"),
    (["--total-env-steps", "0"], "argument --total-env-steps"),
    (["--k", "99"], "argument --k"),
    (["--gamma", "1"], "argument --gamma: must be in (0, 1)"),
    (["--gamma", "0.9", "--gamma-start", "0.95"], "gamma_start must be in (0, gamma]"),
    (["--learning-rate-final", "0.01"], "learning_rate_final must be in (0, learning_rate"),
    (["--learning-rate-final", "0"], "argument --learning-rate-final"),
    (["--algorithm", "ppo"], "argument --algorithm"),
    # the learner's flags (issue 10)
    (["--workers", "0"], "argument --workers"),
    (["--workers", "1000"], "argument --workers"),
    (["--precision", "fp8"], "argument --precision"),
    (["--device", "tpu"], "argument --device"),
    (["--network", "transformer"], "argument --network"),
    (["--backend", "slurm"], "argument --backend"),
    (["--selector", "privileged"], "argument --selector"),
    (["--selection-radius", "0"], "argument --selection-radius"),
    (["--selection-radius", "nan"], "argument --selection-radius"),
    (["--scene-objects", "99"], "argument --scene-objects"),
    (["--k", "4", "--scene-objects", "2"], "scene_objects must be in k..8"),
    (["--k", "4", "--scene-objects-min", "5"], "scene_objects_min must be in 1..4"),
    (["--selector", "dynamic-radius"], "use network 'set'"),
    (["--address", "10.0.0.1:6379"], "address only applies to backend 'ray'"),
    (["--backend", "ray", "--address", "a b"], "address must be a Ray cluster address"),
    (["--object-size", "yes"], "unrecognized arguments: yes"),
    (["--init-from", "no/such/run"], "no complete checkpoint there"),
])
def test_train_refuses_bad_flags(capsys, tmp_path, extra, message):
    assert_refused(capsys, TRAIN + ["--out", tmp_path / "run"] + extra, message)
    assert not (tmp_path / "run").exists()


EVIL = {"env_factory": "subprocess:getoutput", "extra_env_kwargs": {"cmd": "touch {marker}"}}


@pytest.mark.parametrize("config,message", [
    (EVIL, "env_factory 'subprocess:getoutput' is not accepted"),
    ({"env_name": "subprocess:getoutput"}, "env_name must be one of the registered envs"),
    ({"env": "subprocess:getoutput"}, "env as a name at the top level of a training config"),
    ({"env_name": "toy-double-integrator", "extra_env_kwargs": {"cmd": "x"}}, "not accepted by env"),
    ({"extra_env_kwargs": {"max_episode_steps": 5}}, "extra_env_kwargs apply to non-default envs only"),
    ({"learning_rat": 1e-3}, "unknown config key"),
    ({"hidden": [1e9]}, "hidden must be a list of integers"),
    ({"hidden": [100000]}, "hidden must list"),
    ({"buffer_size": 10**12}, "buffer_size must be in [1, 10,000,000]"),
    ({"minutes": "ten"}, "minutes must be a float"),
    ({"seed": True}, "seed must be an int"),
    ({"eval_episodes": 0}, "eval_episodes must be in [1, 100,000]"),
    ({"n_collectors": 10**6}, "n_collectors must be in [1, 64]"),
    # the selection-aware env is the registry's, never a module named by a config
    ({"env_name": "selection:SelectedSlotsEnv"}, "env_name must be one of the registered envs"),
    ({"env_name": "safemanip.selection.training_env:SelectedSlotsEnv"}, "env_name must be one of the registered envs"),
    ({"env_name": "slide-out-selected"}, "env_name must be one of the registered envs"),
    ({"env_factory": "safemanip.selection.training_env:SelectedSlotsEnv", "scene_objects": 4},
     "env_factory 'safemanip.selection.training_env:SelectedSlotsEnv' is not accepted"),
    # the config format written before 2026-12-01 (retired in issue 43): refused with what to do, never converted
    ({"env_factory": "safemanip.env.slide_out:SlideOutEnv"}, "retired in issue 43, and nothing in a config is imported"),
    ({"env_factory": None, "k": 2}, "Name the env with 'env_name', one of ['slide-out', 'toy-double-integrator']"),
    ({"n_objects": 2}, "the policy's object slots are 'k' and a larger training scene is 'scene_objects'"),
    ({"n_objects": 2, "k": 2}, "in a config file of your own, drop it and use those two keys"),
    ({"env_name": "toy-double-integrator", "scene_objects": 4}, "scene_objects (selection-aware training) works on"),
    ({"env": {"layout": "tight"}}, "invalid env settings: layout must be one of"),
    ({"env": {"n_objects": 3}}, "env.n_objects is k's (2), got 3"),
    ({"layout": "gate"}, "layout at the top level of a training config: that is the format written before 2026-12-08"),
    ({"device": "cuda:x"}, "device must be one of"),
    ({"set_embed": 10**6}, "set_embed must be in [1, 4,096]"),
    ({"selection_radius": -1.0}, "selection_radius must be in (0, 10]"),
    ({"backend": "ray", "address": "a b"}, "a config file may not name a Ray cluster"),  # flag or RAY_ADDRESS only
])
def test_train_refuses_bad_configs(capsys, tmp_path, config, message):
    marker = tmp_path / "pwned"
    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps(config).replace("{marker}", str(marker)))
    assert_refused(capsys, TRAIN + ["--config", cfg, "--out", tmp_path / "run"], message)
    assert not marker.exists() and not (tmp_path / "run").exists()


@pytest.mark.parametrize("text,message", [("{not json", "not valid JSON"), ('{"minutes": NaN}', "not valid JSON"),
                                          ("[1, 2]", "must be a JSON object"), ("", "not valid JSON")])
def test_train_refuses_unreadable_config_files(capsys, tmp_path, text, message):
    cfg = tmp_path / "c.json"
    cfg.write_text(text)
    assert_refused(capsys, TRAIN + ["--config", cfg], message)
    assert_refused(capsys, TRAIN + ["--config", tmp_path / "missing.json"], "cannot read the config")


def test_train_checks_out_before_any_work(capsys, tmp_path):
    a_file = tmp_path / "file"
    a_file.write_text("x")
    assert_refused(capsys, TRAIN + ["--out", a_file], "is a file")
    assert_refused(capsys, TRAIN + ["--out", a_file / "run"], "is a file")


def _run_folder(tmp_path: Path, **config) -> Path:
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(json.dumps({"k": 1, "out_dir": str(run), **config}))
    return run


@pytest.mark.parametrize("extra,message", [
    (["--k", "3"], "these flags differ"),
    (["--minutes", "5"], "these flags differ"),
    (["--config", "x.json"], "drop --config"),
    (["--out", "elsewhere"], "names another folder"),
])
def test_resume_refuses_conflicting_flags(capsys, tmp_path, extra, message):
    run = _run_folder(tmp_path)
    assert_refused(capsys, TRAIN + ["--resume", run] + extra, message)


@pytest.mark.parametrize("retired", [{"n_objects": 2, "k": None}, {"env_factory": "safemanip.rl.toy:ToyReachAvoidEnv"}])
def test_a_run_folder_of_the_retired_config_format_is_refused(capsys, tmp_path, retired):
    """A run folder written before 2026-12-01 (``n_objects`` meaning k, ``env_factory``) is refused on --resume (and
    by the reader --init-from uses too) with a message naming the file and what to do, not converted (issue 43)."""
    from safemanip.rl.config import ConfigError, load_run_config

    run = _run_folder(tmp_path, **retired)
    config = {key: value for key, value in json.loads((run / "config.json").read_text()).items() if value is not None}
    (run / "config.json").write_text(json.dumps(config))
    err = assert_refused(capsys, TRAIN + ["--resume", run], f"{run / 'config.json'}: invalid training config")
    assert "retired in issue 43" in err and "re-train" in err
    with pytest.raises(ConfigError, match="retired in issue 43"):
        load_run_config(run / "config.json")


def test_resume_refuses_a_folder_that_is_not_a_run(capsys, tmp_path):
    assert_refused(capsys, TRAIN + ["--resume", tmp_path], "no config.json there")
    run = _run_folder(tmp_path)
    assert_refused(capsys, TRAIN + ["--resume", run], "no complete checkpoint")


def test_a_config_or_run_folder_naming_a_module_runs_nothing(tmp_path):
    """The attack of issue 11: ``"env_factory": "subprocess:getoutput"`` with a shell command. Refused with
    exit 2, for a config file and for a run folder on --resume, and the command never runs."""
    marker = tmp_path / "pwned"
    evil = {**EVIL, "extra_env_kwargs": {"cmd": f"touch {marker}"}}
    cfg = tmp_path / "evil.json"
    cfg.write_text(json.dumps(evil))
    done = run_safemanip(["train", "--config", cfg, "--out", tmp_path / "r1", "--no-progress"], cwd=tmp_path)
    assert done.returncode == 2 and "is not accepted" in done.stderr and "Traceback" not in done.stderr
    run = _run_folder(tmp_path, **evil)
    done = run_safemanip(["train", "--resume", run, "--no-progress"], cwd=tmp_path)
    assert done.returncode == 2 and "is not accepted" in done.stderr and "Traceback" not in done.stderr
    assert not marker.exists()


# ------------------------------------------------------------------------------------------ sweep, demo, semantics
def test_sweep_refuses_bad_input(capsys, tmp_path):
    assert_refused(capsys, ["sweep", "nope"], "no sweep named 'nope'")
    assert_refused(capsys, ["sweep"], "name a sweep")
    assert_refused(capsys, ["sweep", "fig5", "--episodes", "0"], "argument --episodes")
    assert_refused(capsys, ["sweep", "fig5", "--workers", "0"], "argument --workers")
    bad = tmp_path / "bad.json"
    bad.write_text("{")
    assert_refused(capsys, ["sweep", bad], "not valid JSON")
    a_file = tmp_path / "f"
    a_file.write_text("x")
    assert_refused(capsys, ["sweep", "fig5", "--out", a_file], "is a file")
    sem = tmp_path / "sem.json"
    sem.write_text(json.dumps({"name": "s", "figure": "table", "episodes": 1, "judge": "conservative",
                               "policies": ["policies/rarl-k2-conservative-s0.safetensors"], "n_objects": [3],
                               "selectors": ["dynamic-knn"], "semantics": ["99999999999999999999 fragile"]}))
    assert_refused(capsys, ["sweep", sem, "--out", tmp_path / "o"], "at most 8 objects")


def test_sweep_of_missing_policies_only_is_an_error(capsys, tmp_path):
    cfg = tmp_path / "s.json"
    cfg.write_text(json.dumps({"name": "s", "figure": "table", "episodes": 1, "judge": "conservative",
                               "policies": [str(tmp_path / "rarl-k2-conservative.safetensors")], "n_objects": [3],
                               "selectors": ["dynamic-knn"]}))
    assert_refused(capsys, ["sweep", cfg, "--out", tmp_path / "o"], "every cell of sweep")


@pytest.mark.parametrize("argv,message", [
    (["demo", "--seed", "-1"], "argument --seed"),
    (["demo", "--n-objects", "99"], "argument --n-objects"),
    (["render-query", "--seed", "-1"], "argument --seed"),
    (["render-query", "--k", "0"], "argument --k"),
    (["constraint-matrix", "--objects-per-scene", "0"], "argument --objects-per-scene"),
    (["constraint-matrix", "--seed", "-3"], "argument --seed"),
    (["classify-constraints", "--vlm-backend", "openai", "--vlm-timeout", "nan", "mug"], "argument --vlm-timeout"),
    (["classify-constraints", "--vlm-backend", "openai", "--vlm-attempts", "0", "mug"], "argument --vlm-attempts"),
])
def test_other_commands_refuse_bad_numbers(capsys, argv, message):
    assert_refused(capsys, argv, message)


def test_output_paths_are_checked_before_work(capsys, tmp_path):
    a_file = tmp_path / "f"
    a_file.write_text("x")
    assert_refused(capsys, ["demo", "--no-video", "--out", a_file], "is a file")
    assert_refused(capsys, ["render-query", "--vlm-backend", "none", "--out", a_file / "q"], "is a file")
    assert_refused(capsys, ["constraint-matrix", "--trials", "1", "--json", tmp_path], "is a folder")
    assert_refused(capsys, ["constraint-matrix", "--trials", "1", "--json", a_file / "m.json"], "is a file")

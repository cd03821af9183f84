"""Training runs end to end, checkpoints atomically, and resumes after SIGKILL."""

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

from safemanip.rl.checkpoint import find_checkpoint, load_policy, read_checkpoint
from safemanip.rl.config import ConfigError, TrainConfig
from conftest import ROOT, SAFEMANIP, TINY_TRAIN


def test_bad_configs_fail_before_any_work(tmp_path):
    with pytest.raises(ConfigError, match="algorithm must be"):
        TrainConfig(algorithm="ppo")
    with pytest.raises(ConfigError, match="gamma must be"):
        TrainConfig(gamma=1.5)
    with pytest.raises(ConfigError, match="unknown config key"):
        TrainConfig.from_dict({"learning_rat": 1e-3})
    with pytest.raises(ConfigError, match="layout must be one of route, narrow, gate, exit, got 'tight'"):
        TrainConfig(env={"layout": "tight"})
    with pytest.raises(ConfigError, match="layout 'narrow' keeps a route clear"):
        TrainConfig(env={"layout": "narrow", "clear_route": False})
    assert TrainConfig(env={"layout": "narrow"}).env_kwargs["layout"] == "narrow"
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ConfigError, match="not valid JSON"):
        TrainConfig.from_file(bad)


def test_cli_rejects_a_bad_config_with_a_message(tmp_path):
    out = subprocess.run([*SAFEMANIP, "train", "--gamma", "2", "--out", str(tmp_path / "r")],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 2
    assert "argument --gamma: must be in (0, 1), got 2" in out.stderr
    assert not (tmp_path / "r").exists()


def _start(cmd, log):
    return subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)


@pytest.mark.slow
def test_sigkill_then_resume_loses_at_most_one_checkpoint_interval(tmp_path):
    cfg_file = tmp_path / "tiny.json"
    cfg_file.write_text(json.dumps({**TINY_TRAIN, "minutes": 0.5, "total_env_steps": 10**7}))
    run = tmp_path / "run"
    base = [*SAFEMANIP, "train", "--config", str(cfg_file), "--out", str(run), "--no-progress"]
    with open(tmp_path / "log1.txt", "w") as log:
        proc = _start(base, log)
        deadline = time.time() + 90
        while time.time() < deadline:  # wait for a checkpoint with some learning in it
            ckpt = find_checkpoint(run)
            if ckpt is not None and json.loads((ckpt / "meta.json").read_text())["updates"] > 0:
                break
            time.sleep(0.5)
        else:
            proc.kill()
            pytest.fail("no checkpoint within 90 s: " + (tmp_path / "log1.txt").read_text()[-2000:])
        time.sleep(1.0)
        os.killpg(proc.pid, signal.SIGKILL)  # the whole group, mid-run, no clean-up
        proc.wait()
    _, _, meta_before = read_checkpoint(find_checkpoint(run))
    assert not (run / "summary.json").exists()
    config = json.loads((run / "config.json").read_text())  # a budget may change on resume: a short one
    (run / "config.json").write_text(json.dumps({**config, "total_env_steps": meta_before["env_steps"] + 2000}))
    with open(tmp_path / "log2.txt", "w") as log:
        resumed = subprocess.run([*SAFEMANIP, "train", "--resume", str(run), "--no-progress"],
                                 stdout=log, stderr=subprocess.STDOUT, timeout=180)
    text = (tmp_path / "log2.txt").read_text()
    assert resumed.returncode == 0, text[-2000:]
    assert "resuming" in text
    summary = json.loads((run / "summary.json").read_text())
    assert summary["env_steps"] > meta_before["env_steps"]
    assert summary["updates"] > meta_before["updates"]
    assert meta_before["elapsed_s"] >= 2.0  # the checkpoint carried the work done before the kill
    actor, meta = load_policy(run / "policy.safetensors")
    assert meta["k"] == 1 and meta["updates"] == summary["updates"]


def test_policy_file_is_validated(tmp_path):
    from safetensors.numpy import save_file
    import numpy as np

    fake = tmp_path / "fake.safetensors"
    save_file({"x": np.zeros(3, np.float32)}, str(fake))
    with pytest.raises(ValueError, match="not a safemanip policy"):
        load_policy(fake)
    with pytest.raises(ValueError, match="no policy file"):
        load_policy(tmp_path / "missing.safetensors")


def test_every_shipped_policy_and_training_record_is_in_the_current_format():
    """The retired formats (issue 43: ``n_objects`` for k, ``env_factory``) are refused, so nothing shipped may still
    use them: every policy in the package and in results/policies loads, and its training config and every training record under
    results/training read as a TrainConfig."""
    from safemanip.rl.config import load_run_config
    from safemanip.rl.policy_index import PACKAGE_POLICIES

    policies = sorted(PACKAGE_POLICIES.glob("*.safetensors")) + sorted((ROOT / "results" / "policies").glob("*.safetensors"))
    records = sorted((ROOT / "results" / "training").glob("*/config.json"))
    assert policies and records
    for path in policies:
        _, meta = load_policy(path)
        TrainConfig.from_dict(meta["train_config"])
    for path in records:
        load_run_config(path)

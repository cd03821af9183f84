"""One typed env config (``env.config.EnvConfig``) between training, a policy's metadata, evaluation and the env."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest
from conftest import ROOT, SAFEMANIP, SUBPROCESS_ENV, TINY_TRAIN, assert_refused
from safetensors import safe_open

from safemanip.env.config import EnvConfig, EnvConfigError
from safemanip.env.slide_out import SlideOutEnv
from safemanip.rl.checkpoint import load_policy
from safemanip.rl.config import TrainConfig


def test_a_policy_s_recorded_settings_are_its_training_config_s():
    _, meta = load_policy("rarl-k2-conservative-s0")
    config = EnvConfig.from_kwargs(meta["env_kwargs"])
    assert config.kwargs() == meta["env_kwargs"] == TrainConfig.from_dict(meta["train_config"]).env_kwargs
    env = SlideOutEnv(config)
    assert env.config == config and env.scene_config == config.scene() and env.config.layout == "exit"
    assert SlideOutEnv(**config.kwargs()).config == config  # keywords (gym.make's way) make the same config


def test_keywords_beside_a_config_change_it_and_are_checked_once_by_the_config():
    base = EnvConfig(n_objects=3, layout="exit", classes=("fragile", "soft", "durable"))
    env = SlideOutEnv(base, max_episode_steps=50)
    assert env.config == EnvConfig(n_objects=3, layout="exit", classes=("fragile", "soft", "durable"),
                                   max_episode_steps=50) and env.max_episode_steps == 50
    assert SlideOutEnv(n_objects=2, classes="1 fragile, 1 soft").config.classes == ("fragile", "soft")
    with pytest.raises(EnvConfigError, match="max_episode_steps must be an integer"):
        SlideOutEnv(base, max_episode_steps=0)
    with pytest.raises(EnvConfigError, match="unknown setting"):
        SlideOutEnv(n_objects=2, speed=3)  # not a TypeError from deep inside
    with pytest.raises(ValueError, match="config must be an env.config.EnvConfig"):
        SlideOutEnv({"n_objects": 2})


@pytest.mark.parametrize("kwargs, message", [
    ({"n_objects": 2, "speed": 3}, "unknown setting"), ({"layout": "tight"}, "layout must be one of"),
    ({"constraints": "some"}, "constraints must be one of"), ({"embodiment": "ur5"}, "embodiment must be one of"),
    ({"object_size": "yes"}, "object_size must be true or false"), ({"max_episode_steps": 0}, "max_episode_steps"),
    ({"exit_share": 2.0}, "exit_share"), ({"n_objects": 9}, "n_objects")])
def test_bad_settings_are_refused_by_name(kwargs, message):
    with pytest.raises(EnvConfigError, match=message):
        EnvConfig.from_kwargs(kwargs)


def test_settings_left_unset_are_not_recorded():
    assert "gate_share" not in EnvConfig().kwargs() and EnvConfig(gate_share=1.0).kwargs()["gate_share"] == 1.0


# ------------------------------------------------------------------------------------------ a new env option
DUMMY_FIELD = '''    dummy_gain: float = 1.0
    """A test's option: any positive number."""
'''
DUMMY_CHECK = '''        if not (is_real(self.dummy_gain) and self.dummy_gain > 0):
            problems.append(f"dummy_gain must be a positive number, got {brief(self.dummy_gain)}")
'''


def _package_with_a_dummy_option(tmp_path: Path) -> dict:
    """A copy of the package whose ``EnvConfig`` has one more setting, ``dummy_gain``, and its check: the whole change
    an env option needs. Returns the environment that runs ``safemanip`` from the copy."""
    src = tmp_path / "src"
    shutil.copytree(ROOT / "src" / "safemanip", src / "safemanip", ignore=shutil.ignore_patterns("__pycache__"))
    config = src / "safemanip" / "env" / "config.py"
    text = config.read_text()
    field_anchor = '    object_size: bool = False\n    """Each observation slot also carries the object\'s footprint radius."""\n'
    check_anchor = "        if problems:\n            raise EnvConfigError("
    assert text.count(field_anchor) == 1 and text.count(check_anchor) == 1, "EnvConfig changed: update this test"
    config.write_text(text.replace(field_anchor, field_anchor + DUMMY_FIELD)
                      .replace(check_anchor, DUMMY_CHECK + check_anchor))
    return {**SUBPROCESS_ENV, "PYTHONPATH": os.pathsep.join([str(src), SUBPROCESS_ENV["PYTHONPATH"]])}


def test_a_new_env_option_is_one_change_to_env_config_from_flag_to_evaluation(capsys, tmp_path):
    """Issue 43's check: an option added to ``EnvConfig`` alone is a ``safemanip train`` flag, a training-config
    setting, part of the policy's metadata and of the env its evaluation builds, and an ``eval`` flag, with no other
    file touched."""
    env = _package_with_a_dummy_option(tmp_path)

    def safemanip(*args):
        return subprocess.run([*SAFEMANIP, *map(str, args)], capture_output=True, text=True, timeout=600,
                              cwd=tmp_path, env=env)

    assert "--dummy-gain DUMMY_GAIN" in safemanip("train", "--help").stdout
    cfg = tmp_path / "tiny.json"
    cfg.write_text(json.dumps({**TINY_TRAIN, "backend": "inline", "precision": "fp32", "minutes": None}))
    refused = safemanip("train", "--config", cfg, "--dummy-gain", "-1", "--out", tmp_path / "bad", "--no-progress")
    assert refused.returncode == 2 and "dummy_gain must be a positive number, got -1.0" in refused.stderr
    assert not (tmp_path / "bad").exists()  # refused before any work

    run = tmp_path / "run"
    done = safemanip("train", "--config", cfg, "--dummy-gain", "0.5", "--max-episode-steps", "30",
                     "--total-env-steps", "600", "--out", run, "--no-progress")
    assert done.returncode == 0, done.stderr[-2000:]
    assert json.loads((run / "config.json").read_text())["env"]["dummy_gain"] == 0.5  # the training config
    with safe_open(str(run / "policy.safetensors"), "numpy") as f:
        meta = json.loads(f.metadata()["meta"])
    assert meta["env_kwargs"]["dummy_gain"] == 0.5 and meta["train_config"]["env"]["dummy_gain"] == 0.5

    evaluated = safemanip("eval", "--policy", run / "policy.safetensors", "--episodes", "2", "--workers", "1",
                          "--out", tmp_path / "eval")
    assert evaluated.returncode == 0, evaluated.stderr[-2000:]
    summary = json.loads((tmp_path / "eval" / "summary.json").read_text())
    assert summary["eval"]["env_kwargs"]["dummy_gain"] == 0.5  # the env the evaluation built
    assert "--dummy-gain DUMMY_GAIN" in safemanip("eval", "--help").stdout  # an evaluation may change it
    changed = safemanip("eval", "--policy", run / "policy.safetensors", "--episodes", "1", "--workers", "1",
                        "--dummy-gain", "2", "--out", tmp_path / "eval2")
    assert changed.returncode == 0, changed.stderr[-2000:]
    assert json.loads((tmp_path / "eval2" / "summary.json").read_text())["eval"]["env_kwargs"]["dummy_gain"] == 2.0

    # and this package, which has no such option, refuses the policy rather than dropping the setting
    assert_refused(capsys, ["eval", "--policy", run / "policy.safetensors", "--episodes", "1", "--workers", "1"],
                   "unknown setting(s) ['dummy_gain']")

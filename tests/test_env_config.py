"""One typed env config (``env.config.EnvConfig``) between training, a policy's metadata, evaluation and the env."""

from __future__ import annotations

import pytest

from safemanip.env.config import EnvConfig, EnvConfigError
from safemanip.env.slide_out import SlideOutEnv
from safemanip.rl.checkpoint import load_policy
from safemanip.rl.config import TrainConfig


def test_a_policy_s_recorded_settings_are_its_training_config_s():
    _, meta = load_policy("rarl-k2-conservative-s0")
    config = EnvConfig.from_kwargs(meta["env_kwargs"])
    assert config.kwargs() == meta["env_kwargs"] == TrainConfig.from_dict(meta["train_config"]).env_kwargs
    env = SlideOutEnv(**config.kwargs())
    assert env.config == config.scene() and env.config.layout == "exit"


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

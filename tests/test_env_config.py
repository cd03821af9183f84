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

"""A new robot or a new layout is one entry in one registry: ``scene.embodiment.EMBODIMENTS`` and
``scene.placement.LAYOUTS``. Registering a dummy one makes the env, the training config, the CLI and the planner
take it, with nothing else changed."""

from __future__ import annotations

import numpy as np
import pytest

from safemanip.cli import build_parser
from safemanip.control.planner import GridPlanner
from safemanip.env.slide_out import SlideOutEnv
from safemanip.rl.config import TrainConfig
from safemanip.scene import embodiment, placement
from safemanip.scene.hand import CartesianHand


class StubbyHand(CartesianHand):
    """A robot of its own: the ablation's hand with a shorter lift range and a name."""

    name = "stubby"
    lift_range = (0.0, 0.01)


def test_a_robot_is_one_registry_line(monkeypatch):
    monkeypatch.setitem(embodiment.EMBODIMENTS, "stubby", StubbyHand)
    env = SlideOutEnv(n_objects=2, embodiment="stubby")
    obs, info = env.reset(seed=0)
    obs, *_ = env.step(np.array([0.5, 0.0, 0.0], dtype=np.float32))
    assert env.observation_space.contains(obs)
    assert TrainConfig(env={"embodiment": "stubby"}).env.embodiment == "stubby"
    args = build_parser().parse_args(["train", "--embodiment", "stubby", "--out", "x"])
    assert getattr(args, "env:embodiment") == "stubby"
    planner = GridPlanner()
    planner.reset(env)  # it asks the robot where the box can be held (here: anywhere)
    assert planner._space is not None


def test_every_robot_names_a_controller():
    """The controllers live a layer above the models (``control/cartesian.py``); each model names its own, and a
    model subclass (``StubbyHand``) drives with its parent's."""
    from safemanip.control.cartesian import CONTROLLERS, HandController, make_controller

    assert all(robot.controller in CONTROLLERS for robot in embodiment.EMBODIMENTS.values())
    assert isinstance(make_controller(StubbyHand()), HandController)


def test_an_unknown_robot_is_refused_with_the_registry_s_names():
    with pytest.raises(ValueError, match="embodiment"):
        SlideOutEnv(n_objects=1, embodiment="stubby")


def test_a_layout_is_one_registry_line(monkeypatch):
    wide = placement.RouteLayout(clearance=0.05, near_gap=0.06, inner_share=0.5, near_fraction=0.5, exit_share=1.0)
    monkeypatch.setitem(placement.LAYOUTS, "wide-exit", wide)
    env = SlideOutEnv(n_objects=3, layout="wide-exit", constraints="conservative")
    _, info = env.reset(seed=0)
    assert info["scene_kind"] in ("exit", "open") and env.placement.route.layout is wide
    assert TrainConfig(env={"layout": "wide-exit"}).env_kwargs["layout"] == "wide-exit"
    args = build_parser().parse_args(["eval", "--planner", "all", "--n-objects", "3", "--layout", "wide-exit"])
    assert getattr(args, "env:layout") == "wide-exit"

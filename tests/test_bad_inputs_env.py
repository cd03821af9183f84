"""Bad inputs, second round (issue 28): the env's public API. ``SlideOutEnv(...)``, ``reset(seed, options)`` and
``step(action)`` refuse what they cannot use with a ValueError that names the argument: unknown reset options or
option values (never silently ignored), actions that are complex, text, booleans, of the wrong size or so large
that their length overflows (1e308 is finite, its square is not), and a render size the offscreen buffer cannot
hold; no KeyError or TypeError from deep inside."""

from __future__ import annotations

import numpy as np
import pytest

from safemanip.env.slide_out import SlideOutEnv


@pytest.fixture(scope="module")
def env():
    e = SlideOutEnv(n_objects=2)
    e.reset(seed=0)
    yield e
    e.close()


@pytest.mark.parametrize("action,message", [
    (np.array([1e308, 0.0, 0.0]), "too large to use (its length overflows)"),
    ([1e200, 1e200, 0.0], "too large to use"),
    (np.array([-1e160, 0.0, 1e160]), "too large to use"),
    (np.array([1 + 2j, 0, 0]), "must be 3 real numbers"),
    ([0.1j, 0.0, 0.0], "must be 3 real numbers"),
    ("abc", "must be 3 real numbers"),
    (["0.1", "0.2", "0.3"], "must be 3 real numbers"),
    (None, "must be 3 real numbers"),
    ({"x": 1.0}, "must be 3 real numbers"),
    ([True, False, True], "must be 3 real numbers"),
    ([0.1, 0.2], "must be 3 real numbers"),
    (np.zeros((2, 3)), "must be 3 real numbers"),
    ([[0.1], [0.2, 0.3]], "must be 3 real numbers"),
    ([np.nan, 0.0, 0.0], "action must be finite"),
    ([np.inf, 0.0, 0.0], "action must be finite"),
])
def test_step_refuses_an_action_it_cannot_use(env, action, message):
    with pytest.raises(ValueError, match="action") as err:
        env.step(action)
    assert message in str(err.value)


def test_step_still_takes_ordinary_actions(env):
    env.reset(seed=1)
    for action in ([0.1, 0.0, 0.0], np.array([0.2, -0.1, 0.0], np.float32), np.array([[1, 0, 0]]), (3.0, 0.0, 0.0)):
        obs, reward, terminated, truncated, info = env.step(action)
        assert np.isfinite(obs).all()
        if terminated or truncated:
            env.reset(seed=1)


@pytest.mark.parametrize("kwargs,message", [
    ({"options": {"name": ["red mug", "toy sheep"]}}, "unknown option(s) ['name']"),
    ({"options": {"names": ["red mug", "toy sheep"], "layout": "narrow"}}, "unknown option(s) ['layout']"),
    ({"options": {"constraints": "bogus"}}, "options['constraints'] must be one of"),
    ({"options": {"constraints": ["no_contact"]}}, "options['constraints'] must be one of"),
    ({"options": {"constraints": ["no_contact", "gentle"]}}, "options['constraints'] must be one of"),
    ({"options": {"constraints": 3}}, "options['constraints'] must be one of"),
    ({"options": {"names": ["red mug", "unicorn"]}}, "unknown: ['unicorn']"),
    ({"options": {"names": ["red mug", "red mug"]}}, "distinct"),
    ({"options": {"names": "red mug"}}, "options['names'] must be a list"),
    ({"options": {"names": [1, 2]}}, "options['names'] must be a list"),
    ({"options": {"names": ["red mug"]}}, "must hold 2 names"),
    ({"options": ["names"]}, "options must be a dict"),
    ({"seed": -1}, "seed must be None or a non-negative integer"),
    ({"seed": "7"}, "seed must be None or a non-negative integer"),
    ({"seed": 1.5}, "seed must be None or a non-negative integer"),
    ({"seed": True}, "seed must be None or a non-negative integer"),
])
def test_reset_refuses_unknown_options_and_values(env, kwargs, message):
    with pytest.raises(ValueError, match="reset") as err:
        env.reset(**kwargs)
    assert message in str(err.value)


def test_reset_takes_the_documented_options(env):
    _, info = env.reset(seed=3, options={"names": ["soda can", "tennis ball"], "constraints": ["no_contact", "any_contact"]})
    assert info["names"] == ("soda can", "tennis ball") and info["constraints"] == ("no_contact", "any_contact")
    _, info = env.reset(seed=np.int64(3), options={"constraints": "conservative"})
    assert info["constraints"] == ("no_contact", "no_contact")


@pytest.mark.parametrize("kwargs,message", [
    ({"render_size": (0, 640)}, "render_size must be (height, width)"),
    ({"render_size": (480, 100_000)}, "render_size must be (height, width)"),
    ({"render_size": (480.0, 640.0)}, "render_size must be (height, width)"),
    ({"render_size": "480x640"}, "render_size must be (height, width)"),
    ({"render_size": (480, 640, 3)}, "render_size must be (height, width)"),
    ({"names": 5}, "names must be a list of catalog names"),
    ({"names": "red mug"}, "names must be a list of catalog names"),
    ({"classes": 3}, "classes must be a list of semantic classes"),
    ({"constraints": 7}, "constraints must be one of"),
    ({"near_path_fraction": "x"}, "near_path_fraction must be a number in [0, 1]"),
    ({"clear_route": "no"}, "clear_route must be true or false"),
    ({"sleep": 0}, "sleep must be true or false"),
    ({"visual": "yes"}, "visual must be true, false or None"),
    ({"layout": ["route"]}, "layout must be one of"),
    ({"embodiment": ["panda"]}, "embodiment must be one of"),
    ({"slot_order": None}, "slot_order must be one of"),
    ({"action_curve": True}, "action_curve must be a number"),
    ({"action_curve": "2"}, "action_curve must be a number"),
    ({"render_mode": 5}, "render_mode must be None or 'rgb_array'"),
    ({"thresholds": {"collision": 0.01}}, "thresholds must be an env.margins.Thresholds"),
])
def test_constructor_refuses_bad_arguments_by_name(kwargs, message):
    with pytest.raises(ValueError) as err:
        SlideOutEnv(n_objects=2, **kwargs)
    assert message in str(err.value)


def test_a_render_size_within_the_buffer_renders(gl):
    env = SlideOutEnv(n_objects=1, render_size=(120, 160), visual=True)
    try:
        env.reset(seed=0)
        frame = env.render_camera("front")
        assert frame.shape == (120, 160, 3)
    finally:
        env.close()


def test_every_form_of_an_action_steps_the_same(env):
    """A float32 or float64 vector (the shortcut in ``_action_vector``) steps exactly as the same numbers given as a
    list, a tuple or a (1, 3) array (the general checks)."""
    forms = (np.array([0.3, -0.2, 0.1], np.float32), np.array([0.3, -0.2, 0.1], np.float32).astype(np.float64),
             [float(np.float32(0.3)), float(np.float32(-0.2)), float(np.float32(0.1))],
             tuple(np.array([0.3, -0.2, 0.1], np.float32).tolist()), np.array([[0.3, -0.2, 0.1]], np.float32))
    results = []
    for action in forms:
        env.reset(seed=4)
        obs, reward, *_ = env.step(action)
        results.append((obs, reward))
    for obs, reward in results[1:]:
        np.testing.assert_array_equal(obs, results[0][0])
        assert reward == results[0][1]

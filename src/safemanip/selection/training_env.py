"""Selection-aware training: the full N-object slide-out env seen through the deployment pipeline.

``SelectedSlotsEnv`` holds a ``SlideOutEnv`` with N objects (the judge: its margins, failures and
rewards cover every object) and gives the policy the k-slot observation deployment would give it:
an object selector (``dynamic-knn`` or ``dynamic-radius``) re-picks on its schedule (every 4 control
steps by default), and the ``Reducer`` builds s_rel from the picked objects, nearest to the held box
first, exactly as ``evaluation/episode.py`` does at test time. Constraint one-hots are the env's own
(the ground-truth constraint selector of training scenes); a ``conservative`` policy sees
``no_contact`` everywhere, as in the reducer.

Why it lives here: ``selection`` sits above ``env`` and beside ``rl``; ``rl`` imports nothing from
``selection``, and this module takes only the registry's ``register_env`` from ``rl``. The env
registry (``rl/envs.py``) fixes the name ``slide-out-selected`` (``SELECTED_ENV``), which
``TrainConfig.rollout_env_kwargs`` chooses for selection-aware training; importing this module hands
the registry its factory. ``safemanip train`` imports it; so must any other caller of
``rl.train.train`` that trains selection-aware. No name read from a config is ever imported.
"""

from __future__ import annotations

import gymnasium as gym

from safemanip.env.observation import observation_space
from safemanip.env.slide_out import SlideOutEnv
from safemanip.rl.envs import SELECTED_ENV, register_env
from safemanip.selection.reducer import Reducer
from safemanip.selection.selectors import DEFAULT_INTERVAL, DEFAULT_RADIUS, DynamicKNN, DynamicRadius
from safemanip.selection.view import EnvViewBuilder

TRAINING_SELECTORS = {"dynamic-knn": lambda interval, radius: DynamicKNN(interval),
                      "dynamic-radius": lambda interval, radius: DynamicRadius(interval, radius)}


class SelectedSlotsEnv(gym.Env):
    """A k-slot view of an N-object scene; ``step``/``reset`` return the env's info (judged on all N)."""

    def __init__(self, k: int, n_objects: int, selector: str = "dynamic-knn", radius: float = DEFAULT_RADIUS,
                 interval: int = DEFAULT_INTERVAL, constraints: str = "conservative", slot_order: str | None = None,
                 object_size: bool = False, **env_kwargs):
        if selector not in TRAINING_SELECTORS:
            raise ValueError(f"selector must be one of {sorted(TRAINING_SELECTORS)}, got {selector!r}")
        if not 0 <= k <= n_objects and selector == "dynamic-knn":
            raise ValueError(f"dynamic-knn needs k <= N, got k={k}, N={n_objects}")
        del slot_order  # the reducer orders the slots (nearest first), as at deployment
        self.env = SlideOutEnv(n_objects=n_objects, constraints=constraints, object_size=object_size, **env_kwargs)
        self.k = int(k)
        # a varying number of picks leaves slots empty: zeros, which a set network masks out
        self.reducer = Reducer(self.k, "all" if constraints == "random" else "conservative",
                               empty_slots=selector == "dynamic-radius", object_size=self.env.object_size)
        self.selector = TRAINING_SELECTORS[selector](interval, radius)
        self.builder = EnvViewBuilder()
        self.observation_space = observation_space(self.k, self.env.object_size)
        self.action_space = self.env.action_space
        self.max_episode_steps = self.env.max_episode_steps
        self.selected: list[int] = []

    def _observe(self, t: int):
        state = self.env.scene_state()
        view = self.builder.view(self.env, state, t)
        if t == 0:
            self.selector.reset(view, self.k)
        self.selected = self.selector.select(view, self.k)
        return self.reducer(state, self.selected, self.env.constraints)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        _, info = self.env.reset(seed=seed, options=options)
        self.builder.reset(self.env)
        return self._observe(0), info

    def step(self, action):
        _, reward, terminated, truncated, info = self.env.step(action)
        return self._observe(info["t"]), reward, terminated, truncated, info

    def close(self):
        self.env.close()


register_env(SELECTED_ENV, SelectedSlotsEnv)

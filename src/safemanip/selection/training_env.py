"""Selection-aware training: the full N-object slide-out env seen through the deployment pipeline.

``SelectedSlotsEnv`` holds a ``SlideOutEnv`` with N objects (the judge: its margins, failures and
rewards cover every object) and gives the policy the k-slot observation deployment would give it:
an object selector (``dynamic-knn`` or ``dynamic-radius``, or ``mixed``: one of the two drawn per episode)
re-picks on its schedule (every 4 control steps by default), and the ``Reducer`` builds s_rel from the
picked objects, nearest to the held box first, exactly as ``evaluation/episode.py`` does at test time. With mixed clutter (``min_objects``)
each episode draws its N, and slots a sparse scene cannot fill are padded as deployment pads them.
Constraint one-hots are the env's own (the ground-truth constraint selector of training scenes); a
``conservative`` policy sees ``no_contact`` everywhere, as in the reducer.

Why it lives here: ``selection`` sits above ``env`` and beside ``rl``, and the two import nothing from each
other. The env registry (``rl/envs.py``) fixes the name ``slide-out-selected`` (``SELECTED_ENV``), which
``TrainConfig.rollout_env_kwargs`` chooses for selection-aware training; the caller of the training loop passes
this class as its env factory, ``rl.train.train(cfg, env_factory=SelectedSlotsEnv)``, as ``safemanip train`` does
(importing this module registers nothing). No name read from a config is ever imported.
"""

from __future__ import annotations

import gymnasium as gym

from safemanip.env.observation import observation_space
from safemanip.env.slide_out import SlideOutEnv
from safemanip.selection.reducer import Reducer
from safemanip.selection.selectors import DEFAULT_INTERVAL, DEFAULT_RADIUS, DynamicKNN, DynamicRadius
from safemanip.selection.view import EnvViewBuilder

TRAINING_SELECTORS = {"dynamic-knn": lambda interval, radius: DynamicKNN(interval),
                      "dynamic-radius": lambda interval, radius: DynamicRadius(interval, radius)}
MIXED = "mixed"
"""Each episode draws one of ``TRAINING_SELECTORS``: a policy trained so is used with either at deployment (a
set network trained with the radius selector alone fails when handed a fixed k of far-away objects)."""


class SelectedSlotsEnv(gym.Env):
    """A k-slot view of an N-object scene; ``step``/``reset`` return the env's info (judged on all N)."""

    def __init__(self, k: int, n_objects: int, selector: str = "dynamic-knn", radius: float = DEFAULT_RADIUS,
                 interval: int = DEFAULT_INTERVAL, constraints: str = "conservative", slot_order: str | None = None,
                 object_size: bool = False, min_objects: int | None = None, empty_slots: bool | None = None,
                 **env_kwargs):
        """``min_objects``: mixed clutter, each episode's scene holds N drawn uniformly from ``min_objects`` to
        ``n_objects``. ``empty_slots``: slots no object fills are left all zero (absent, for a set network);
        otherwise they hold far-away dummy objects, as ``--pad`` gives a flat policy at deployment. Default:
        empty for ``dynamic-radius``, whose picks vary in number."""
        if selector not in TRAINING_SELECTORS and selector != MIXED:
            raise ValueError(f"selector must be one of {sorted(TRAINING_SELECTORS) + [MIXED]}, got {selector!r}")
        fewest = n_objects if min_objects is None else int(min_objects)
        if min_objects is not None and not 1 <= fewest <= n_objects:
            raise ValueError(f"min_objects must be in 1..n_objects ({n_objects}), got {min_objects}")
        if not 0 <= k <= n_objects and selector in ("dynamic-knn", MIXED):
            raise ValueError(f"dynamic-knn needs k <= N, got k={k}, N={n_objects}")
        del slot_order  # the reducer orders the slots (nearest first), as at deployment
        self.k = int(k)
        self.scene_sizes = list(range(fewest, n_objects + 1))
        """The numbers of objects a scene may hold (one, unless mixed clutter)."""
        # one env per scene size, each with its compiled models; built when first drawn
        self._make_env = lambda n: SlideOutEnv(n_objects=n, constraints=constraints, object_size=object_size,
                                               **env_kwargs)
        self._envs = {n_objects: self._make_env(n_objects)}
        self.env = self._envs[n_objects]
        empty = selector in ("dynamic-radius", MIXED) if empty_slots is None else bool(empty_slots)
        # a varying number of picks (or objects) leaves slots to fill: zeros, which a set network masks out, or
        # dummies far from the path for a flat policy
        self.reducer = Reducer(self.k, "all" if constraints == "random" else "conservative",
                               pad=not empty and fewest < self.k, empty_slots=empty, object_size=self.env.object_size)
        names = sorted(TRAINING_SELECTORS) if selector == MIXED else [selector]
        self._selectors = {name: TRAINING_SELECTORS[name](interval, radius) for name in names}
        self.selector_name = names[0]
        """The selector of the current episode."""
        self.selector = self._selectors[self.selector_name]
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
        if len(self.scene_sizes) > 1 or len(self._selectors) > 1:
            # mixed clutter or selectors: this env's generator draws the scene size, the selector and the
            # scene's seed, so a seeded stream of episodes is reproducible whichever come up
            super().reset(seed=seed)
            if len(self.scene_sizes) > 1:
                n = self.scene_sizes[int(self.np_random.integers(len(self.scene_sizes)))]
                if n not in self._envs:
                    self._envs[n] = self._make_env(n)
                self.env = self._envs[n]
            if len(self._selectors) > 1:
                names = list(self._selectors)
                self.selector_name = names[int(self.np_random.integers(len(names)))]
                self.selector = self._selectors[self.selector_name]
            seed = int(self.np_random.integers(1 << 31))
        _, info = self.env.reset(seed=seed, options=options)
        self.builder.reset(self.env)
        return self._observe(0), info

    def step(self, action):
        _, reward, terminated, truncated, info = self.env.step(action)
        return self._observe(info["t"]), reward, terminated, truncated, info

    def close(self):
        for env in self._envs.values():
            env.close()

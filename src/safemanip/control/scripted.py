"""A scripted controller: a fast pull to the right out from under the top box, then a slide that slows
down into the goal (the box must come to rest there to count as placed).

It ignores the clutter, so it fails whenever an object stands in its way; it is the baseline the
learned policies have to beat, and a quick way to see the task.
"""

from __future__ import annotations

import numpy as np


class ScriptedController:
    def __init__(self, pull_speed: float = 1.0, slide_speed: float = 0.25, lift: float = 0.0):
        """Speeds are fractions of the env's maximum speed (1.0 = the Panda's 1.7 m/s)."""
        self.pull_speed = pull_speed
        self.slide_speed = slide_speed
        self.lift = lift

    def reset(self, env=None) -> None:
        """Start a new episode (``env`` is accepted for the planner's signature; this controller needs no map)."""
        self._pulled_out = False

    def act(self, info: dict, env) -> np.ndarray:
        """Action in [-1, 1]^3 from the env's info (margins) and its state."""
        state = env.scene_state()
        if not self._pulled_out and info["margins"]["l1"] <= 0.0:
            return np.array([self.pull_speed, 0.0, self.lift], dtype=np.float32)
        self._pulled_out = True
        to_goal = np.asarray(env.geometry.goal_xy) - state.bottom_pos[:2]
        step = to_goal / env.max_step
        norm = np.linalg.norm(step)
        if norm > self.slide_speed:
            step *= self.slide_speed / norm
        return np.array([step[0], step[1], 0.0], dtype=np.float32)

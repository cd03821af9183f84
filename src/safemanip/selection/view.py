"""Building a ``SceneView`` from a running ``SlideOutEnv``, step by step.

The view holds what a robot could observe (names, object positions and velocities, the paths of the
end-effector and of the manipulated box) plus the judge's ground-truth classes for privileged
selectors, and a lazy ``render`` callable: frames are only rendered when a selector calls it (the
Dynamic-VLM selector with an image backend), so kNN evaluations never touch OpenGL.
"""

from __future__ import annotations

import numpy as np

from safemanip.env.observation import SceneState
from safemanip.scene.catalog import CONSTRAINT_OF_CLASS
from safemanip.selection.base import SceneView

CLASS_OF_CONSTRAINT = {c: cls for cls, c in CONSTRAINT_OF_CLASS.items()}


class EnvViewBuilder:
    """Call ``reset(env)`` after ``env.reset`` and ``view(env, state, t)`` once per control step.

    Paths are kept in preallocated buffers (the env's own path lists would have to be re-stacked at
    every step, quadratic in the episode length); the view's arrays are read-only slices of them.

    ``privileged_classes`` are the classes the judge uses: the class implied by each object's
    ground-truth constraint in the env (no_contact -> fragile, soft_contact -> soft, any_contact ->
    durable). Under a conservative judge every object is therefore "fragile", which is what the
    privileged selector and the ground-truth constraint selector must see to be oracles of *that* judge.
    """

    def __init__(self, camera: str = "front", render_size: tuple[int, int] | None = None):
        self.camera = camera
        self.render_size = render_size
        self.renders = 0
        self._ee = self._box = None
        self._n = 0

    def reset(self, env) -> None:
        cap = int(env.max_episode_steps) + 1
        self._ee = np.zeros((cap, 3))
        self._box = np.zeros((cap, 3))
        self._n = 0
        self._classes = tuple(CLASS_OF_CONSTRAINT[c] for c in env.constraints)
        self._names = tuple(env.names)

    def view(self, env, state: SceneState, t: int) -> SceneView:
        if self._n <= t:  # one new path point per control step (the env's path includes t = 0)
            if self._n >= len(self._ee):
                self._ee = np.concatenate([self._ee, np.zeros_like(self._ee)])
                self._box = np.concatenate([self._box, np.zeros_like(self._box)])
            self._ee[self._n] = state.ee_pos
            self._box[self._n] = state.bottom_pos
            self._n += 1
        ee_path, box_path = self._ee[:self._n], self._box[:self._n]
        ee_path.flags.writeable = False  # selectors read the view; a stray write would corrupt later views
        box_path.flags.writeable = False
        return SceneView(t=t, names=self._names, positions=state.obj_pos, velocities=state.obj_vel,
                         ee_path=ee_path, box_path=box_path, box_velocity=state.bottom_vel,
                         privileged_classes=self._classes, render=lambda: self._render(env, ee_path))

    def _render(self, env, ee_path: np.ndarray) -> dict:
        """{"image", "boxes" (object id -> pixel box), "ee_path_px"} of the current frame for a VLM."""
        from safemanip.env.render import project_points

        h, w = self.render_size or env.render_size
        self.renders += 1
        image = env.render_camera(self.camera, h, w)
        boxes = {k: v for k, v in env.object_boxes_2d(self.camera, h, w).items() if isinstance(k, int)}
        ee_px = project_points(env.model, env.data, self.camera, np.asarray(ee_path), h, w)
        return {"image": image, "boxes": boxes, "ee_path_px": ee_px}

"""``safemanip/SlideOut-v0``: pull the bottom cereal box out from under the top one, fast enough
that the top box stays put, then slide it to the goal without hurting the clutter.

One step = one 20 Hz control step = 25 physics steps of 2 ms. The action is the end-effector
displacement in [-1, 1]^3, scaled by ``max_step`` (0.1 m, i.e. up to 2 m/s): the hand's set-point
ramps from where the end-effector is to ``ee + action * max_step`` over the control step.
"""

from __future__ import annotations

from typing import Any, Sequence

import gymnasium as gym
import mujoco
import numpy as np

from safemanip.env import margins as M
from safemanip.env.observation import (SceneState, build_observation, encode_constraints, observation_space)
from safemanip.scene.builder import CONTROL_DT, TIMESTEP, SceneIndex, build_model
from safemanip.scene.catalog import CONSTRAINT_TYPES, load_catalog, names_of_class
from safemanip.scene.config import GEOMETRY, SceneConfig
from safemanip.scene.embodiment import CartesianHand
from safemanip.scene.placement import sample_placement

CONSTRAINT_MODES = ("ground_truth", "conservative", "random")
EVENTS = ("running", "success", "failure:dyn", "failure:hard", "failure:soft", "failure:oob", "timeout", "unstable")
DISTANCE_CAP = 0.3  # geom distances saturate here: far objects do not need an exact value
_MANIPULATED_REACH = 0.22  # bounding radius of the held box and palm around the box centre


class SlideOutEnv(gym.Env):
    metadata = {"render_modes": ["rgb_array"], "render_fps": int(round(1 / CONTROL_DT))}

    def __init__(self, n_objects: int = 4, names: Sequence[str] | None = None, classes: Sequence[str] | str | None = None,
                 constraints: str | Sequence[str] = "ground_truth", near_path_fraction: float = 0.5,
                 render_mode: str | None = None, max_episode_steps: int = 300, max_step: float = 0.1,
                 thresholds: M.Thresholds = M.DEFAULT_THRESHOLDS, sleep: bool = True, slot_order: str = "index",
                 render_size: tuple[int, int] = (480, 640)):
        if isinstance(classes, str):
            from safemanip.scene.config import parse_semantics
            classes = parse_semantics(classes)
        self.config = SceneConfig(n_objects=n_objects, names=tuple(names) if names else None,
                                  classes=tuple(classes) if classes else None, near_path_fraction=near_path_fraction)
        if isinstance(constraints, str):
            if constraints not in CONSTRAINT_MODES:
                raise ValueError(f"constraints must be one of {CONSTRAINT_MODES} or a list of {CONSTRAINT_TYPES}, "
                                 f"got {constraints!r}")
        else:
            constraints = tuple(constraints)
            bad = [c for c in constraints if c not in CONSTRAINT_TYPES]
            if bad or len(constraints) != n_objects:
                raise ValueError(f"give one constraint per object from {CONSTRAINT_TYPES}; got {list(constraints)}")
        if slot_order not in ("index", "nearest"):
            raise ValueError(f"slot_order must be 'index' or 'nearest', got {slot_order!r}")
        self.slot_order = slot_order
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        if max_episode_steps < 1 or max_step <= 0:
            raise ValueError("max_episode_steps must be >= 1 and max_step > 0")
        self.constraint_mode = constraints
        self.render_mode = render_mode
        self.max_episode_steps = int(max_episode_steps)
        self.max_step = float(max_step)
        self.thresholds = thresholds
        self.sleep = sleep
        self.render_size = render_size
        self.geometry = GEOMETRY
        self.hand = CartesianHand()
        self.n_substeps = int(round(CONTROL_DT / TIMESTEP))
        self.observation_space = observation_space(n_objects)
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(3,), dtype=np.float32)
        self._sims: dict[tuple[str, ...], tuple] = {}
        self._renderer = None
        self.model = self.data = None
        self.names: tuple[str, ...] = ()
        self.constraints: tuple[str, ...] = ()

    # ------------------------------------------------------------------ set-up
    def _sim(self, names: tuple[str, ...]):
        if names not in self._sims:
            model = build_model(names, self.sleep)
            data = mujoco.MjData(model)
            self._sims[names] = (model, data, SceneIndex.from_model(model, len(names)), self.hand.bind(model))
        return self._sims[names]

    def _choose_names(self, rng: np.random.Generator) -> tuple[str, ...]:
        if self.config.names is not None:
            return self.config.names
        if self.config.classes is None:
            pool = sorted(load_catalog())
            return tuple(rng.choice(pool, size=self.config.n_objects, replace=False).tolist())
        chosen: list[str] = []
        for c in self.config.classes:
            pool = [n for n in names_of_class(c) if n not in chosen]
            chosen.append(str(rng.choice(pool)))
        return tuple(chosen)

    def _choose_constraints(self, mode, rng: np.random.Generator) -> tuple[str, ...]:
        n = len(self.names)
        if not isinstance(mode, str):
            return tuple(mode)
        if mode == "conservative":
            return ("no_contact",) * n
        if mode == "random":
            return tuple(CONSTRAINT_TYPES[i] for i in rng.integers(0, 3, size=n))
        catalog = load_catalog()
        return tuple(catalog[name].constraint for name in self.names)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        options = options or {}
        rng = self.np_random
        names = tuple(options["names"]) if "names" in options else self._choose_names(rng)
        if len(names) != self.config.n_objects:
            raise ValueError(f"options['names'] must hold {self.config.n_objects} names, got {list(names)}")
        self.names = names
        self.model, self.data, self.index, self.binding = self._sim(names)
        self.constraints = self._choose_constraints(options.get("constraints", self.constraint_mode), rng)
        catalog = load_catalog()
        radii = np.array([catalog[n].footprint_radius for n in names])
        placement = sample_placement(radii, rng, self.config.near_path_fraction, self.geometry)
        m, d, idx = self.model, self.data, self.index
        mujoco.mj_resetData(m, d)
        for i in range(len(names)):
            adr = idx.object_qpos[i]
            d.qpos[adr:adr + 3] = (*placement.xy[i], 0.0005)
            d.qpos[adr + 3:adr + 7] = (np.cos(placement.yaw[i] / 2), 0, 0, np.sin(placement.yaw[i] / 2))
        mujoco.mj_forward(m, d)
        self._constraint_onehot = encode_constraints(self.constraints)
        self._top_start = d.xpos[idx.top_box_body, :2].tolist()
        self._object_is_soft = np.array([c == "soft_contact" for c in self.constraints])
        self._object_checked = np.array([c != "any_contact" for c in self.constraints], dtype=bool)
        self._checked_ids = np.flatnonzero(self._object_checked)
        self._manipulated = [int(g) for g in self.index.manipulated_geoms]
        self._margin_names = {i: f"{'g_soft' if self._object_is_soft[i] else 'g_hard'}:{i}:{name}"
                              for i, name in enumerate(self.names) if self._object_checked[i]}
        self._t = 0
        state = self.scene_state()
        terms = self._margins(state)
        return self._observe(state), self._info(terms, "running", None)

    # ------------------------------------------------------------------ dynamics
    def step(self, action):
        a = np.asarray(action, dtype=np.float64).reshape(3).clip(-1.0, 1.0)
        m, d = self.model, self.data
        self.hand.command_velocity(d, self.binding, a * (self.max_step / CONTROL_DT))
        time_before = d.time
        mujoco.mj_step(m, d, nstep=self.n_substeps)
        self._t += 1
        # On a bad qpos/qvel/qacc MuJoCo resets the whole MjData (time back to 0) and carries on: time that
        # did not advance by the full control step is the cheap trace of it; NaNs that slipped through are
        # caught by the finiteness check
        unstable = d.time < time_before + 0.5 * CONTROL_DT or not np.isfinite(d.qvel).all()
        if unstable:
            state = self._last_state
            obs = self._observe(state)
            info = self._info(self._last_terms, "unstable", None)
            return obs, 0.0, True, False, info
        state = self.scene_state()
        terms = self._margins(state)
        l, g = terms["l"], terms["g"]
        event, culprit = "running", None
        terminated = truncated = False
        if M.is_failure(g):
            event, culprit = self._failure_cause(terms)
            terminated = True
        elif M.is_success(l, g):
            event, terminated = "success", True
        elif self._t >= self.max_episode_steps:
            event, truncated = "timeout", True
        # reward: the paper's r = min(l, g); the reach-avoid learner reads l and g from info instead
        return self._observe(state), float(min(l, g)), terminated, truncated, self._info(terms, event, culprit)

    def scene_state(self) -> SceneState:
        d, idx = self.data, self.index
        top_v = idx.top_box_qvel
        ee_vel = self.hand.ee_velocity(d, self.binding).copy()
        state = SceneState(
            ee_pos=self.hand.ee_position(d, self.binding).copy(), ee_vel=ee_vel,
            bottom_pos=d.xpos[idx.bottom_box_body].copy(), bottom_vel=ee_vel,  # rigidly held
            top_pos=d.xpos[idx.top_box_body].copy(), top_vel=d.qvel[top_v:top_v + 3].copy(),
            obj_pos=d.xpos[idx.object_bodies], obj_vel=d.qvel[idx.object_qvel_flat].reshape(-1, 3))
        self._last_state = state
        return state

    # ------------------------------------------------------------------ margins
    def object_distances(self, object_ids=None) -> np.ndarray:
        """Signed distance (m, capped at 0.3) from the manipulated box and hand to each object's geoms.

        Objects whose bounding sphere is farther than the cap from the box's bounding sphere are not
        queried: their distance is the cap either way.
        """
        m, d, idx = self.model, self.data, self.index
        ids = np.arange(len(self.names)) if object_ids is None else np.asarray(object_ids, dtype=int)
        out = np.full(len(self.names), DISTANCE_CAP)
        if len(ids) == 0:
            return out
        offset = d.xpos[idx.object_bodies[ids]] - d.xpos[idx.bottom_box_body]
        gap = np.sqrt(np.einsum("ij,ij->i", offset, offset)) - idx.object_reach[ids] - _MANIPULATED_REACH
        for i in ids[gap < DISTANCE_CAP].tolist():
            best = DISTANCE_CAP
            for g1 in self._manipulated:
                for g2 in idx.object_geoms[i]:
                    dist = mujoco.mj_geomDistance(m, d, g1, int(g2), DISTANCE_CAP, None)
                    if dist < best:
                        best = dist
            out[i] = best
        return out

    def _margins(self, state: SceneState) -> dict[str, Any]:
        th, geo = self.thresholds, self.geometry
        half = geo.box_half_extents
        bottom = state.bottom_pos[:2].tolist()  # python floats: these margins are scalar maths
        top = state.top_pos[:2].tolist()
        terms: dict[str, Any] = {
            "l1": M.margin_out_from_under(bottom, top, half, half, th.out_clearance),
            "l2": M.margin_in_goal(bottom, geo.goal_xy, th.goal_radius),
            "g_dyn": M.margin_top_box(top, self._top_start, float(self.data.xmat[self.index.top_box_body, 8]),
                                      th.top_box_displacement, th.top_box_min_up),
            "g_oob": M.margin_in_workspace(bottom, geo.table_half_extents, geo.workspace_inset),
        }
        checked = self._checked_ids
        object_terms = np.full(len(self.names), np.inf)
        if len(checked):
            distances = self.object_distances(checked)
            hard = distances[checked] - th.collision
            rel = state.obj_vel[checked] - state.bottom_vel
            speed = np.sqrt(np.einsum("ij,ij->i", rel, rel))
            soft = np.maximum(hard, th.relative_speed - speed)  # = margin_soft_contact, vectorised
            object_terms[checked] = np.where(self._object_is_soft[checked], soft, hard)
            g_objects = float(object_terms[checked].min())
        else:
            distances = np.full(len(self.names), DISTANCE_CAP)
            g_objects = np.inf
        terms["objects"] = object_terms
        terms["distances"] = distances
        terms["l"] = min(terms["l1"], terms["l2"])
        terms["g"] = float(min(terms["g_dyn"], terms["g_oob"], g_objects))
        self._last_terms = terms
        return terms

    def _failure_cause(self, terms) -> tuple[str, int | None]:
        candidates = {"failure:dyn": terms["g_dyn"], "failure:oob": terms["g_oob"]}
        worst_obj = None
        if len(self.names) and np.isfinite(terms["objects"]).any():
            worst_obj = int(np.argmin(terms["objects"]))
            kind = "failure:soft" if self._object_is_soft[worst_obj] else "failure:hard"
            candidates[kind] = terms["objects"][worst_obj]
        event = min(candidates, key=candidates.get)
        return event, (worst_obj if event in ("failure:hard", "failure:soft") else None)

    # ------------------------------------------------------------------ outputs
    def slot_ids(self, state: SceneState) -> np.ndarray:
        """Object ids in observation-slot order: scene order, or nearest to the held box first."""
        if self.slot_order == "index" or len(self.names) < 2:
            return np.arange(len(self.names))
        offset = state.obj_pos[:, :2] - state.bottom_pos[:2]
        return np.argsort(np.einsum("ij,ij->i", offset, offset), kind="stable")

    def _observe(self, state: SceneState) -> np.ndarray:
        ids = self.slot_ids(state)
        return build_observation(state, ids, self._constraint_onehot[ids])

    def _info(self, terms, event: str, culprit: int | None) -> dict:
        margins = {"l1": terms["l1"], "l2": terms["l2"], "g_dyn": terms["g_dyn"], "g_oob": terms["g_oob"]}
        objects = terms["objects"]
        for i, key in self._margin_names.items():
            margins[key] = float(objects[i])
        return {"l": float(terms["l"]), "g": float(terms["g"]), "margins": margins, "event": event,
                "object": self.names[culprit] if culprit is not None else None, "object_id": culprit,
                "t": self._t, "names": self.names, "constraints": self.constraints,
                "is_success": event == "success"}

    # ------------------------------------------------------------------ rendering
    def render(self):
        if self.render_mode == "rgb_array":
            return self.render_camera("front")
        return None

    def _get_renderer(self, height: int, width: int):
        from safemanip.env.render import make_renderer
        key = (id(self.model), height, width)
        if self._renderer is None or self._renderer[0] != key:
            if self._renderer is not None:
                self._renderer[1].close()
            self._renderer = (key, make_renderer(self.model, height, width))
        return self._renderer[1]

    def render_camera(self, camera: str = "front", height: int | None = None, width: int | None = None) -> np.ndarray:
        h, w = height or self.render_size[0], width or self.render_size[1]
        renderer = self._get_renderer(h, w)
        renderer.update_scene(self.data, camera=camera)
        return renderer.render()

    def object_boxes_2d(self, camera: str = "front", height: int | None = None, width: int | None = None):
        """Image-space bounding box (x0, y0, x1, y1) of every clutter object and of the two cereal boxes."""
        from safemanip.env.render import project_body_boxes
        h, w = height or self.render_size[0], width or self.render_size[1]
        bodies = {i: int(b) for i, b in enumerate(self.index.object_bodies)}
        bodies["box_bottom"] = self.index.bottom_box_body
        bodies["box_top"] = self.index.top_box_body
        return project_body_boxes(self.model, self.data, camera, bodies, h, w)

    def close(self):
        if self._renderer is not None:
            self._renderer[1].close()
            self._renderer = None


class TimeoutEvent(gym.Wrapper):
    """Applied by ``gym.make`` outside its TimeLimit: a time-limit truncation is reported as event 'timeout'.

    ``gym.make(..., max_episode_steps=n)`` consumes that argument itself, so the env cannot see it.
    """

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        if truncated and not terminated and info.get("event") == "running":
            info = {**info, "event": "timeout"}
        return obs, reward, terminated, truncated, info

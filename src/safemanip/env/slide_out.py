"""``safemanip/SlideOut-v0``: pull the bottom cereal box out from under the top one, fast enough
that the top box stays put, then slide it to the goal without hurting the clutter.

One step = one 20 Hz control step = 25 physics steps of 2 ms. The action is the end-effector
displacement over the step as a vector in the unit ball (longer actions are scaled back onto it), times
the Panda's 1.7 m/s: at most 8.5 cm per step. The commanded velocity then passes the Panda's Cartesian
acceleration limit (13 m/s^2) and the lift band (the pads keep pressing on the box), and the embodiment
(``panda`` by default, or the idealised ``hand``) tracks it within its joint limits: its controller
(``control/cartesian.py``) turns it into the servos' commands for the step.

Safety is judged at every physics substep (``scene/builder.py``): a step's g is the minimum over its 25
substeps and its end state, so no contact between two 20 Hz observations goes unseen. Success means
placed: the box on the table in the goal, slower than v_place, out from under the top box, which is still safe.

The env's parts, each a module of ``env/``: ``arguments`` (every argument checked by name), ``sampling`` (names,
constraint types, scene kind and placement at reset), ``state`` (the flat state and its named blocks, read in a few
gathers), ``judge`` (the margins over the step's substeps), ``observation`` (the observation's layout), ``render``
(cameras and image-space boxes); this class holds the episode and calls them.
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

from safemanip.control.cartesian import make_controller
from safemanip.control.diff_ik import MAX_EE_ACCEL, MAX_EE_SPEED
from safemanip.control.setpoint import CartesianSetpoint
from safemanip.env import judge, sampling
from safemanip.env import margins as M
from safemanip.env.arguments import _action_vector, _check_reset_arguments, _check_runtime_arguments
from safemanip.env.config import EnvConfig
from safemanip.env.judge import DISTANCE_CAP
from safemanip.env.observation import SceneState, encode_constraints, observation_space
from safemanip.env.state import StateGather
from safemanip.scene.builder import CONTROL_DT, SUBSTEPS, build_model, scene_index
from safemanip.scene.catalog import load_catalog
from safemanip.scene.config import GEOMETRY
from safemanip.scene.embodiment import make_embodiment
EVENTS = ("running", "success", "failure:dyn", "failure:hard", "failure:soft", "failure:oob", "timeout", "unstable")
RESTING_TOLERANCE = 0.002  # success needs the held box on the table: its bottom face at most this high [m]


class SlideOutEnv(gym.Env):
    metadata = {"render_modes": ["rgb_array"], "render_fps": int(round(1 / CONTROL_DT))}

    def __init__(self, config: EnvConfig | None = None, *, render_mode: str | None = None,
                 thresholds: M.Thresholds = M.DEFAULT_THRESHOLDS, sleep: bool = True,
                 render_size: tuple[int, int] = (480, 640), visual: bool | None = None, check_scenes: bool = True,
                 **settings):
        """``config``: the env's settings (``env/config.py``: what a policy is trained in and records), or its fields
        as keywords (``SlideOutEnv(n_objects=4, layout="exit")``, ``gym.make``); keywords beside a config change it.
        Either way they are checked once, by ``EnvConfig``, and a bad one is refused by name (``EnvConfigError``, a
        ValueError). The other arguments say how this env runs, not what it is: how it renders, whether bodies may
        sleep, whether gate and exit scenes are confirmed with the planner's map, and the judge's thresholds."""
        _check_runtime_arguments(locals())  # each refused by name (ValueError)
        if config is None:
            config = EnvConfig.from_kwargs(settings, where="SlideOutEnv")
        elif not isinstance(config, EnvConfig):
            raise ValueError(f"SlideOutEnv: config must be an env.config.EnvConfig (or give its settings as keywords), "
                             f"got {type(config).__name__}")
        elif settings:
            config = EnvConfig.from_kwargs({**config.kwargs(), **settings}, where="SlideOutEnv")
        self.config = config
        self.scene_config = config.scene()
        self.check_scenes = bool(check_scenes)
        """Confirm each gate and exit scene with the planner's free-space map (``_is_its_kind``, ~25 ms a draw)."""
        # the settings the env reads every step or reset, as attributes (the config stays the record)
        self.slot_order = config.slot_order
        self.embodiment_name = config.embodiment
        self.action_curve = config.action_curve
        self.object_size = config.object_size
        """Each observation slot also carries the object's footprint radius (``env/observation.py``)."""
        self.constraint_mode = config.constraints
        self.render_mode = render_mode
        self.max_episode_steps = config.max_episode_steps
        self.max_speed = MAX_EE_SPEED
        self.max_accel = MAX_EE_ACCEL
        self.max_step = self.max_speed * CONTROL_DT  # the longest displacement one action can ask for [m]
        self.setpoint = CartesianSetpoint(CONTROL_DT, self.action_curve, self.max_speed, self.max_accel)
        """What each action asks the arm's controller for (action curve, lift band, hold point, the arm's limits)."""
        self.thresholds = thresholds
        self.sleep = sleep
        self.render_size = render_size
        self.geometry = GEOMETRY
        # visual meshes only when frames will be rendered: they are ~95 % of a compile, physics is the same
        self.visual = (render_mode is not None) if visual is None else bool(visual)
        self.robot = make_embodiment(config.embodiment, visual=self.visual, gap=thresholds.collision)
        self.controller = make_controller(self.robot)
        self.n_substeps = SUBSTEPS
        self.observation_space = observation_space(config.n_objects, self.object_size)
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(3,), dtype=np.float32)
        self._sims: dict[tuple[str, ...], tuple] = {}
        self._radii: dict[tuple[str, ...], np.ndarray] = {}
        self._tables: dict[tuple, tuple] = {}
        self._renderer = None
        self._substep_hook = None
        self.model = self.data = None
        self.names: tuple[str, ...] = ()
        self.constraints: tuple[str, ...] = ()
        self.placement = None

    # ------------------------------------------------------------------ set-up
    def _sim(self, names: tuple[str, ...]):
        if names not in self._sims:
            key = (names, self.sleep, self.embodiment_name, self.visual, self.thresholds.collision)
            # model and index are shared by every env in the process (``MODEL_CACHE_SIZE``); the data, the
            # robot's binding (its scratch arrays) and the views into the data are this env's own
            model, index = build_model(*key), scene_index(*key)
            data = mujoco.MjData(model)
            binding = self.robot.bind(model)
            _evict_oldest(self._sims)
            self._sims[names] = (model, data, index, binding, StateGather.build(model, index, binding, data,
                                                                                  self.object_size))
        return self._sims[names]

    def _footprint_radii(self, names: tuple[str, ...]) -> np.ndarray:
        if names not in self._radii:
            catalog = load_catalog()
            _evict_oldest(self._radii)
            self._radii[names] = np.array([catalog[n].footprint_radius for n in names])
        return self._radii[names]

    def _constraint_tables(self, names: tuple[str, ...], constraints: tuple[str, ...]) -> tuple:
        """Per-episode lookups that depend only on (names, constraints): computed once per combination.

        The first is the flat state's per-episode tail: the constraint one-hots, then (``object_size``)
        the footprint radii."""
        key = (names, constraints)
        if key not in self._tables:
            soft = [c == "soft_contact" for c in constraints]
            checked = [i for i, c in enumerate(constraints) if c != "any_contact"]
            margin_names = {i: f"{'g_soft' if soft[i] else 'g_hard'}:{i}:{names[i]}" for i in checked}
            _evict_oldest(self._tables)
            tail = [encode_constraints(constraints).ravel().astype(np.float64)]
            if self.object_size:
                tail.append(self._footprint_radii(names).astype(np.float64))
            self._tables[key] = (np.concatenate(tail), soft, checked, margin_names)
        return self._tables[key]

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        seed = _check_reset_arguments(self.config.n_objects, seed, options)  # a NumPy integer seed becomes an int
        super().reset(seed=seed)
        options = options or {}
        rng = self.np_random
        names = tuple(options["names"]) if "names" in options else sampling.choose_names(self, rng)
        if len(names) != self.config.n_objects:
            raise ValueError(f"options['names'] must hold {self.config.n_objects} names, got {list(names)}")
        self.names = names
        self.model, self.data, self.index, self.binding, self.gather = self._sim(names)
        self.constraints = sampling.choose_constraints(self, options.get("constraints", self.constraint_mode), rng)
        # this episode's initial layout (``near_path``: which objects stand beside the route; ``kind``, ``roles``)
        self.placement = sampling.place_scene(self, sampling.draw_kind(self, rng), rng)
        self._top_start = self.data.xpos[self.index.top_box_body, :2].tolist()
        self._episode_flat, self._soft_flags, self._checked_list, self._margin_names = \
            self._constraint_tables(names, self.constraints)
        self._t = 0
        self._read_state()
        self.setpoint.reset(self._values)  # at rest, holding the end-effector where it is
        if not math.isfinite(sum(self._values)):
            raise RuntimeError("the scene is not finite right after reset: the model or the placement is broken")
        terms = self._margins()
        return self._observe(), self._info(terms, "running", None)

    # ------------------------------------------------------------------ dynamics
    def step(self, action):
        if self.model is None:  # no scene yet: reset() builds it (gymnasium's OrderEnforcing says the same)
            raise gym.error.ResetNeeded("call reset() before step(): the env has no scene until its first reset()")
        request = _action_vector(action)  # refuses what is not 3 finite real numbers (ValueError)
        command = self.setpoint.commit(self.setpoint.plan(request, self._values))  # control/setpoint.py
        m, d = self.model, self.data
        phases = self.controller.command_velocity(m, d, self.binding, command, CONTROL_DT)
        time_before = d.time
        self._run_substeps(m, d, phases)
        self._t += 1
        # On a bad qpos/qvel/qacc MuJoCo resets the whole MjData (time back to 0) and carries on: time that
        # did not advance by the full control step is the cheap trace of it; NaNs that slipped through into
        # the state the env reads are caught by the finiteness check
        if d.time < time_before + 0.5 * CONTROL_DT or not self._read_state():
            self._flat, self._values = self._last_good
            self._state = None
            return self._observe(), 0.0, True, False, self._info(self._last_terms, "unstable", None)
        terms = self._margins(substeps=True)
        l, g = terms["l"], terms["g"]
        event, culprit = "running", None
        terminated = truncated = False
        if M.is_failure(g):
            event, culprit = judge.failure_cause(self, terms)
            terminated = True
        elif M.is_success(l, g) and self._resting():
            event, terminated = "success", True
        elif self._t >= self.max_episode_steps:
            event, truncated = "timeout", True
        # reward: the paper's r = min(l, g); the reach-avoid learner reads l and g from info instead
        return self._observe(), float(min(l, g)), terminated, truncated, self._info(terms, event, culprit)

    def _run_substeps(self, m, d, phases) -> None:
        """The control step's physics: each phase's servo command for its substeps. With a substep hook, the same
        mj_step calls in chunks (bit-identical physics), the hook watching every ``every`` substeps."""
        actuators = self.binding.actuator_ids
        if self._substep_hook is None:
            for substeps, ctrl in phases:
                d.ctrl[actuators] = ctrl
                mujoco.mj_step(m, d, nstep=substeps)
            return
        every, hook = self._substep_hook
        done = 0
        for substeps, ctrl in phases:
            d.ctrl[actuators] = ctrl
            end = done + substeps
            while done < end:
                chunk_end = min(end, (done // every + 1) * every)
                mujoco.mj_step(m, d, nstep=chunk_end - done)
                done = chunk_end
                if done % every == 0:
                    hook(self)

    def _resting(self) -> bool:
        """Whether the held box lies on the table (its bottom face within RESTING_TOLERANCE of the top): a box
        placed in the goal, not one hanging from the hand."""
        z = self._values[self.gather.bottom_pos.start + 2]
        return z - self.geometry.box_half_extents[2] <= RESTING_TOLERANCE

    def _read_state(self) -> bool:
        """Read the state from MjData in two gathers into one flat array (layout: ``_StateGather``).

        Returns whether it is finite; the last finite read is kept for an unstable step's observation.
        The ``SceneState`` view of it is built only when someone asks (``scene_state``).
        """
        g = self.gather
        flat = np.concatenate((g.site_xpos[g.ee_site], g.sensordata[g.sensor_index], g.qvel[g.qvel_index],
                               g.xpos[g.body_rows].ravel(), self._episode_flat))
        values = flat.tolist()
        self._flat, self._values, self._state = flat, values, None
        if math.isfinite(sum(values)):
            self._last_good = (flat, values)
            return True
        return False

    def scene_state(self) -> SceneState:
        """The paper's full state, read now (its arrays are fresh: safe to keep across steps)."""
        self._read_state()
        return self._current_state()

    def _current_state(self) -> SceneState:
        if self._state is None:
            flat, g = self._flat, self.gather
            self._state = SceneState(
                ee_pos=flat[g.ee_pos], ee_vel=flat[g.ee_vel], bottom_pos=flat[g.bottom_pos], bottom_vel=flat[g.box_vel],
                top_pos=flat[g.top_pos], top_vel=flat[g.top_vel], obj_pos=flat[g.obj_pos].reshape(-1, 3),
                obj_vel=flat[g.obj_vel].reshape(-1, 3), obj_radius=self._footprint_radii(self.names))
        return self._state

    def watch_substeps(self, every: int | None, hook=None) -> None:
        """Call ``hook(env)`` every ``every`` physics substeps inside each step (``None`` switches it off).

        For videos between control steps (every 5 substeps = 100 frames per simulated second) and for
        tests that check limits at physics resolution; the physics is bit-identical either way.
        """
        if every is None:
            self._substep_hook = None
            return
        if not isinstance(every, int) or not 1 <= every <= self.n_substeps or self.n_substeps % every:
            raise ValueError(f"every must divide the {self.n_substeps} substeps of a control step, got {every!r}")
        self._substep_hook = (every, hook)

    # ------------------------------------------------------------------ margins
    def object_distances(self, object_ids=None) -> np.ndarray:
        """Signed distance (m, capped at 0.3) from the manipulated box and hand to each object's geoms.

        Objects whose bounding sphere is farther than the cap from the box's bounding sphere are not
        queried: their distance is the cap either way.
        """
        ids = range(len(self.names)) if object_ids is None else [int(i) for i in np.atleast_1d(object_ids)]
        self._read_state()
        out = [DISTANCE_CAP] * len(self.names)
        for i, dist in zip(ids, self._distances(ids)):
            out[i] = dist
        return np.array(out)

    def _distances(self, ids) -> list[float]:
        return judge.geom_distances(self, ids)

    def _margins(self, state: SceneState | None = None, substeps: bool = False) -> dict[str, Any]:
        return judge.margins(self, state, substeps)

    # ------------------------------------------------------------------ outputs
    def slot_ids(self, state: SceneState) -> np.ndarray:
        """Object ids in observation-slot order: scene order, or nearest to the held box first."""
        if self.slot_order == "index" or len(self.names) < 2:
            return self.gather.index_order
        offset = state.obj_pos[:, :2] - state.bottom_pos[:2]
        return np.argsort(np.einsum("ij,ij->i", offset, offset), kind="stable")

    def _observe(self) -> np.ndarray:
        """The observation of the last state read: ``build_observation``'s layout (a test holds them equal),
        gathered from the flat state in one go."""
        g = self.gather
        ids = g.index_order if self.slot_order == "index" else self.slot_ids(self._current_state())
        obs = self._flat[g.observation_sources(ids)].astype(np.float32)
        values = self._values
        if max(values) > 10.0 or min(values) < -10.0:  # rare: only then pay for the clip
            np.clip(obs, -10.0, 10.0, out=obs)
        return obs

    def _info(self, terms, event: str, culprit: int | None) -> dict:
        margins = {"l1": terms["l1"], "l2": terms["l2"], "l3": terms["l3"], "g_dyn": terms["g_dyn"],
                   "g_oob": terms["g_oob"]}
        objects = terms["objects"]
        for i, key in self._margin_names.items():
            margins[key] = float(objects[i])
        return {"l": float(terms["l"]), "g": float(terms["g"]), "margins": margins, "event": event,
                "object": self.names[culprit] if culprit is not None else None, "object_id": culprit,
                "t": self._t, "names": self.names, "constraints": self.constraints, "scene_kind": self.placement.kind,
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


_CACHE_SIZE = 64  # scenes (compiled model + data) kept per env: random object draws would otherwise grow without bound


def _evict_oldest(cache: dict) -> None:
    while len(cache) >= _CACHE_SIZE:
        del cache[next(iter(cache))]


class TimeoutEvent(gym.Wrapper):
    """Applied by ``gym.make`` outside its TimeLimit: a time-limit truncation is reported as event 'timeout'.

    ``gym.make(..., max_episode_steps=n)`` consumes that argument itself, so the env cannot see it.
    """

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        if truncated and not terminated and info.get("event") == "running":
            info = {**info, "event": "timeout"}
        return obs, reward, terminated, truncated, info


# ------------------------------------------------------------------ argument checks (the public API's inputs)

"""``safemanip/SlideOut-v0``: pull the bottom cereal box out from under the top one, fast enough
that the top box stays put, then slide it to the goal without hurting the clutter.

One step = one 20 Hz control step = 25 physics steps of 2 ms. The action is the end-effector
displacement over the step as a vector in the unit ball (longer actions are scaled back onto it), times
the Panda's 1.7 m/s: at most 8.5 cm per step. The commanded velocity then passes the Panda's Cartesian
acceleration limit (13 m/s^2) and the lift band (the box slides; it may rise 2 cm at most), and the
embodiment (``panda`` by default, or the idealised ``hand``) tracks it.

Safety is judged at every physics substep (``scene/builder.py``): a step's g is the minimum over its 25
substeps and its end state, so no contact between two 20 Hz observations goes unseen. Success means
placed: the box in the goal, slower than v_place, out from under the top box, which is still safe.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import gymnasium as gym
import mujoco
import numpy as np

from safemanip.control.diff_ik import MAX_EE_ACCEL, MAX_EE_SPEED, limit_ee_velocity, shape_action
from safemanip.env import margins as M
from safemanip.env.observation import SceneState, encode_constraints, observation_space, slot_dim
from safemanip.scene.builder import CONTROL_DT, SUBSTEPS, SceneIndex, build_model, scene_index
from safemanip.scene.catalog import CONSTRAINT_TYPES, load_catalog, names_of_class
from safemanip.scene.config import GEOMETRY, SceneConfig
from safemanip.scene.embodiment import EMBODIMENTS, make_embodiment
from safemanip.scene.grasp import PAD_PRESS
from safemanip.control.planner import open_for_the_arm, part_extents
from safemanip.scene.placement import LAYOUTS, sample_placement, sample_route

CONSTRAINT_MODES = ("ground_truth", "conservative", "random")
EVENTS = ("running", "success", "failure:dyn", "failure:hard", "failure:soft", "failure:oob", "timeout", "unstable")
DISTANCE_CAP = 0.3  # geom distances saturate here: far objects do not need an exact value
_MANIPULATED_REACH = 0.25  # bounding radius of the held box and the hand around the box centre
LIFT_BAND = 0.5 * PAD_PRESS  # the hand may rise this far above the nominal press [m]: the pads, half out, still
# press with 18 N (20 N at the nominal press), so the action's z only trims the pressing force and never lets go
HEIGHT_GAIN = 0.5  # share of the hand's height error corrected per step: a full correction overshoots and rings
SCENE_TRIES = 20  # draws of a gate or exit scene before the episode falls back to an open one
RESTING_TOLERANCE = 0.002  # success needs the held box on the table: its bottom face at most this high [m]


class SlideOutEnv(gym.Env):
    metadata = {"render_modes": ["rgb_array"], "render_fps": int(round(1 / CONTROL_DT))}

    def __init__(self, n_objects: int = 4, names: Sequence[str] | None = None, classes: Sequence[str] | str | None = None,
                 constraints: str | Sequence[str] = "ground_truth", near_path_fraction: float | None = None,
                 render_mode: str | None = None, max_episode_steps: int = 300,
                 thresholds: M.Thresholds = M.DEFAULT_THRESHOLDS, sleep: bool = True, slot_order: str = "index",
                 render_size: tuple[int, int] = (480, 640), embodiment: str = "panda", visual: bool | None = None,
                 action_curve: float = 1.0, object_size: bool = False, clear_route: bool = True,
                 layout: str = "route", gate_share: float | None = None, exit_share: float | None = None,
                 check_scenes: bool = True):
        _check_init_arguments(locals())  # every argument's type and range, each refused by name (ValueError)
        if isinstance(classes, str):
            from safemanip.scene.config import parse_semantics
            classes = parse_semantics(classes)
        self.config = SceneConfig(n_objects=n_objects, names=tuple(names) if names else None,
                                  classes=tuple(classes) if classes else None, near_path_fraction=near_path_fraction,
                                  clear_route=clear_route, layout=layout, gate_share=gate_share,
                                  exit_share=exit_share)
        self.check_scenes = bool(check_scenes)
        """Confirm each gate and exit scene with the planner's free-space map (``_is_its_kind``, ~25 ms a draw)."""
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
        if not isinstance(max_episode_steps, (int, np.integer)) or not 1 <= max_episode_steps <= 100_000:
            raise ValueError(f"max_episode_steps must be an integer from 1 to 100000, got {max_episode_steps!r}")
        if embodiment not in EMBODIMENTS:
            raise ValueError(f"embodiment must be one of {sorted(EMBODIMENTS)}, got {embodiment!r}")
        self.embodiment_name = embodiment
        if not (isinstance(action_curve, (int, float)) and 1.0 <= action_curve <= 4.0):
            raise ValueError(f"action_curve must be a number from 1 (linear) to 4, got {action_curve!r}")
        self.action_curve = float(action_curve)
        if not isinstance(object_size, (bool, np.bool_)):
            raise ValueError(f"object_size must be true or false, got {object_size!r}")
        self.object_size = bool(object_size)
        """Each observation slot also carries the object's footprint radius (``env/observation.py``)."""
        self.constraint_mode = constraints
        self.render_mode = render_mode
        self.max_episode_steps = int(max_episode_steps)
        self.max_speed = MAX_EE_SPEED
        self.max_accel = MAX_EE_ACCEL
        self.max_step = self.max_speed * CONTROL_DT  # the longest displacement one action can ask for [m]
        self.thresholds = thresholds
        self.sleep = sleep
        self.render_size = render_size
        self.geometry = GEOMETRY
        # visual meshes only when frames will be rendered: they are ~95 % of a compile, physics is the same
        self.visual = (render_mode is not None) if visual is None else bool(visual)
        self.robot = make_embodiment(embodiment, visual=self.visual, gap=thresholds.collision)
        self.n_substeps = SUBSTEPS
        self.observation_space = observation_space(n_objects, self.object_size)
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
            self._sims[names] = (model, data, index, binding, _StateGather.build(model, index, binding, data,
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

    def _choose_names(self, rng: np.random.Generator) -> tuple[str, ...]:
        if self.config.names is not None:
            return self.config.names
        if self.config.n_objects == 0:
            return ()
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
        seed = _check_reset_arguments(self.config.n_objects, seed, options)  # a NumPy integer seed becomes an int
        super().reset(seed=seed)
        options = options or {}
        rng = self.np_random
        names = tuple(options["names"]) if "names" in options else self._choose_names(rng)
        if len(names) != self.config.n_objects:
            raise ValueError(f"options['names'] must hold {self.config.n_objects} names, got {list(names)}")
        self.names = names
        self.model, self.data, self.index, self.binding, self.gather = self._sim(names)
        self.constraints = self._choose_constraints(options.get("constraints", self.constraint_mode), rng)
        # this episode's initial layout (``near_path``: which objects stand beside the route; ``kind``, ``roles``)
        self.placement = self._place_scene(self._draw_kind(rng), rng)
        m, d, idx = self.model, self.data, self.index
        self._top_start = d.xpos[idx.top_box_body, :2].tolist()
        self._episode_flat, self._soft_flags, self._checked_list, self._margin_names = \
            self._constraint_tables(names, self.constraints)
        self._t = 0
        self._command = np.zeros(3)
        self._read_state()
        self._lift_band = (self._values[2], self._values[2] + LIFT_BAND)
        self._height = self._values[2]  # the commanded height of the end-effector
        if not math.isfinite(sum(self._values)):
            raise RuntimeError("the scene is not finite right after reset: the model or the placement is broken")
        terms = self._margins()
        return self._observe(), self._info(terms, "running", None)

    def _draw_kind(self, rng: np.random.Generator) -> str:
        """This episode's scene kind (``SCENE_KINDS``), by the config's shares; an open layout draws nothing."""
        gate, exit_ = self.config.kind_shares
        if gate == 0.0 and exit_ == 0.0:
            return "open"
        u = float(rng.random())
        return "gate" if u < gate else "exit" if u < gate + exit_ else "open"

    def _place_scene(self, kind: str, rng: np.random.Generator):
        """Sample a placement of ``kind`` and set the scene to it. A gate or exit scene is redrawn until the planner's
        free-space map confirms what it is meant to be (``_is_its_kind``), at most ``SCENE_TRIES`` times; then it
        becomes an open scene, and ``placement.kind`` says so."""
        radii = self._footprint_radii(self.names)
        fragile = np.array([c == "no_contact" for c in self.constraints], dtype=bool)
        layout = LAYOUTS[self.config.layout]
        for attempt in range(SCENE_TRIES if kind != "open" else 1):
            route = sample_route(rng, self.geometry, layout=layout) if self.config.clear_route else None
            placement = sample_placement(radii, rng, self.config.near_fraction, self.geometry, route=route, kind=kind,
                                         fragile=fragile)
            self._set_poses(placement)
            if placement.kind == "open" or not self.check_scenes or self._is_its_kind(placement, fragile):
                return placement
        return self._place_scene("open", rng)

    def _set_poses(self, placement) -> None:
        m, d, idx = self.model, self.data, self.index
        mujoco.mj_resetData(m, d)
        self.robot.reset(m, d, self.binding)
        for i in range(len(self.names)):
            adr = idx.object_qpos[i]
            d.qpos[adr:adr + 3] = (*placement.xy[i], 0.0005)
            d.qpos[adr + 3:adr + 7] = (np.cos(placement.yaw[i] / 2), 0, 0, np.sin(placement.yaw[i] / 2))
        mujoco.mj_forward(m, d)

    def _is_its_kind(self, placement, fragile: np.ndarray) -> bool:
        """A gate is closed to the arm avoiding every object and open avoiding the fragile ones only; an exit is
        open (``control.planner.open_for_the_arm``, on the planner's 1 cm map of the scene as placed)."""
        parts = part_extents(self)
        if placement.kind == "exit":
            return open_for_the_arm(self, parts)
        breakable = part_extents(self, objects=np.flatnonzero(fragile))
        return not open_for_the_arm(self, parts) and open_for_the_arm(self, breakable)

    # ------------------------------------------------------------------ dynamics
    def step(self, action):
        _check_action(action)
        request = np.asarray(action, dtype=np.float64).reshape(3)
        if not (math.isfinite(request[0]) and math.isfinite(request[1]) and math.isfinite(request[2])):
            raise ValueError(f"action must be finite, got {request.tolist()}: a NaN action usually means the "
                             "policy's weights or its observation hold NaN")
        # by norm, not per axis (no faster diagonals), through the action curve (``shape_action``)
        request = shape_action(request, self.action_curve) * self.max_speed
        z_low, z_high = self._lift_band
        # the lift band: the action moves the commanded height within the band, and the hand is sent there (the
        # pads' push makes the velocity-servoed arm drift up by a few mm otherwise)
        self._height = min(max(self._height + request[2] * CONTROL_DT, z_low), z_high)
        request[2] = HEIGHT_GAIN * (self._height - self._values[2]) / CONTROL_DT
        command = limit_ee_velocity(request, self._command, CONTROL_DT, self.max_speed, self.max_accel)
        self._command = command
        m, d = self.model, self.data
        self.robot.command_velocity(m, d, self.binding, command, CONTROL_DT)
        time_before = d.time
        if self._substep_hook is None:
            mujoco.mj_step(m, d, nstep=self.n_substeps)
        else:  # the same mj_step calls in chunks (bit-identical physics), with the hook watching in between
            every, hook = self._substep_hook
            for done in range(every, self.n_substeps + every, every):
                mujoco.mj_step(m, d, nstep=min(every, self.n_substeps - done + every))
                hook(self)
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
            event, culprit = self._failure_cause(terms)
            terminated = True
        elif M.is_success(l, g) and self._resting():
            event, terminated = "success", True
        elif self._t >= self.max_episode_steps:
            event, truncated = "timeout", True
        # reward: the paper's r = min(l, g); the reach-avoid learner reads l and g from info instead
        return self._observe(), float(min(l, g)), terminated, truncated, self._info(terms, event, culprit)

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
        """Capped geom distances of objects ``ids``, from the positions of the last state read."""
        m, d, gather, v = self.model, self.data, self.gather, self._values
        bx, by, bz = v[gather.bottom_pos.start:gather.bottom_pos.start + 3]
        base = gather.obj_pos.start
        out = []
        for i in ids:
            j = base + 3 * i
            dx, dy, dz = v[j] - bx, v[j + 1] - by, v[j + 2] - bz
            best = DISTANCE_CAP
            if math.sqrt(dx * dx + dy * dy + dz * dz) - gather.reach[i] < DISTANCE_CAP:
                for g1, g2 in gather.geom_pairs[i]:
                    dist = mujoco.mj_geomDistance(m, d, g1, g2, DISTANCE_CAP, None)
                    if dist < best:
                        best = dist
            out.append(best)
        return out

    def _margins(self, state: SceneState | None = None, substeps: bool = False) -> dict[str, Any]:
        """Every margin term of the last state read (``state``, if given, must be that state).

        With ``substeps``, each g term is also the minimum over the physics substeps of the control step
        just taken, read from the judge sensors' history (``scene/builder.py``).
        """
        if state is not None and state is not self._state:
            raise ValueError("_margins works on the state of the last read; pass env.scene_state() or nothing")
        th, geo, v, gather = self.thresholds, self.geometry, self._values, self.gather
        half = geo.box_half_extents
        b0 = gather.bottom_pos.start
        bottom = v[b0:b0 + 2]
        top = v[b0 + 3:b0 + 5]
        bvx, bvy, bvz = v[gather.box_vel]
        terms: dict[str, Any] = {
            "l1": M.margin_out_from_under(bottom, top, half, half, th.out_clearance),
            "l2": M.margin_in_goal(bottom, geo.goal_xy, th.goal_radius),
            "g_dyn": M.margin_top_box(top, self._top_start, float(gather.xmat[gather.top_up_z]),
                                      th.top_box_displacement, th.top_box_min_up),
            "g_oob": M.margin_in_workspace(bottom, geo.table_half_extents, geo.workspace_inset),
            "l3": M.margin_at_rest(math.sqrt(bvx * bvx + bvy * bvy + bvz * bvz), th.place_speed,
                                   th.place_horizon, th.rest_horizon),
        }
        history = None
        if substeps:
            gather = self.gather
            history = gather.history[gather.history_index]  # (substeps, columns): one gather
            terms["g_dyn"] = min(terms["g_dyn"], M.worst_top_box(
                history[:, gather.h_top_pos], self._top_start, history[:, gather.h_top_up_z],
                th.top_box_displacement, th.top_box_min_up))
            terms["g_oob"] = min(terms["g_oob"], M.worst_in_workspace(
                history[:, gather.h_box_xy], geo.table_half_extents, geo.workspace_inset))
        n = len(self.names)
        object_terms = [math.inf] * n
        distances = [DISTANCE_CAP] * n
        g_objects = math.inf
        checked = self._checked_list
        if checked:
            v0 = gather.obj_vel.start
            for i, dist in zip(checked, self._distances(checked)):
                distances[i] = dist
                if self._soft_flags[i]:
                    j = v0 + 3 * i
                    speed = math.sqrt((v[j] - bvx) ** 2 + (v[j + 1] - bvy) ** 2 + (v[j + 2] - bvz) ** 2)
                    term = M.margin_soft_contact(dist, speed, th.collision, th.relative_speed)
                else:
                    term = dist - th.collision  # = margin_no_contact
                object_terms[i] = term
            if history is not None:
                # (substeps, N, 2): a contact within d4 of the robot / of the held box at that substep
                found = history[:, gather.h_found] > 0.5
                if found.any():
                    for i in checked:
                        hit = found[:, i]
                        if hit.any():
                            object_terms[i] = min(object_terms[i], self._substep_contact_margin(history, hit, i))
            g_objects = min(object_terms[i] for i in checked)
        terms["objects"] = np.array(object_terms) if n else _EMPTY
        terms["distances"] = np.array(distances) if n else _EMPTY
        terms["l"] = min(terms["l1"], terms["l2"], terms["l3"])
        terms["g"] = float(min(terms["g_dyn"], terms["g_oob"], g_objects))
        self._last_terms = terms
        return terms

    def _substep_contact_margin(self, history: np.ndarray, hit: np.ndarray, i: int) -> float:
        """Worst g of object i over the substeps where the robot or the held box came within d4 of it (``hit``:
        (substeps, 2), which of the two contact sensors found one)."""
        th, gather = self.thresholds, self.gather
        substeps = hit.any(axis=1)
        rows = history[substeps]
        distance = np.where(hit[substeps], rows[:, gather.h_dist[i]], np.inf).min(axis=1)
        if not self._soft_flags[i]:
            return float(np.min(distance)) - th.collision  # = margin_no_contact
        # the held box's velocity stands for the robot's: it is the fastest-moving part near the table
        relative = rows[:, gather.h_box_vel] - rows[:, gather.h_obj_vel[i]]
        speed = np.sqrt(np.einsum("ij,ij->i", relative, relative))
        return min(M.margin_soft_contact(float(dd), float(sp), th.collision, th.relative_speed)
                   for dd, sp in zip(distance, speed))

    def _failure_cause(self, terms) -> tuple[str, int | None]:
        candidates = {"failure:dyn": terms["g_dyn"], "failure:oob": terms["g_oob"]}
        worst_obj = None
        if len(self.names) and np.isfinite(terms["objects"]).any():
            worst_obj = int(np.argmin(terms["objects"]))
            kind = "failure:soft" if self._soft_flags[worst_obj] else "failure:hard"
            candidates[kind] = terms["objects"][worst_obj]
        event = min(candidates, key=candidates.get)
        return event, (worst_obj if event in ("failure:hard", "failure:soft") else None)

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


_EMPTY = np.zeros(0)
_EMPTY.flags.writeable = False
_CACHE_SIZE = 64  # scenes (compiled model + data) kept per env: random object draws would otherwise grow without bound


def _evict_oldest(cache: dict) -> None:
    while len(cache) >= _CACHE_SIZE:
        del cache[next(iter(cache))]


class _Blocks:
    """Consecutive named blocks of a flat array: ``take(n)`` returns the next n entries' slice."""

    def __init__(self):
        self.size = 0

    def take(self, n: int) -> slice:
        block = slice(self.size, self.size + n)
        self.size += n
        return block


@dataclass(frozen=True)
class _StateGather:
    """Index arrays and MjData views, built once per compiled scene, that read the state in a few gathers.

    The flat state is ``[ee_pos(3), ee_vel(3), box_vel(3), top_vel(3), obj_vel(3N), bottom_pos(3), top_pos(3),
    obj_pos(3N), constraint one-hots(3N), footprint radii(N, with object_size)]``: the order ``_read_state``
    concatenates its sources in (the site's position, two sensors, the free joints' linear velocities, the
    bodies' positions, the episode's constants); the slices below name each block. An observation is one
    gather from it.

    The judge sensors' history is read as one (substeps, columns) gather through ``history_index``; the
    ``h_*`` fields name its columns.
    """

    xpos: np.ndarray  # views into this scene's MjData (its buffers never move)
    qvel: np.ndarray
    site_xpos: np.ndarray
    xmat: np.ndarray  # flat
    sensordata: np.ndarray
    history: np.ndarray
    sensor_index: np.ndarray  # in sensordata: the end-effector's, then the held box's linear velocity
    ee_site: int
    top_up_z: int  # index in ``xmat`` of the top box's up-axis z component
    body_rows: np.ndarray
    qvel_index: np.ndarray
    ee_pos: slice  # the blocks of the flat state
    ee_vel: slice
    box_vel: slice
    top_vel: slice
    obj_vel: slice
    bottom_pos: slice
    top_pos: slice
    obj_pos: slice
    reach: list[float]  # per object: bounding radius of its geoms plus the held box's
    geom_pairs: list[list[tuple[int, int]]]  # per object: (manipulated geom, object geom) pairs to query
    index_order: np.ndarray
    robot_sources: np.ndarray  # (18,): flat-state indices of the robot and box part of the observation
    slot_sources: np.ndarray  # (N, 9 or 10): flat-state indices of each slot entry (observation.py layout)
    index_sources: np.ndarray  # observation_sources(index_order), the common case, precomputed
    history_index: np.ndarray  # (substeps, columns) indices into MjData.history
    h_found: np.ndarray  # (N, 2) columns: contact found between object i and the robot's subtree / the held box
    h_dist: np.ndarray  # (N, 2) columns: those contacts' distances
    h_obj_vel: np.ndarray  # (N, 3) columns: object i's linear velocity
    h_box_vel: np.ndarray  # (3,) the held box's linear velocity
    h_box_xy: np.ndarray  # (2,) the held box's position
    h_top_pos: np.ndarray  # (2,) the top box's horizontal position
    h_top_up_z: int  # the z component of the top box's up axis

    @classmethod
    def build(cls, model: mujoco.MjModel, index: SceneIndex, binding, data: mujoco.MjData,
              object_size: bool = False) -> "_StateGather":
        n = len(index.object_bodies)
        blocks = _Blocks()
        ee_pos, ee_vel, box_vel, top_vel, obj_vel = (blocks.take(3), blocks.take(3), blocks.take(3), blocks.take(3),
                                                     blocks.take(3 * n))
        bottom_pos, top_pos, obj_pos = blocks.take(3), blocks.take(3), blocks.take(3 * n)
        onehot, radius = blocks.take(3 * n), blocks.take(n if object_size else 0)
        robot = np.r_[ee_pos, ee_vel, bottom_pos, box_vel, top_pos, top_vel].astype(np.intp)
        slots = np.array([np.r_[obj_pos.start + 3 * i:obj_pos.start + 3 * i + 3,
                                obj_vel.start + 3 * i:obj_vel.start + 3 * i + 3,
                                onehot.start + 3 * i:onehot.start + 3 * i + 3,
                                radius.start + i:radius.start + i + (1 if object_size else 0)]
                          for i in range(n)], dtype=np.intp).reshape(n, slot_dim(object_size))
        manipulated = [int(g) for g in index.manipulated_geoms]
        columns: list[np.ndarray] = []  # per column, its (substeps,) indices into MjData.history

        def history_columns(sensor_name: str) -> list[int]:
            sensor = model.sensor(sensor_name)
            samples, dim = int(model.sensor_history[sensor.id, 0]), int(sensor.dim[0])
            # layout per sensor: 2 header values, the sample times, then the samples (dim values each)
            values = int(model.sensor_historyadr[sensor.id]) + 2 + samples
            first = len(columns)
            for c in range(dim):
                columns.append(values + c + dim * np.arange(samples))
            return list(range(first, first + dim))

        found, dist, object_vel = [], [], []
        for i in range(n):
            (f_robot, d_robot), (f_box, d_box) = (history_columns(f"judge_contact{i}"),
                                                  history_columns(f"judge_box_contact{i}"))
            found.append((f_robot, f_box))
            dist.append((d_robot, d_box))
            object_vel.append(history_columns(f"judge_vel{i}"))
        h_box_vel = history_columns("judge_box_vel")
        box_xy = history_columns("judge_box_pos")[:2]
        top_xy = history_columns("judge_top_pos")[:2]
        top_up_z = history_columns("judge_top_up")[2]

        def sensor_values(name: str) -> np.ndarray:
            adr = int(model.sensor_adr[model.sensor(name).id])
            return np.arange(adr, adr + 3)

        return cls(
            xpos=data.xpos, qvel=data.qvel, site_xpos=data.site_xpos, xmat=data.xmat.reshape(-1),
            sensordata=data.sensordata, history=data.history,
            sensor_index=np.r_[sensor_values("ee_vel"), sensor_values("judge_box_vel")].astype(np.intp),
            ee_site=int(binding.ee_site), top_up_z=9 * int(index.top_box_body) + 8,
            body_rows=np.r_[index.bottom_box_body, index.top_box_body, index.object_bodies].astype(np.intp),
            qvel_index=np.r_[np.arange(index.top_box_qvel, index.top_box_qvel + 3),
                             index.object_qvel_flat].astype(np.intp),
            ee_pos=ee_pos, ee_vel=ee_vel, box_vel=box_vel, top_vel=top_vel, obj_vel=obj_vel,
            bottom_pos=bottom_pos, top_pos=top_pos, obj_pos=obj_pos,
            reach=[float(r) + _MANIPULATED_REACH for r in index.object_reach],
            geom_pairs=[[(g1, int(g2)) for g1 in manipulated for g2 in geoms] for geoms in index.object_geoms],
            index_order=np.arange(n), robot_sources=robot, slot_sources=slots,
            index_sources=np.concatenate((robot, slots.ravel())),
            history_index=np.stack(columns, axis=1).astype(np.intp),
            h_found=np.array(found, dtype=np.intp).reshape(n, 2), h_dist=np.array(dist, dtype=np.intp).reshape(n, 2),
            h_obj_vel=np.array(object_vel, dtype=np.intp).reshape(n, 3), h_box_vel=np.array(h_box_vel, dtype=np.intp),
            h_box_xy=np.array(box_xy, dtype=np.intp), h_top_pos=np.array(top_xy, dtype=np.intp), h_top_up_z=top_up_z)

    def observation_sources(self, ids: np.ndarray) -> np.ndarray:
        if ids is self.index_order:
            return self.index_sources
        return np.concatenate((self.robot_sources, self.slot_sources[ids].ravel()))


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
MAX_RENDER_SIZE = (960, 1280)
"""Largest (height, width) of a rendered frame: the offscreen buffer ``scene/builder.py`` allocates."""
RESET_OPTIONS = ("names", "constraints")


def _is_int(value) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def _is_real(value) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _check_init_arguments(args: dict) -> None:
    """``SlideOutEnv.__init__``'s arguments, each refused with a ValueError that names it (rather than a KeyError
    or TypeError from deep inside)."""
    def refuse(name: str, want: str):
        raise ValueError(f"SlideOutEnv: {name} must be {want}, got {_short(args[name])}")

    def strings(value) -> bool:
        return isinstance(value, (list, tuple)) and all(isinstance(v, str) for v in value)

    if args["names"] is not None and not strings(args["names"]):
        refuse("names", "a list of catalog names (or None)")
    if args["classes"] is not None and not (isinstance(args["classes"], str) or strings(args["classes"])):
        refuse("classes", "a list of semantic classes or a description such as '2 fragile, 1 soft' (or None)")
    if not (isinstance(args["constraints"], str) or strings(args["constraints"])):
        refuse("constraints", f"one of {CONSTRAINT_MODES} or a list of {CONSTRAINT_TYPES}")
    if args["near_path_fraction"] is not None and not (_is_real(args["near_path_fraction"])
                                                       and 0 <= args["near_path_fraction"] <= 1):
        refuse("near_path_fraction", "a number in [0, 1] (or None)")
    for name in ("sleep", "clear_route", "check_scenes"):
        if not isinstance(args[name], (bool, np.bool_)):
            refuse(name, "true or false")
    if args["visual"] is not None and not isinstance(args["visual"], (bool, np.bool_)):
        refuse("visual", "true, false or None")
    if not isinstance(args["layout"], str):  # which names: the scene config says
        refuse("layout", f"one of {', '.join(map(repr, LAYOUTS))}")
    for name, allowed in (("embodiment", EMBODIMENTS), ("slot_order", ("index", "nearest"))):
        if not isinstance(args[name], str) or args[name] not in allowed:
            refuse(name, f"one of {', '.join(map(repr, allowed))}")
    if args["render_mode"] is not None and not isinstance(args["render_mode"], str):
        refuse("render_mode", "None or 'rgb_array'")
    size = args["render_size"]
    if not (isinstance(size, (list, tuple)) and len(size) == 2 and all(_is_int(v) for v in size)
            and 1 <= size[0] <= MAX_RENDER_SIZE[0] and 1 <= size[1] <= MAX_RENDER_SIZE[1]):
        refuse("render_size", f"(height, width) in pixels, at most {MAX_RENDER_SIZE}")
    if not (_is_real(args["action_curve"]) and math.isfinite(args["action_curve"])):
        refuse("action_curve", "a number from 1 (linear) to 4")
    if not isinstance(args["thresholds"], M.Thresholds):
        refuse("thresholds", "an env.margins.Thresholds")


def _check_reset_arguments(n_objects: int, seed, options) -> int | None:
    """``reset``'s seed and options: unknown option keys and values are refused, not ignored. Returns the seed as a
    Python int (Gymnasium refuses NumPy integers)."""
    if seed is not None and not (_is_int(seed) and 0 <= seed < 2**63):
        raise ValueError(f"reset: seed must be None or a non-negative integer, got {_short(seed)}")
    seed = None if seed is None else int(seed)
    if options is None:
        return seed
    if not isinstance(options, dict):
        raise ValueError(f"reset: options must be a dict with keys from {RESET_OPTIONS}, got {_short(options)}")
    unknown = [k for k in options if k not in RESET_OPTIONS]
    if unknown:
        raise ValueError(f"reset: unknown option(s) {_short(unknown)}; options takes {', '.join(RESET_OPTIONS)}")
    if "names" in options:
        names = options["names"]
        catalog = load_catalog()
        if not (isinstance(names, (list, tuple)) and all(isinstance(n, str) for n in names)):
            raise ValueError(f"reset: options['names'] must be a list of {n_objects} catalog names, got {_short(names)}")
        if len(names) != n_objects or len(set(names)) != len(names) or not all(n in catalog for n in names):
            unknown_names = [n for n in names if n not in catalog]
            raise ValueError(f"reset: options['names'] must hold {n_objects} names, distinct and from the catalog "
                             f"(`safemanip catalog` lists them), got {_short(list(names))}"
                             + (f"; unknown: {_short(unknown_names)}" if unknown_names else ""))
    if "constraints" in options:
        value = options["constraints"]
        ok = (value in CONSTRAINT_MODES) if isinstance(value, str) else (
            isinstance(value, (list, tuple)) and len(value) == n_objects
            and all(isinstance(c, str) and c in CONSTRAINT_TYPES for c in value))
        if not ok:
            raise ValueError(f"reset: options['constraints'] must be one of {CONSTRAINT_MODES} or a list of "
                             f"{n_objects} of {CONSTRAINT_TYPES}, got {_short(value)}")
    return seed


def _check_action(action) -> None:
    """An action ``step`` can use: three finite real numbers whose squared norm is finite too (1e200 is finite, but
    the speed it asks for is not), not complex, text, booleans or objects."""
    try:
        a = np.asarray(action)
    except Exception:
        a = None
    if a is None or a.dtype.kind not in "iuf" or a.size != 3 or a.ndim > 2:
        kind = "no array" if a is None else f"dtype {a.dtype}, shape {a.shape}"
        raise ValueError(f"step: action must be 3 real numbers (the end-effector displacement in the unit ball), got "
                         f"{_short(action)} ({kind})")
    a = a.astype(np.float64).reshape(3)
    with np.errstate(over="ignore", invalid="ignore"):
        square = float(a @ a)
    if np.isfinite(a).all() and not math.isfinite(square):
        raise ValueError(f"step: action {a.tolist()} is too large to use (its length overflows); actions lie in the "
                         "unit ball, longer ones are scaled back onto it")

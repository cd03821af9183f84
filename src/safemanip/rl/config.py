"""Training configuration: one dataclass, validated before any work starts."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

from safemanip.env.config import EnvConfig, EnvConfigError
from safemanip.rl.envs import DEFAULT_ENV, ENVS, SELECTED_ENV, check_env
from safemanip.scene.config import MAX_OBJECTS
from safemanip.util.values import brief


class ConfigError(ValueError):
    """A training config that cannot run; the message says what to change."""


TRAINING_ENV = EnvConfig(n_objects=2, constraints="conservative", slot_order="nearest", action_curve=2.0)
"""The training env where it differs from the env's own defaults (``EnvConfig``): every object no_contact (the
paper's F^conser), slots nearest first (the order the deployment reducer uses), and the action curve 2 (placing the
box at rest asks for |a| < 0.17 instead of 0.03, so exploration noise and the actor's gradient can find it). A
run changes it through ``TrainConfig.env``."""
TRAINING_CONSTRAINTS = {"conservative": "conservative", "random": "all"}
"""The constraint modes a policy is trained with (``EnvConfig.constraints``) and the constraint set each gives the
policy's name and metadata: F^conser, or all types drawn at random per object and episode."""


@dataclass
class TrainConfig:
    algorithm: str = "rarl"
    """'rarl' (discounted reach-avoid backup) or 'vanilla' (DDPG on the discounted return of r = min(l, g), with
    absorbing terminal states). The vanilla target is ``rl/backup.py::discounted_return_target``."""
    k: int = 2
    """Clutter objects in every training scene: the k object slots the policy sees (at evaluation a scene may
    hold N >= k objects: eval's --n-objects)."""
    env: EnvConfig | None = None
    """The training scenes, as the env takes them (``env.config.EnvConfig``: layout, constraint mode, robot, action
    curve, observation options, episode length); None: ``TRAINING_ENV``. A file gives the settings that differ from
    ``TRAINING_ENV`` as an object under "env". Its n_objects is always k: the env the policy was trained in has k
    objects (the larger scenes of selection-aware training are ``scene_objects``). Recorded in the policy's metadata
    (``env_kwargs``), from which evaluation builds its env."""
    total_env_steps: int = 2_000_000
    """Budget in environment steps (the run stops at whichever budget is reached first)."""
    minutes: float | None = 60.0
    """Budget in wall-clock minutes; 0 means no time limit. (That is the command line's spelling, which
    ``safemanip train`` turns into None: here, and in a --config file, the limit is off with None / null and 0 is
    out of range.)"""
    seed: int = 0
    """Seed of everything random in the run: the learner's networks and sampling, the rollout workers' scenes and
    exploration noise."""
    out_dir: str = "runs/rarl"
    """Run folder: config, checkpoints, logs, evaluations and policies."""
    # -- Table V
    batch_size: int = 200
    """Transitions per learner update (Table V)."""
    learning_rate: float = 1e-3
    """AdamW learning rate of the actor and the critics (Table V)."""
    learning_rate_final: float | None = None
    """If set, both learning rates fall to this on a cosine over the budget; unset, they stay constant (Table V).
    The cosine runs from ``learning_rate`` on the same progress measure as gamma's anneal."""
    buffer_size: int = 100_000
    """Replay buffer capacity in transitions (Table V)."""
    gamma: float = 0.99
    """Discount factor; with a starting discount (--gamma-start) it is annealed from that to this value."""
    gamma_start: float | None = None
    """If set, the discount rises linearly from this value to --gamma over the first half of the budget."""
    polyak: float = 0.995
    """Target networks move by (1 - polyak) towards the trained ones every update (Table V)."""
    hidden: tuple[int, ...] = (256, 256, 256)
    """Hidden layer widths of the actor and critic MLPs (Table V: three layers of 256)."""
    # -- another env (e.g. the toy system, safemanip.toy)
    env_name: str = DEFAULT_ENV
    """A name in the closed env registry ``safemanip.rl.envs.ENVS`` ('slide-out' or
    'toy-double-integrator'); never an import path."""
    extra_env_kwargs: dict = field(default_factory=dict)
    """Keyword arguments for a non-default env, from the list its registry entry accepts."""
    # -- TD3 options
    twin_critics: bool = True
    """Two critics, target = min of the two (TD3)."""
    target_noise: float = 0.02
    """Std of the target-policy smoothing noise (0 disables it). Small on purpose: placing the box needs
    |a| < 0.03 (5 cm/s of 1.7 m/s), and TD3's usual 0.2 averages the value of that tiny stopping set away."""
    target_noise_clip: float = 0.05
    """The target-policy smoothing noise is clipped to this."""
    policy_delay: int = 2
    """Actor and target networks are updated every this many critic updates."""
    actor_preactivation_penalty: float = 0.0
    """Weight of mean(u^2), u the actor's output before its tanh, added to the actor loss (0: off). A DDPG actor
    can drive u far past the tanh's knee, where its gradient vanishes and it emits one constant action for good
    (logged as ``actor/saturated``); this keeps u near the range where tanh still bends. 1e-3 changes
    nothing for |u| < 1 (a 1e-3 loss against Q's O(0.1)) and pulls hard on |u| > 10."""
    # -- exploration and data flow
    exploration_noise: float = 0.3
    """Std of the Gaussian noise added to the actor's actions in [-1, 1] during collection."""
    noise_per_episode: bool = True
    """Each episode draws its noise std uniformly from [0, exploration_noise]: some episodes act almost as the
    actor would, so the replay holds placements (a box at rest needs |a| < 0.03, which full noise all but
    rules out) as well as wide exploration."""
    noise_color: float = 0.0
    """Spectrum of the exploration noise, as the exponent beta of its power law 1/f^beta (Eberhard et al.,
    "Pink Noise Is All You Need", ICLR 2023): 0 white (independent every step, TD3's usual), 1 pink, 2 red.
    Correlated noise keeps a deviation for many steps -- a detour round the clutter -- where white noise at
    20 Hz averages out within a few steps. Each episode starts a fresh sequence (``colorednoise``)."""
    random_steps: int = 10_000
    """Environment steps taken with uniformly random actions before the actor is used."""
    learning_starts: int = 5_000
    """Environment steps collected before the first update."""
    env_steps_per_update: float = 4.0
    """Target data rate: environment steps collected per learner update (the inverse update-to-data ratio)."""
    n_collectors: int = 1
    """Rollout worker processes, each stepping its envs (4 unless a --config file sets envs_per_collector)
    round-robin on one core."""
    envs_per_collector: int = 4
    """Envs each rollout worker steps round-robin."""
    torch_threads: int = 1
    """Threads for the learner's PyTorch; the collectors use the other core(s)."""
    # -- learner speed, network, selection-aware training, rollout backend
    device: str = "auto"
    """Learner device: 'auto' (CUDA if PyTorch sees a GPU, else CPU), 'cpu' or 'cuda'. Rollouts stay on CPUs."""
    precision: str = "auto"
    """Forward passes in 'bf16' (autocast; fp32 master weights, losses and targets) or 'fp32'; 'auto' takes
    bf16 only where it is native and measured faster at start-up. (``rl/precision.py``.)"""
    network: str = "mlp"
    """'mlp': the paper's flat MLPs over a fixed k; 'set': a shared per-object encoder pooled over the slots
    (order-invariant, absent slots masked), one network for any number of objects."""
    set_embed: int = 128
    """Width of the set network's per-object encoder (two ReLU layers)."""
    scene_objects: int | None = None
    """Selection-aware training: objects in each training scene (N >= k); the object selector picks the
    policy's k objects every 4 control steps and the judge covers all N. (The interval is ``selection_interval``;
    None: N = k.)"""
    scene_objects_min: int | None = None
    """Mixed clutter: each training episode draws N uniformly from this to --scene-objects (or k), so sparse
    scenes, where the task is learnt quickly, keep teaching the dense ones. Slots a scene
    with N < k cannot fill are padded as at deployment: far-away dummy objects for the flat MLP, absent
    (masked) slots for the set network. None: every scene holds the same N."""
    selector: str = "dynamic-knn"
    """Object selector for selection-aware training: 'dynamic-knn' (k nearest), 'dynamic-radius' (every
    object within --selection-radius, at most k; needs --network set) or 'mixed' (each episode draws one of
    the two, so one set-network policy works with either at deployment; needs --network set)."""
    selection_radius: float = 0.35
    """dynamic-radius: horizontal distance from the held box's centre [m] within which objects are picked."""
    selection_interval: int = 4
    """Control steps between re-selections during selection-aware training (the paper's 4)."""
    init_from: str | None = None
    """A finished or interrupted run folder whose checkpoint's networks (actor, critics and their targets)
    start this run: fine-tuning, e.g. a policy trained at N = k continued in larger scenes. The optimiser
    state and replay buffer start afresh; k, network, sizes, embodiment and action curve must match."""
    backend: str = "local"
    """Rollout workers as local processes ('local'), Ray actors ('ray') or in the learner's own process, one chunk at
    a time ('inline': slower, deterministic for a seed); the learner stays in this process."""
    address: str | None = None
    """Ray cluster address (HOST:PORT or 'auto') for --backend ray. None starts a local Ray instance (or joins
    RAY_ADDRESS). Set from the --address flag only: never written to config.json (``to_json``), refused in a
    --config file and dropped from a run's config.json on --resume (``load_run_config``), so that no file can send
    a run, its rollout workers or its policy to a remote cluster."""
    # -- evaluation, logging, checkpoints
    eval_every_s: float = 120.0
    """Seconds between evaluations on held-out seeds."""
    eval_episodes: int = 50
    """Episodes per evaluation."""
    checkpoint_every_s: float = 120.0
    """Seconds between checkpoints."""
    log_every_s: float = 10.0
    """Seconds between logged scalars."""

    def __post_init__(self):
        problems = _type_problems(self)
        if problems:  # the range checks below assume the right types
            raise ConfigError("invalid training config:\n  - " + "\n  - ".join(problems))
        self.hidden = tuple(int(h) for h in self.hidden)
        problems += self._env_problems()
        # every field's own range and choices, from the one table the command line uses too
        for name, allowed in FIELD_CHOICES.items():
            value = getattr(self, name)
            if value not in allowed and not (name == "device" and str(value).startswith("cuda:")
                                             and value[len("cuda:"):].isdigit()):
                problems.append(f"{name} must be one of {', '.join(map(repr, allowed))}, got {value!r}")
        for name, bounds in FIELD_BOUNDS.items():
            value = getattr(self, name)
            if value is not None and not bounds.contains(value):
                problems.append(f"{name} must be in {bounds}, got {value}")
        # rules across fields
        if self.gamma_start is not None and self.gamma_start > self.gamma:
            problems.append(f"gamma_start must be in (0, gamma], got {self.gamma_start}")
        if self.learning_rate_final is not None and self.learning_rate_final > self.learning_rate:
            problems.append(f"learning_rate_final must be in (0, learning_rate = {self.learning_rate}], "
                            f"got {self.learning_rate_final}")
        if self.buffer_size < self.batch_size:
            problems.append("batch_size must be >= 1 and buffer_size >= batch_size")
        if self.learning_starts < self.batch_size:
            problems.append(f"learning_starts ({self.learning_starts}) must be >= batch_size ({self.batch_size})")
        if not self.hidden or min(self.hidden) < 1 or max(self.hidden) > 4096 or len(self.hidden) > 8:
            problems.append(f"hidden must list 1..8 layer widths in 1..4096, got {list(self.hidden)}")
        if not isinstance(self.out_dir, str) or not self.out_dir.strip():
            problems.append("out_dir must be a folder path")
        problems += check_env(self.env_name, self.extra_env_kwargs)
        if self.env_name == DEFAULT_ENV and self.extra_env_kwargs:
            problems.append("extra_env_kwargs apply to non-default envs only (the slide-out env takes its settings "
                            "from env)")
        problems += self._learner_problems()
        if problems:
            raise ConfigError("invalid training config:\n  - " + "\n  - ".join(problems))

    def _env_problems(self) -> list[str]:
        """The training env, checked by ``EnvConfig`` itself (one checker for every way in); an object from a file
        becomes an ``EnvConfig`` over ``TRAINING_ENV``'s values, and n_objects is k's."""
        env = TRAINING_ENV if self.env is None else self.env
        if isinstance(env, dict):
            if "n_objects" in env and env["n_objects"] != self.k:
                return [f"env.n_objects is k's ({self.k}), got {brief(env['n_objects'])}: set k for the policy's "
                        f"slots, and scene_objects for larger training scenes"]
            try:
                env = EnvConfig.from_kwargs({**TRAINING_ENV.kwargs(), **env, "n_objects": self.k}, "env")
            except EnvConfigError as err:
                return [str(err)]
        elif not isinstance(env, EnvConfig):
            return [f"env must be an object of env settings (env.config.EnvConfig), got {brief(env)}"]
        elif env is not TRAINING_ENV and env.n_objects != self.k:
            return [f"env.n_objects is k's ({self.k}), got {env.n_objects}: set k for the policy's slots, and "
                    f"scene_objects for larger training scenes"]
        if isinstance(env.constraints, tuple) or env.constraints not in TRAINING_CONSTRAINTS:
            return [f"env.constraints must be one of {', '.join(map(repr, TRAINING_CONSTRAINTS))} for training "
                    f"('random': every type, the paper's policies trained on all constraint types), got "
                    f"{brief(env.constraints)}"]
        try:
            self.env = replace(env, n_objects=self.k)
        except EnvConfigError as err:
            return [str(err)]
        return []

    def _learner_problems(self) -> list[str]:
        """Checks across the learner fields (network, selection-aware training, backend)."""
        problems = []
        if self.scene_objects is not None:
            if not self.k <= self.scene_objects <= MAX_OBJECTS:
                problems.append(f"scene_objects must be in k..{MAX_OBJECTS} ({self.k}..{MAX_OBJECTS}), "
                                f"got {self.scene_objects}")
            if self.env_name != DEFAULT_ENV:
                problems.append(f"scene_objects (selection-aware training) works on the {DEFAULT_ENV!r} env, "
                                f"not {self.env_name!r}")
        if self.scene_objects_min is not None:
            most = self.scene_objects or self.k
            if not 1 <= self.scene_objects_min <= most:
                problems.append(f"scene_objects_min must be in 1..{most} (the scene_objects, or k, it mixes up to), "
                                f"got {self.scene_objects_min}")
            if self.env_name != DEFAULT_ENV:
                problems.append(f"scene_objects_min (mixed clutter) works on the {DEFAULT_ENV!r} env, not {self.env_name!r}")
        if self.selector in ("dynamic-radius", "mixed") and self.network != "set":
            problems.append(f"selector {self.selector!r} hands the policy a varying number of objects: use network 'set'")
        if self.init_from is not None and (not self.init_from.strip() or len(self.init_from) > 4096):
            problems.append(f"init_from must be a run folder, got {self.init_from!r}")
        if self.address is not None:
            if self.backend != "ray":
                problems.append("address only applies to backend 'ray'")
            elif not self.address.strip() or len(self.address) > 255 or any(c.isspace() for c in self.address):
                problems.append(f"address must be a Ray cluster address (HOST:PORT, or 'auto'), got {self.address!r}")
        return problems

    @property
    def selection_aware(self) -> bool:
        """Training scenes hold more objects than the policy's slots, a varying number of them (mixed clutter),
        or the slots vary (dynamic-radius, mixed)."""
        return self.env_name == DEFAULT_ENV and (self.scene_objects is not None or self.scene_objects_min is not None
                                            or self.selector in ("dynamic-radius", "mixed"))

    @property
    def rollout_env_kwargs(self) -> dict:
        """The env the rollout workers and the periodic evaluation run: ``env_kwargs``, or with selection-aware
        training the registry's ``slide-out-selected`` env: the full N-object scene seen through the selector
        (its factory, ``selection.training_env.SelectedSlotsEnv``, is passed to ``rl.train.train`` by its caller)."""
        if not self.selection_aware:
            return self.env_kwargs
        kwargs = {**self.env_kwargs, "env": SELECTED_ENV, "n_objects": self.scene_objects or self.k, "k": self.k,
                  "selector": self.selector, "radius": self.selection_radius, "interval": self.selection_interval}
        if self.scene_objects_min is not None:
            kwargs.update(min_objects=self.scene_objects_min, empty_slots=self.network == "set")
        return kwargs

    @property
    def env_kwargs(self) -> dict:
        """The training env's settings (``env.config.EnvConfig``), recorded in the policy's metadata."""
        if self.env_name != DEFAULT_ENV:
            return {"env": self.env_name, **self.extra_env_kwargs}
        return self.env.kwargs()

    @property
    def constraint_set(self) -> str:
        """The policy's constraint set as its name and metadata say it: 'conservative' (F^conser) or 'all'."""
        return TRAINING_CONSTRAINTS[self.env.constraints]

    def learning_rate_at(self, progress: float) -> float:
        if self.learning_rate_final is None:
            return self.learning_rate
        frac = min(1.0, max(0.0, progress))
        return self.learning_rate_final + (self.learning_rate - self.learning_rate_final) * 0.5 * (1 + math.cos(math.pi * frac))

    def gamma_at(self, progress: float) -> float:
        if self.gamma_start is None:
            return self.gamma
        frac = min(1.0, max(0.0, progress / 0.5))
        return self.gamma_start + frac * (self.gamma - self.gamma_start)

    def to_json(self) -> str:
        """The config as written to config.json, checkpoints and policies: every field but the Ray address, the env
        as its keyword arguments (``EnvConfig.kwargs``)."""
        out = {f.name: getattr(self, f.name) for f in fields(self) if f.name not in NOT_RECORDED}
        out["env"] = {k: v for k, v in self.env.kwargs().items() if k != "n_objects"}  # k's
        out["hidden"] = list(self.hidden)
        return json.dumps(out, indent=1)

    @classmethod
    def from_dict(cls, data: dict) -> "TrainConfig":
        if not isinstance(data, dict):
            raise ConfigError(f"a training config must be a JSON object of TrainConfig fields, got {type(data).__name__}")
        data = dict(data)
        problems = retired_key_problems(data)
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known - set(RETIRED_KEYS))
        if unknown:
            problems.append(f"unknown config key(s) {unknown}; known keys: {sorted(known)}")
        if problems:
            raise ConfigError("invalid training config:\n  - " + "\n  - ".join(problems))
        return cls(**data)

    @classmethod
    def from_file(cls, path: str | Path) -> "TrainConfig":
        """A --config file: TrainConfig fields as a JSON object. A Ray address in it is refused (it comes from
        --address or RAY_ADDRESS only)."""
        data = _read_config(path)
        if isinstance(data, dict) and data.get("address") is not None:
            raise ConfigError(f"{path}: a config file may not name a Ray cluster ('address'): the address comes from "
                              f"--address HOST:PORT or the RAY_ADDRESS environment variable only; remove it from the file")
        return _from_file_dict(data, path)


def _from_file_dict(data, path: str | Path) -> "TrainConfig":
    """``TrainConfig.from_dict`` of a file's contents, its refusal naming the file."""
    try:
        return TrainConfig.from_dict(data)
    except ConfigError as err:
        raise ConfigError(f"{path}: {err}") from None


def load_run_config(path: str | Path) -> tuple[TrainConfig, str | None]:
    """(config, dropped address) of a run folder's config.json (for --resume and --init-from). A Ray address
    recorded by an older version is dropped, not used: the caller says so."""
    data = _read_config(path)
    dropped = data.pop("address", None) if isinstance(data, dict) else None
    return _from_file_dict(data, path), (str(dropped)[:300] if dropped is not None else None)


def _read_config(path: str | Path):
    from safemanip.util.files import JSONInputError, read_json_file

    try:
        return read_json_file(path, str(path), max_bytes=MAX_CONFIG_BYTES)
    except OSError as err:
        raise ConfigError(f"cannot read the config {path}: {err.strerror or err}") from err
    except JSONInputError as err:
        raise ConfigError(str(err)) from err


FLAT_ENV_KEYS = ("constraints", "near_path_fraction", "clear_route", "layout", "embodiment", "action_curve",
                 "object_size", "slot_order", "max_episode_steps")
"""The env settings that the training-config format written before 2026-12-08 kept at the top level (and its ``env``,
then the registry name, now ``env_name``): retired in issue 43 when the env's settings moved under ``env``."""
RETIRED_KEYS = ("n_objects", "env_factory") + FLAT_ENV_KEYS
"""Keys of the training-config format written before 2026-12-01 (``n_objects`` for the slot count k, ``env_factory``
for the env as a Python class): retired in issue 43, refused by ``TrainConfig.from_dict`` with what to do instead,
never converted."""


def retired_key_problems(data: dict) -> list[str]:
    """What to do about each retired key in a config (run folder, policy metadata or --config file)."""
    problems = []
    flat = [key for key in FLAT_ENV_KEYS if key in data]
    if flat or isinstance(data.get("env"), str):
        problems.append(f"{', '.join(flat) or 'env as a name'} at the top level of a training config: that is the format written "
                        f"before 2026-12-08, retired in issue 43. The env's settings go in an object under 'env' (e.g. "
                        f"\"env\": {{\"layout\": \"gate\", \"constraints\": \"random\"}}; constraints 'all' is now "
                        f"'random'), and a registry env's name under 'env_name'. A run folder in the old format: start a "
                        f"new run (safemanip train ... --out NEW_FOLDER)")
    if "n_objects" in data:
        problems.append("key 'n_objects' is not a training setting: the policy's object slots are 'k' and a larger "
                        "training scene is 'scene_objects'. A run folder or policy that stores the slot count as "
                        "'n_objects' was written before 2026-12-01, a format retired in issue 43: re-train it "
                        "(safemanip train --k K ...); in a config file of your own, drop it and use those two keys")
    if "env_factory" in data:
        problems.append(f"env_factory {_brief(data['env_factory'])} is not accepted: naming an env by its Python "
                        f"class is the format of run folders written before 2026-12-01, retired in issue 43, and "
                        f"nothing in a config is imported. Name the env with 'env_name', one of {sorted(ENVS)} (default "
                        f"{DEFAULT_ENV!r}), and re-train a run folder that has the old key")
    return problems


def _brief(value, limit: int = 80) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


NOT_RECORDED = ("address",)
"""TrainConfig fields never written to a file (``to_json``)."""
MAX_CONFIG_BYTES = 1_000_000


MAX_RADIUS = 10.0
"""Largest selection_radius [m]: the table is about 1.5 m across, so this already means every object."""


@dataclass(frozen=True)
class Bounds:
    """A field's range: [lo, hi], either end open if so marked."""

    lo: float
    hi: float
    lo_open: bool = False
    hi_open: bool = False

    def contains(self, value) -> bool:
        return (value > self.lo if self.lo_open else value >= self.lo) and \
            (value < self.hi if self.hi_open else value <= self.hi)

    def __str__(self) -> str:
        def number(x: float) -> str:
            return f"{int(x):,}" if float(x).is_integer() else f"{x:g}"
        return f"{'(' if self.lo_open else '['}{number(self.lo)}, {number(self.hi)}{')' if self.hi_open else ']'}"


FIELD_BOUNDS = {
    "k": Bounds(0, MAX_OBJECTS),
    "total_env_steps": Bounds(1, 10**12), "minutes": Bounds(0, 60 * 24 * 365, lo_open=True), "seed": Bounds(0, 2**32 - 1),
    "batch_size": Bounds(1, 65_536), "learning_rate": Bounds(0, 1, lo_open=True),
    "learning_rate_final": Bounds(0, 1, lo_open=True), "buffer_size": Bounds(1, 10**7),
    "gamma": Bounds(0, 1, lo_open=True, hi_open=True), "gamma_start": Bounds(0, 1, lo_open=True, hi_open=True),
    "polyak": Bounds(0, 1, lo_open=True, hi_open=True),
    "target_noise": Bounds(0, 10), "target_noise_clip": Bounds(0, 10), "policy_delay": Bounds(1, 1_000),
    "actor_preactivation_penalty": Bounds(0, 10), "exploration_noise": Bounds(0, 10), "noise_color": Bounds(0, 2),
    "random_steps": Bounds(0, 10**12), "learning_starts": Bounds(1, 10**9),
    "env_steps_per_update": Bounds(0, 10_000, lo_open=True), "n_collectors": Bounds(1, 64),
    "envs_per_collector": Bounds(1, 256), "torch_threads": Bounds(1, 256), "set_embed": Bounds(1, 4096),
    "scene_objects": Bounds(0, MAX_OBJECTS), "scene_objects_min": Bounds(1, MAX_OBJECTS),
    "selection_radius": Bounds(0, MAX_RADIUS, lo_open=True), "selection_interval": Bounds(1, 100_000),
    "eval_every_s": Bounds(0, 86_400, lo_open=True), "eval_episodes": Bounds(1, 100_000),
    "checkpoint_every_s": Bounds(0, 86_400, lo_open=True), "log_every_s": Bounds(0, 86_400, lo_open=True),
}
"""Every numeric field's range, in one place: ``TrainConfig`` checks a config against it and ``safemanip train``
builds its flags' argparse types from it. The upper bounds keep a typo from allocating terabytes or spawning hundreds
of processes."""
FIELD_CHOICES = {
    "algorithm": ("rarl", "vanilla"), "device": ("auto", "cpu", "cuda"),
    "precision": ("auto", "bf16", "fp32"), "network": ("mlp", "set"),
    "selector": ("dynamic-knn", "dynamic-radius", "mixed"), "backend": ("local", "ray", "inline"),
}
"""Every field that names one of a closed set, and the set. (The env's fields, robots and layouts among them, are
checked by ``EnvConfig`` against the registries themselves, so a registered one is taken everywhere at once.)"""

_KINDS = {"int": (int,), "float": (int, float), "str": (str,), "bool": (bool,), "dict": (dict,)}


def _type_problems(cfg: "TrainConfig") -> list[str]:
    """Each field's value has its declared type (ints are ints, floats finite); tuples of ints for hidden."""
    problems = []
    for f in fields(cfg):
        value = getattr(cfg, f.name)
        optional = "| None" in f.type
        if value is None and optional or f.name == "env":  # the env is checked by EnvConfig (_env_problems)
            continue
        kind = f.type.replace(" | None", "").strip()
        if kind.startswith("tuple"):
            if not isinstance(value, (list, tuple)) or not all(isinstance(h, int) and not isinstance(h, bool)
                                                              for h in value):
                problems.append(f"{f.name} must be a list of integers, got {value!r}")
            continue
        types = _KINDS[kind]
        if not isinstance(value, types) or (kind != "bool" and isinstance(value, bool)):
            problems.append(f"{f.name} must be {'an' if kind == 'int' else 'a'} {kind}"
                            f"{' or null' if optional else ''}, got {value!r}")
        elif kind == "float" and not math.isfinite(value):
            problems.append(f"{f.name} must be a finite number, got {value!r}")
    return problems


"""Training configuration: one dataclass, validated before any work starts."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

from safemanip.scene.config import MAX_OBJECTS


class ConfigError(ValueError):
    """A training config that cannot run; the message says what to change."""


@dataclass
class TrainConfig:
    algorithm: str = "rarl"
    """'rarl' (discounted reach-avoid backup) or 'vanilla' (DDPG on the return of r = min(l, g))."""
    n_objects: int = 2
    """Clutter objects in every training scene (the policy's k)."""
    constraints: str = "conservative"
    """'conservative': every object no_contact (paper F^conser); 'all': each object's constraint drawn
    uniformly from {no_contact, soft_contact, any_contact} every episode."""
    near_path_fraction: float = 0.5
    """Share of the clutter placed near the path to the goal."""
    slot_order: str = "nearest"
    """Order of the object slots in the observation: 'nearest' (by distance to the held box, re-sorted every
    step -- the order the deployment reducer uses) or 'index' (the scene's fixed object order)."""
    total_env_steps: int = 2_000_000
    """Budget in environment steps (the run stops at whichever budget is reached first)."""
    minutes: float | None = 60.0
    """Budget in wall-clock minutes (None: no time limit)."""
    seed: int = 0
    out_dir: str = "runs/rarl"
    # -- Table V
    batch_size: int = 200
    learning_rate: float = 1e-3
    buffer_size: int = 100_000
    gamma: float = 0.99
    """Discount factor; with ``gamma_start`` set it is annealed from gamma_start to this value."""
    gamma_start: float | None = None
    """If set, gamma rises linearly from this value to ``gamma`` over the first half of the budget."""
    polyak: float = 0.995
    hidden: tuple[int, ...] = (256, 256, 256)
    max_episode_steps: int = 300
    # -- another env (e.g. the toy system, safemanip.rl.toy)
    env_factory: str | None = None
    """'module:Class' of the env to train on instead of the slide-out env (None: slide-out)."""
    extra_env_kwargs: dict = field(default_factory=dict)
    """Keyword arguments for ``env_factory``'s class (only with env_factory set)."""
    # -- TD3 options
    twin_critics: bool = True
    """Two critics, target = min of the two (TD3)."""
    target_noise: float = 0.2
    """Std of the target-policy smoothing noise (0 disables it)."""
    target_noise_clip: float = 0.5
    policy_delay: int = 2
    """Actor and target networks are updated every this many critic updates."""
    # -- exploration and data flow
    exploration_noise: float = 0.3
    """Std of the Gaussian noise added to the actor's actions in [-1, 1] during collection."""
    random_steps: int = 10_000
    """Environment steps taken with uniformly random actions before the actor is used."""
    learning_starts: int = 5_000
    """Environment steps collected before the first update."""
    env_steps_per_update: float = 4.0
    """Target data rate: environment steps collected per learner update (the inverse update-to-data ratio)."""
    n_collectors: int = 1
    """Rollout worker processes (each simulates ``envs_per_collector`` envs round-robin on one core)."""
    envs_per_collector: int = 4
    torch_threads: int = 1
    """Threads for the learner's PyTorch; the collectors use the other core(s)."""
    # -- learner speed, network, selection-aware training, rollout backend (issue 10)
    device: str = "auto"
    """Learner device: 'auto' (CUDA if PyTorch sees a GPU, else CPU), 'cpu' or 'cuda'. Rollouts stay on CPUs."""
    precision: str = "auto"
    """Forward passes in 'bf16' (autocast; fp32 master weights, losses and targets) or 'fp32'; 'auto' takes
    bf16 only where it is native and measured faster at start-up (rl/precision.py)."""
    network: str = "mlp"
    """'mlp': the paper's flat MLPs over a fixed k; 'set': a shared per-object encoder pooled over the slots
    (order-invariant, absent slots masked), one network for any number of objects."""
    set_embed: int = 128
    """Width of the set network's per-object encoder (two ReLU layers)."""
    scene_objects: int | None = None
    """Selection-aware training: objects in each training scene (N >= n_objects); the object selector picks
    the policy's slots every ``selection_interval`` steps and the judge covers all N. None: N = n_objects."""
    selector: str = "dynamic-knn"
    """Object selector for selection-aware training: 'dynamic-knn' (k nearest) or 'dynamic-radius' (every
    object within ``selection_radius``, at most n_objects; needs network='set')."""
    selection_radius: float = 0.35
    """dynamic-radius: horizontal distance from the held box's centre [m] within which objects are picked."""
    selection_interval: int = 4
    """Control steps between re-selections during selection-aware training (the paper's 4)."""
    backend: str = "local"
    """Rollout workers as local processes ('local') or Ray actors ('ray'); the learner stays in this process."""
    address: str | None = None
    """Ray cluster address (HOST:PORT or 'auto'); None starts a local Ray instance. Only with backend='ray'."""
    # -- evaluation, logging, checkpoints
    eval_every_s: float = 120.0
    eval_episodes: int = 50
    checkpoint_every_s: float = 120.0
    log_every_s: float = 10.0

    def __post_init__(self):
        self.hidden = tuple(int(h) for h in self.hidden)
        problems = []
        if self.algorithm not in ("rarl", "vanilla"):
            problems.append(f"algorithm must be 'rarl' or 'vanilla', got {self.algorithm!r}")
        if self.constraints not in ("conservative", "all"):
            problems.append(f"constraints must be 'conservative' or 'all', got {self.constraints!r}")
        if not 0 <= self.n_objects <= MAX_OBJECTS:
            problems.append(f"n_objects must be 0..{MAX_OBJECTS}, got {self.n_objects}")
        if not 0 < self.gamma < 1:
            problems.append(f"gamma must be in (0, 1), got {self.gamma}")
        if self.gamma_start is not None and not 0 < self.gamma_start <= self.gamma:
            problems.append(f"gamma_start must be in (0, gamma], got {self.gamma_start}")
        if not 0 < self.polyak < 1:
            problems.append(f"polyak must be in (0, 1), got {self.polyak}")
        if self.batch_size < 1 or self.buffer_size < self.batch_size:
            problems.append("batch_size must be >= 1 and buffer_size >= batch_size")
        if self.total_env_steps < 1 or (self.minutes is not None and self.minutes <= 0):
            problems.append("the budget must be positive: total_env_steps >= 1 and minutes > 0 (or None)")
        if self.learning_starts < self.batch_size:
            problems.append(f"learning_starts ({self.learning_starts}) must be >= batch_size ({self.batch_size})")
        if self.env_steps_per_update <= 0 or self.n_collectors < 1 or self.envs_per_collector < 1:
            problems.append("env_steps_per_update > 0, n_collectors >= 1 and envs_per_collector >= 1 are required")
        if self.slot_order not in ("nearest", "index"):
            problems.append(f"slot_order must be 'nearest' or 'index', got {self.slot_order!r}")
        if not self.hidden or min(self.hidden) < 1:
            problems.append(f"hidden must list positive layer widths, got {self.hidden}")
        if self.policy_delay < 1 or self.torch_threads < 1:
            problems.append("policy_delay and torch_threads must be >= 1")
        if self.env_factory is not None and (not isinstance(self.env_factory, str)
                                             or len(self.env_factory.split(":")) != 2 or "" in self.env_factory.split(":")):
            problems.append(f"env_factory must be 'module:Class', got {self.env_factory!r}")
        if not isinstance(self.extra_env_kwargs, dict) or (self.extra_env_kwargs and self.env_factory is None):
            problems.append("extra_env_kwargs must be a dict, and is only used with env_factory set")
        problems += self._learner_problems()
        if problems:
            raise ConfigError("invalid training config:\n  - " + "\n  - ".join(problems))

    def _learner_problems(self) -> list[str]:
        """Checks of the issue-10 fields (device, precision, network, selection-aware training, backend)."""
        problems = []
        for name, allowed in (("device", ("auto", "cpu", "cuda")), ("precision", ("auto", "bf16", "fp32")),
                              ("network", ("mlp", "set")), ("selector", ("dynamic-knn", "dynamic-radius")),
                              ("backend", ("local", "ray"))):
            value = getattr(self, name)
            if value not in allowed and not (name == "device" and str(value).startswith("cuda:")):
                problems.append(f"{name} must be one of {allowed}, got {value!r}")
        if self.set_embed < 1 or self.selection_interval < 1 or self.selection_radius <= 0:
            problems.append("set_embed >= 1, selection_interval >= 1 and selection_radius > 0 are required")
        if self.scene_objects is not None:
            if not self.n_objects <= self.scene_objects <= MAX_OBJECTS:
                problems.append(f"scene_objects must be in n_objects..{MAX_OBJECTS} ({self.n_objects}..), "
                                f"got {self.scene_objects}")
            if self.env_factory is not None:
                problems.append("scene_objects (selection-aware training) works on the slide-out env, not env_factory")
        if self.selector == "dynamic-radius" and self.network != "set":
            problems.append("selector 'dynamic-radius' hands the policy a varying number of objects: use network 'set'")
        if self.address is not None and self.backend != "ray":
            problems.append("address only applies to backend 'ray'")
        return problems

    @property
    def selection_aware(self) -> bool:
        """Training scenes hold more objects than the policy's slots, or the slots vary (dynamic-radius)."""
        return self.env_factory is None and (self.scene_objects is not None or self.selector == "dynamic-radius")

    @property
    def rollout_env_kwargs(self) -> dict:
        """The env the rollout workers and the periodic evaluation run: ``env_kwargs``, or with selection-aware
        training the full-scene env seen through the selector (``selection.training_env``)."""
        if not self.selection_aware:
            return self.env_kwargs
        return {"factory": "safemanip.selection.training_env:SelectedSlotsEnv", **self.env_kwargs,
                "n_objects": self.scene_objects or self.n_objects, "k": self.n_objects, "selector": self.selector,
                "radius": self.selection_radius, "interval": self.selection_interval}

    @property
    def env_kwargs(self) -> dict:
        if self.env_factory is not None:
            return {"factory": self.env_factory, **self.extra_env_kwargs}
        return {"n_objects": self.n_objects, "constraints": "random" if self.constraints == "all" else "conservative",
                "near_path_fraction": self.near_path_fraction, "max_episode_steps": self.max_episode_steps,
                "slot_order": self.slot_order}

    def gamma_at(self, progress: float) -> float:
        if self.gamma_start is None:
            return self.gamma
        frac = min(1.0, max(0.0, progress / 0.5))
        return self.gamma_start + frac * (self.gamma - self.gamma_start)

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=1)

    @classmethod
    def from_dict(cls, data: dict) -> "TrainConfig":
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ConfigError(f"unknown config key(s) {unknown}; known keys: {sorted(known)}")
        return cls(**data)

    @classmethod
    def from_file(cls, path: str | Path) -> "TrainConfig":
        try:
            return cls.from_dict(json.loads(Path(path).read_text()))
        except json.JSONDecodeError as err:
            raise ConfigError(f"{path} is not valid JSON: {err}") from err

"""``benchmark.json``: the benchmark's settings, training seeds, shared recipe, budget and seed blocks, loaded into
typed objects and checked in one place (``load_benchmark``) before anything runs.

The file (the shipped one is package data beside this module; ``--benchmark FILE`` gives another)::

  {"description": "...",                          optional, free text
   "budget_env_steps": STEPS,                     every run stops at this many environment steps
   "recipe": {"gamma": ..., ...},                 training settings every run shares (training-config keys)
   "seeds": [SEED, ...],                          every setting is trained once per seed
   "selection": {"block": B, "episodes": N},      the seed block that chooses a run's final or best policy
   "reporting": {"fig4": B, ...},                 the shipped sweeps the benchmark reports, each with its block
   "settings": [{"name": "rarl-k2-conservative", "group": "table1", "algorithm": "rarl", "k": 2, ...}, ...]}

A setting is its name, its queue group and the training-config keys that set it apart. Its runs are named
``NAME-sSEED``, the policy file names the sweeps read a cell's algorithm, k, constraints and training from, so a
name must say what its keys say. Runs are queued group by group (in the order the groups first appear), each group
seed by seed: a queue stopped part-way has whole findings (each judged over every seed) rather than one seed of all.

Nothing in the file runs code: its values are numbers, names and training-config values, each checked here.
"""

from __future__ import annotations

import reprlib
from dataclasses import dataclass
from fnmatch import fnmatchcase
from importlib import resources
from pathlib import Path

SHIPPED = "benchmark.json"
"""The shipped benchmark, package data of ``safemanip.bench``."""
REQUIRED_KEYS = ("budget_env_steps", "recipe", "seeds", "selection", "reporting", "settings")
OPTIONAL_KEYS = ("description",)
SET_PER_RUN = {"seed": "the 'seeds' list", "total_env_steps": "'budget_env_steps'",
               "out_dir": "safemanip bench train --out"}
"""Training-config keys a run gets from elsewhere than the recipe or its setting (and where from)."""
NEVER_FROM_A_FILE = {"address": "the Ray cluster comes from --address or RAY_ADDRESS only"}
SETTING_KEYS = ("name", "group")
"""A setting's own keys; every other key of a setting is a training-config key."""


class BenchmarkError(ValueError):
    """A benchmark file that cannot be used; the message names the file, the key and the fix."""


@dataclass(frozen=True)
class Setting:
    name: str
    """The runs' name without the seed, e.g. 'rarl-k2-conservative-selaware'."""
    group: str
    """The queue group: runs are trained group by group (e.g. 'table1': what Table I needs)."""
    config: dict
    """The training-config keys that set this setting apart from the recipe (algorithm, k, constraints, ...)."""


@dataclass(frozen=True)
class Run:
    setting: Setting
    seed: int

    @property
    def name(self) -> str:
        """The run's folder name and its policy's name: ``SETTING-sSEED``."""
        return f"{self.setting.name}-s{self.seed}"


@dataclass(frozen=True)
class Benchmark:
    source: str
    """Where it was read from (for messages)."""
    settings: tuple[Setting, ...]
    seeds: tuple[int, ...]
    recipe: dict
    budget_env_steps: int
    selection_block: int
    selection_episodes: int
    reporting: dict
    """Shipped sweep name -> the seed block it reports on."""

    @property
    def runs(self) -> list[Run]:
        """Every run in queue order: group by group, each group seed by seed."""
        groups = list(dict.fromkeys(s.group for s in self.settings))
        return [Run(s, seed) for group in groups for seed in self.seeds for s in self.settings if s.group == group]

    def select(self, patterns: list[str] | None) -> list[Run]:
        """The runs whose name matches one of the shell-style ``patterns`` (all without any), in queue order. A
        pattern that matches no run is an error: a typo must not train nothing silently."""
        runs = self.runs
        if not patterns:
            return runs
        unmatched = [p for p in patterns if not any(fnmatchcase(r.name, p) for r in runs)]
        if unmatched:
            raise BenchmarkError(f"--only {' '.join(unmatched)} matches no run of {self.source}; runs are named like "
                                 f"{runs[0].name} (use * and ?, e.g. --only 'rarl-k2-*' or --only '*-s0')")
        return [r for r in runs if any(fnmatchcase(r.name, p) for p in patterns)]

    def config(self, run: Run, run_dir: str | Path):
        """The run's training config: the recipe, its setting's keys, its seed, the budget and its folder."""
        from safemanip.rl.config import TrainConfig

        env = {**self.recipe.get("env", {}), **run.setting.config.get("env", {})}  # the env's keys, from either
        return TrainConfig.from_dict({**self.recipe, **run.setting.config, "env": env, "seed": run.seed,
                                      "total_env_steps": self.budget_env_steps, "out_dir": str(run_dir)})


def load_benchmark(path: str | Path | None = None) -> Benchmark:
    """The benchmark at ``path`` (None: the shipped one), every problem found reported at once (BenchmarkError)."""
    from safemanip.util.files import JSONInputError, parse_json, read_json_file

    source = str(path) if path is not None else f"the shipped {SHIPPED}"
    try:
        if path is None:
            data = parse_json(resources.files("safemanip.bench").joinpath(SHIPPED).read_text(), source)
        else:
            data = read_json_file(path, str(path))
    except JSONInputError as err:
        raise BenchmarkError(f"{source}: not a benchmark file ({err.reason}); fix the JSON") from None
    except OSError as err:
        raise BenchmarkError(f"cannot read the benchmark file {source} ({err.strerror or err}); give an existing "
                             f"file to --benchmark, or leave it out for the shipped one") from None
    bench, problems = _parse(data, source)
    if problems:
        raise BenchmarkError(f"{source} cannot be used:\n  - " + "\n  - ".join(problems))
    return bench


def _parse(data, source: str) -> tuple[Benchmark | None, list[str]]:
    """(the benchmark, []) or (None, every problem of ``data``)."""
    if not isinstance(data, dict):
        return None, [f"a benchmark file is a JSON object of {', '.join(REQUIRED_KEYS)}; got {reprlib.repr(data)}"]
    problems = [f"missing key {k!r}" for k in REQUIRED_KEYS if k not in data]
    unknown = [k for k in data if k not in REQUIRED_KEYS + OPTIONAL_KEYS]
    if unknown:
        problems.append(f"unknown key(s) {', '.join(map(repr, unknown))}; a benchmark file takes "
                        f"{', '.join(REQUIRED_KEYS + OPTIONAL_KEYS)}")
    if problems:
        return None, problems
    budget, recipe, seeds = data["budget_env_steps"], data["recipe"], data["seeds"]
    if type(budget) is not int or budget < 1:
        problems.append(f"budget_env_steps must be a positive whole number of environment steps, got "
                        f"{reprlib.repr(budget)}")
    if not (isinstance(seeds, list) and seeds and all(type(s) is int and s >= 0 for s in seeds)
            and len(set(seeds)) == len(seeds)):
        problems.append(f"seeds must be a non-empty list of distinct training seeds (whole numbers >= 0), got "
                        f"{reprlib.repr(seeds)}")
    if not isinstance(recipe, dict):
        problems.append(f"recipe must be an object of training settings, got {reprlib.repr(recipe)}")
    else:
        problems += [f"recipe: {p}" for p in _key_problems(recipe)]
    selection_block, selection_episodes = _selection(data["selection"], problems)
    reporting = _reporting(data["reporting"], selection_block, problems)
    settings = _settings(data["settings"], recipe if isinstance(recipe, dict) else {}, problems)
    if problems:
        return None, problems
    bench = Benchmark(source, tuple(settings), tuple(seeds), dict(recipe), budget, selection_block,
                      selection_episodes, reporting)
    for setting in settings:  # the whole config of one run per setting: the config checks itself
        problems += _config_problems(bench, setting)
    return (None if problems else bench), problems


def _key_problems(keys: dict) -> list[str]:
    """Keys of a recipe or a setting that are not training settings it may hold."""
    from dataclasses import fields

    from safemanip.rl.config import TrainConfig

    known = {f.name for f in fields(TrainConfig)}
    problems = []
    for key in keys:
        if key in SET_PER_RUN:
            problems.append(f"{key!r} is set per run, from {SET_PER_RUN[key]}: remove it")
        elif key in NEVER_FROM_A_FILE:
            problems.append(f"{key!r} may not be given in a file ({NEVER_FROM_A_FILE[key]}): remove it")
        elif key not in known:
            problems.append(f"unknown training setting {key!r}; the training settings are those of "
                            f"safemanip train --config ({', '.join(sorted(known - set(SET_PER_RUN)))})")
        elif key == "env" and not isinstance(keys[key], dict):
            problems.append(f"'env' must be an object of env settings (e.g. {{\"layout\": \"exit\"}}), got "
                            f"{reprlib.repr(keys[key])}")
    return problems


def _selection(selection, problems: list[str]) -> tuple[int, int]:
    from safemanip.evaluation.harness import SEED_STRIDE

    most = 2**31 // SEED_STRIDE - 1
    if not (isinstance(selection, dict) and set(selection) == {"block", "episodes"}):
        problems.append(f"selection must be {{\"block\": B, \"episodes\": N}}, got {reprlib.repr(selection)}")
        return -1, 0
    block, episodes = selection["block"], selection["episodes"]
    if type(block) is not int or not 0 <= block <= most:
        problems.append(f"selection.block must be a seed block 0..{most}, got {reprlib.repr(block)}")
    if type(episodes) is not int or not 1 <= episodes <= SEED_STRIDE:
        problems.append(f"selection.episodes must be a whole number 1..{SEED_STRIDE}, got {reprlib.repr(episodes)}")
    return block, episodes


def _reporting(reporting, selection_block: int, problems: list[str]) -> dict:
    """The reporting blocks, each one a shipped sweep's own ("seed" in its spec: the two must agree), none the
    selection block (nothing reported may have been chosen on the episodes it is reported on)."""
    from safemanip.evaluation.sweep.spec import SweepError, available, load_config

    if not (isinstance(reporting, dict) and reporting):
        problems.append(f"reporting must be an object of shipped sweep names and seed blocks, e.g. {{\"fig4\": 31}}, "
                        f"got {reprlib.repr(reporting)}")
        return {}
    for name, block in reporting.items():
        if name not in available():
            problems.append(f"reporting: no shipped sweep {name!r}; the shipped sweeps are {', '.join(available())}")
            continue
        if block == selection_block:
            problems.append(f"reporting.{name} is block {block}, the selection block: a policy chosen on these "
                            f"episodes would be reported on them too; give the sweep another block")
        try:
            spec_block = load_config(name).seed
        except SweepError as err:
            problems.append(f"reporting.{name}: {err}")
            continue
        if block != spec_block:
            problems.append(f"reporting.{name} is block {reprlib.repr(block)} but the sweep's spec reports on block "
                            f"{spec_block}: make the two agree (the spec's \"seed\" is what the sweep runs)")
    return dict(reporting)


def _settings(settings, recipe: dict, problems: list[str]) -> list[Setting]:
    if not (isinstance(settings, list) and settings):
        problems.append(f"settings must be a non-empty list of settings, got {reprlib.repr(settings)}")
        return []
    out, seen = [], set()
    for i, entry in enumerate(settings):
        where = f"settings[{i}]"
        if not isinstance(entry, dict) or not all(isinstance(entry.get(k), str) and entry[k] for k in SETTING_KEYS):
            problems.append(f"{where} must be an object with a 'name', a 'group' and training settings, got "
                            f"{reprlib.repr(entry)}")
            continue
        name = entry["name"]
        where = f"settings[{i}] ({name})"
        if name in seen:
            problems.append(f"{where}: the name is given twice; every setting needs its own")
        seen.add(name)
        config = {k: v for k, v in entry.items() if k not in SETTING_KEYS}
        problems += [f"{where}: {p}" for p in _key_problems(config)]
        twice = sorted(set(config) & set(recipe) - {"env"})
        if isinstance(config.get("env"), dict) and isinstance(recipe.get("env"), dict):
            twice += [f"env.{key}" for key in sorted(set(config["env"]) & set(recipe["env"]))]
        if twice:
            problems.append(f"{where}: {', '.join(twice)} also in the recipe; set each once, in the recipe or in "
                            f"the settings")
        out.append(Setting(name, entry["group"], config))
    return out


def _config_problems(bench: Benchmark, setting: Setting) -> list[str]:
    """What the training config refuses in a setting's first run, and whether the setting's name says what its keys
    say (a sweep refuses a policy whose metadata contradicts its file name, which makes its cell ids)."""
    from safemanip.evaluation.sweep.spec import POLICY_NAME
    from safemanip.rl.config import ConfigError

    run = Run(setting, bench.seeds[0])
    try:
        cfg = bench.config(run, "runs")
    except ConfigError as err:
        return [f"settings ({setting.name}): {str(err).replace(chr(10) + '  - ', ' ').strip()}"]
    named = POLICY_NAME.fullmatch(run.name)
    wanted = f"{cfg.algorithm}-k{cfg.k}-{cfg.constraint_set}{'-selaware' if cfg.selection_aware else ''}"
    if named is None or setting.name != wanted:
        return [f"settings ({setting.name}): its keys make it {wanted!r}; name it so (policy files are named "
                f"ALGORITHM-kK-CONSTRAINTS[-selaware]-sSEED, and a sweep refuses a policy its name contradicts)"]
    return []

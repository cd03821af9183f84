"""``safemanip train``: flags override a ``TrainConfig`` (validated before any work); ``--resume`` continues
the run in the folder given, with that run's own config."""

from __future__ import annotations

import json
import shlex
import signal
import sys
from pathlib import Path

from safemanip.cli.common import CliError, add_config_flags, add_env_flags, env_flag, env_flag_values

FLAGS = {
    "--algorithm": "algorithm", "--k": "k",
    "--total-env-steps": "total_env_steps", "--minutes": "minutes", "--seed": "seed", "--out": "out_dir",
    "--init-from": "init_from", "--gamma": "gamma", "--gamma-start": "gamma_start",
    "--learning-rate-final": "learning_rate_final", "--noise-color": "noise_color",
    "--actor-preactivation-penalty": "actor_preactivation_penalty", "--env-steps-per-update": "env_steps_per_update",
    "--eval-every-s": "eval_every_s", "--eval-episodes": "eval_episodes", "--checkpoint-every-s": "checkpoint_every_s",
    # learner speed, network, selection-aware training and rollout backend
    "--device": "device", "--precision": "precision", "--network": "network", "--scene-objects": "scene_objects",
    "--scene-objects-min": "scene_objects_min", "--selector": "selector", "--selection-radius": "selection_radius",
    "--backend": "backend", "--address": "address", "--workers": "n_collectors",
}
"""The ``TrainConfig`` fields with a flag; every other field is set through ``--config``. The flags' types, ranges,
choices and help come from the config itself (``cli.common.add_config_flags``). The env's settings have a flag each,
generated from ``EnvConfig`` (``cli.common.add_env_flags``): every one but n_objects (k's) and the lists (names,
classes: through --config)."""
EXTRA_HELP = {"address": "Default: RAY_ADDRESS, else a local Ray instance; never read from a config file."}


def _cmd_train(args) -> int:
    from safemanip.rl.config import TrainConfig, load_run_config
    from safemanip.rl.train import train
    from safemanip.util.files import check_output_dir

    given = {field: getattr(args, field) for field in FLAGS.values() if getattr(args, field) is not None}
    given_env = env_flag_values(args)
    if given.get("minutes") == 0:
        given["minutes"] = None  # documented: 0 means no time limit
    if args.resume:
        run_dir = Path(args.resume)
        if not (run_dir / "config.json").is_file():
            raise CliError(f"--resume {args.resume}: no config.json there; is it a run folder?")
        if args.config:
            raise CliError("--resume uses the run's own config.json; drop --config")
        cfg, dropped = load_run_config(run_dir / "config.json")
        if dropped is not None:
            print(f"safemanip train: note: {run_dir / 'config.json'} records a Ray cluster address ({dropped!r}); it is "
                  f"ignored: the address comes from --address or RAY_ADDRESS only", file=sys.stderr)
        if "out_dir" in given and Path(given.pop("out_dir")).resolve() != run_dir.resolve():
            raise CliError(f"--resume writes into {run_dir}; --out names another folder. Copy the run folder there "
                           f"and resume the copy instead")
        address = given.pop("address", None)  # where the workers run, not a setting of the run: allowed
        conflicts = [f"{flag} {getattr(args, field)} (the run has {getattr(cfg, field)!r})"
                     for flag, field in FLAGS.items() if field in given and given[field] != getattr(cfg, field)]
        conflicts += [f"{env_flag(field)} {value} (the run has {getattr(cfg.env, field)!r})"
                      for field, value in given_env.items() if value != getattr(cfg.env, field)]
        if conflicts:
            raise CliError(f"--resume continues {run_dir} with its own settings; these flags differ from them: "
                           f"{'; '.join(conflicts)}. Drop them, or start a new run with --out")
        if address is not None:
            cfg = TrainConfig.from_dict({**cfg.__dict__, "address": address})
    else:
        run_dir = None
        base = TrainConfig.from_file(args.config) if args.config else TrainConfig()
        env = {**base.env.kwargs(), **given_env}
        cfg = TrainConfig.from_dict({**base.__dict__, **given, "env": env})  # validated here, before any work starts
        problems = check_output_dir(cfg.out_dir)
        if problems:
            raise CliError(problems[0])
    if cfg.backend == "ray":  # a cluster that does not answer: refused in seconds, before the run folder is touched
        from safemanip.util.procs import check_ray_address, ray_address

        address, source = ray_address(cfg.address)
        if address:
            check_ray_address(address, source)
    env_factory = None  # the registry's env the config names
    if cfg.selection_aware:  # rl imports nothing from selection: the training loop takes its env as an argument
        from safemanip.selection.training_env import SelectedSlotsEnv

        env_factory = SelectedSlotsEnv
    command = "safemanip " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    run_dir = train(cfg, resume=bool(args.resume), progress=not args.no_progress, command=command, run_dir=run_dir,
                    env_factory=env_factory)
    summary = (run_dir / "summary.json").read_text()
    stopped_by = json.loads(summary).get("interrupted")
    if stopped_by:
        print(f"run stopped by {stopped_by}; checkpoint and policy saved in {run_dir}; continue with: "
              f"safemanip train --resume {run_dir}\n{summary}")
        return 128 + int(getattr(signal, stopped_by))
    print(f"run finished: {run_dir}\n{summary}")
    return 0


def register(sub) -> None:
    from safemanip.env.config import ENV_CHOICES, EnvConfig
    from safemanip.rl.config import FIELD_BOUNDS, FIELD_CHOICES, TRAINING_CONSTRAINTS, Bounds, TrainConfig

    tr = sub.add_parser("train", help="train a reach-avoid (rarl) or vanilla DDPG policy")
    tr.add_argument("--config", help="JSON file of training settings (flags override it)")
    tr.add_argument("--resume", metavar="RUN_DIR", help="continue an interrupted run from its newest checkpoint, "
                                                        "writing into RUN_DIR")
    bounds = {**FIELD_BOUNDS, "minutes": Bounds(0, FIELD_BOUNDS["minutes"].hi)}  # 0 on the command line: no limit
    add_config_flags(tr, TrainConfig, FLAGS, bounds, FIELD_CHOICES, EXTRA_HELP)
    env = tr.add_argument_group("the training env (default: every object no_contact, slots nearest first, action "
                                "curve 2)")
    add_env_flags(env, EnvConfig, skip=("n_objects",),
                  choices={**ENV_CHOICES, "constraints": tuple(TRAINING_CONSTRAINTS)})
    tr.add_argument("--no-progress", action="store_true")
    tr.set_defaults(func=_cmd_train)

"""``safemanip train``: flags override a ``TrainConfig`` (validated before any work); ``--resume`` continues
the run in the folder given, with that run's own config."""

from __future__ import annotations

import json
import shlex
import signal
import sys
from dataclasses import fields
from pathlib import Path

from safemanip.cli.common import SEED, CliError, float_in, int_in
from safemanip.scene.embodiment import EMBODIMENTS
from safemanip.scene.placement import LAYOUTS

SWITCH = "switch"  # a flag without a value that sets its field to true
# flag -> (TrainConfig field, argparse type, help); every one is checked for range here and again by TrainConfig
FLAGS = {
    "--algorithm": ("algorithm", None, "rarl (reach-avoid backup) or vanilla (DDPG on r = min(l, g))"),
    "--k": ("k", int_in(0, 8), "clutter objects in every training scene: the policy's k slots"),
    "--constraints": ("constraints", None, "conservative (all no_contact) or all (types drawn per episode)"),
    "--embodiment": ("embodiment", None, "panda (the 7-DoF Franka Panda, default) or hand (the idealised ablation)"),
    "--action-curve": ("action_curve", float_in(1, 4), "commanded speed = 1.7 m/s x |a|^curve (1: linear; default 2)"),
    "--object-size": ("object_size", SWITCH, "each object slot also carries its footprint radius (not the paper's "
                                             "layout)"),
    "--layout": ("layout", None, "scene layout: route (default) or narrow (every object beside the route, on both "
                                 "sides, 1 cm to spare)"),
    "--total-env-steps": ("total_env_steps", int_in(1, 10**12), "budget in environment steps"),
    "--minutes": ("minutes", float_in(0, 525_600), "wall-clock budget in minutes (0: no time limit)"),
    "--seed": ("seed", SEED, "seed of everything random in the run"),
    "--out": ("out_dir", None, "run folder (checkpoints, logs, policies)"),
    "--init-from": ("init_from", None, "start from the networks of this run folder's checkpoint (fine-tuning; "
                                      "k, network, sizes, embodiment must match)"),
    "--gamma": ("gamma", float_in(0, 1), "discount factor, in (0, 1)"),
    "--gamma-start": ("gamma_start", float_in(0, 1), "anneal gamma from this value over the first half of the budget"),
    "--learning-rate-final": ("learning_rate_final", float_in(0, 1, lo_open=True),
                              "let both learning rates fall on a cosine to this over the budget (default: constant)"),
    "--noise-color": ("noise_color", float_in(0, 2), "exploration noise spectrum 1/f^beta: 0 white (default), "
                                                     "1 pink, 2 red (correlated over an episode)"),
    "--actor-preactivation-penalty": ("actor_preactivation_penalty", float_in(0, 10),
                                      "weight of mean(pre-tanh action^2) in the actor loss, against a saturated "
                                      "actor (default 0: off; try 1e-3)"),
    "--env-steps-per-update": ("env_steps_per_update", float_in(0, 10_000, lo_open=True),
                               "environment steps collected per learner update"),
    "--eval-every-s": ("eval_every_s", float_in(0, 86_400, lo_open=True), "seconds between evaluations"),
    "--eval-episodes": ("eval_episodes", int_in(1, 100_000), "episodes per evaluation"),
    "--checkpoint-every-s": ("checkpoint_every_s", float_in(0, 86_400, lo_open=True), "seconds between checkpoints"),
    "--max-episode-steps": ("max_episode_steps", int_in(1, 100_000), "episode length in control steps"),
    # learner speed, network, selection-aware training and rollout backend
    "--device": ("device", None, "learner device: auto (CUDA if PyTorch sees a GPU), cpu or cuda (default auto)"),
    "--precision": ("precision", None, "forward passes in bf16 autocast or fp32; auto: bf16 where it is native "
                                       "and measured faster at start-up (default auto)"),
    "--network": ("network", None, "flat MLP (the paper's, fixed k) or object-set network (any number of objects)"),
    "--scene-objects": ("scene_objects", int_in(0, 8), "selection-aware training: N objects per scene (N >= k); "
                                                       "the selector picks the policy's k"),
    "--scene-objects-min": ("scene_objects_min", int_in(1, 8), "mixed clutter: each episode's N is drawn from this "
                                                               "to --scene-objects (or k); empty slots are padded"),
    "--selector": ("selector", None, "object selector for selection-aware training (dynamic-radius and mixed, "
                                     "a per-episode draw of the two, need --network set)"),
    "--selection-radius": ("selection_radius", float_in(0, 10, lo_open=True), "dynamic-radius: radius around the "
                                                                              "held box [m] (default 0.35)"),
    "--backend": ("backend", None, "rollout workers as local processes or Ray actors (default local)"),
    "--address": ("address", None, "Ray cluster address HOST:PORT for --backend ray (default: RAY_ADDRESS, else a local "
                                   "Ray instance); never read from a config file"),
    "--workers": ("n_collectors", int_in(1, 64), "rollout workers: processes or Ray actors (default 1)"),
}
CHOICES = {"--algorithm": ["rarl", "vanilla"], "--constraints": ["conservative", "all"], "--embodiment": sorted(EMBODIMENTS),
           "--device": ["auto", "cpu", "cuda"], "--precision": ["auto", "bf16", "fp32"], "--network": ["mlp", "set"],
           "--selector": ["dynamic-knn", "dynamic-radius", "mixed"], "--backend": ["local", "ray"],
           "--layout": list(LAYOUTS)}


def _cmd_train(args) -> int:
    import safemanip.selection.training_env  # noqa: F401  registers the selection-aware training env
    from safemanip.rl.config import TrainConfig, load_run_config
    from safemanip.rl.train import train
    from safemanip.util.files import check_output_dir

    given = {field: getattr(args, field) for field, _, _ in FLAGS.values() if getattr(args, field) is not None}
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
                     for flag, (field, _, _) in FLAGS.items() if field in given and given[field] != getattr(cfg, field)]
        if conflicts:
            raise CliError(f"--resume continues {run_dir} with its own settings; these flags differ from them: "
                           f"{'; '.join(conflicts)}. Drop them, or start a new run with --out")
        if address is not None:
            cfg = TrainConfig.from_dict({**cfg.__dict__, "address": address})
    else:
        run_dir = None
        base = TrainConfig.from_file(args.config).__dict__ if args.config else {}
        cfg = TrainConfig.from_dict({**base, **given})  # validated here, before any work starts
        problems = check_output_dir(cfg.out_dir)
        if problems:
            raise CliError(problems[0])
    if cfg.backend == "ray":  # a cluster that does not answer: refused in seconds, before the run folder is touched
        from safemanip.util.procs import check_ray_address, ray_address

        address, source = ray_address(cfg.address)
        if address:
            check_ray_address(address, source)
    command = "safemanip " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    run_dir = train(cfg, resume=bool(args.resume), progress=not args.no_progress, command=command, run_dir=run_dir)
    summary = (run_dir / "summary.json").read_text()
    stopped_by = json.loads(summary).get("interrupted")
    if stopped_by:
        print(f"run stopped by {stopped_by}; checkpoint and policy saved in {run_dir}; continue with: "
              f"safemanip train --resume {run_dir}\n{summary}")
        return 128 + int(getattr(signal, stopped_by))
    print(f"run finished: {run_dir}\n{summary}")
    return 0


def register(sub) -> None:
    from safemanip.rl.config import TrainConfig

    tr = sub.add_parser("train", help="train a reach-avoid (rarl) or vanilla DDPG policy")
    tr.add_argument("--config", help="JSON file with TrainConfig fields (flags override it)")
    tr.add_argument("--resume", metavar="RUN_DIR", help="continue an interrupted run from its newest checkpoint, "
                                                        "writing into RUN_DIR")
    known = {f.name for f in fields(TrainConfig)}
    for flag, (field, typ, help_) in FLAGS.items():
        assert field in known, field
        if typ is SWITCH:
            tr.add_argument(flag, dest=field, action="store_const", const=True, default=None, help=help_)
        else:
            tr.add_argument(flag, dest=field, type=typ, choices=CHOICES.get(flag), help=help_)
    tr.add_argument("--no-progress", action="store_true")
    tr.set_defaults(func=_cmd_train)

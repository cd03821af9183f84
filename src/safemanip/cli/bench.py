"""``safemanip bench train | promote | sweep | findings | status``: the benchmark of ``bench/benchmark.json``."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from safemanip.cli.common import add_compute_backend, float_in

DESCRIPTION = """The paper's benchmark, from training to the findings. Its settings, training seeds, recipe, budget
and seed blocks are listed once, in the package's benchmark.json (--benchmark FILE gives another). Run it from the
repository's top folder: the records go to runs/bench, results/ and docs/results.md there."""

EXAMPLES = """steps, each resumable (what is finished is skipped):
  safemanip bench train                     train the 54 runs here, one after another, into runs/bench
  safemanip bench train --address 10.0.0.5:6379
                                            one Ray task per run on a cluster (runs/bench on a shared filesystem)
  safemanip bench promote                   final or best of each finished run into the policies folder
  safemanip bench sweep                     the reported sweeps: fig4 fig5 fig6 table1 table2, and the
                                            filter's fig4-filter table1-filter
  safemanip bench findings                  the status, findings and filter blocks of docs/results.md
  safemanip bench status                    one line per run and per sweep
"""

TRAIN_ADDRESS_HELP = ("Ray cluster address (HOST:PORT, as `ray start --head` prints it; default: RAY_ADDRESS, else "
                      "train here one run after another). Each run becomes one Ray task; the runs folder must be on a "
                      "filesystem every node mounts at the same path, and the package installed on every node.")


def _policies(args) -> Path:
    from safemanip.rl.policy_index import BENCHMARK_POLICIES

    return Path(args.policies) if args.policies else BENCHMARK_POLICIES


def _cmd_train(args) -> int:
    from safemanip.bench.benchmark import load_benchmark
    from safemanip.bench.train import plan, train_here, train_on_ray
    from safemanip.util.procs import check_ray_address, ray_address

    bench = load_benchmark(args.benchmark)
    address, source = ray_address(args.address)
    if address:  # a cluster that does not answer is refused in seconds, before anything is written
        check_ray_address(address, source)
    jobs, skipped = plan(bench, Path(args.out), args.only, _policies(args))
    where = f"on the Ray cluster at {address} ({source})" if address else "here, one after another"
    print(f"{len(jobs) + len(skipped)} run(s): {len(skipped)} finished or promoted (skipped), {len(jobs)} to train "
          f"{where}; output of each in {args.out}/NAME.log", flush=True)
    if not jobs:
        return 0
    if address:
        return train_on_ray(jobs, Path(args.out), address, args.cpus_per_run)
    return train_here(jobs)


def _cmd_promote(args) -> int:
    from safemanip.bench.benchmark import load_benchmark
    from safemanip.bench.promote import plan, promote

    bench = load_benchmark(args.benchmark)
    policies, records = _policies(args), Path(args.records)
    todo = plan(bench, Path(args.runs), policies, records)
    if not todo:
        print(f"nothing to promote: no run in {args.runs} is finished and not promoted yet (safemanip bench status)")
    for candidate in todo:
        promote(bench, candidate, policies, records)
    return 0


def _cmd_sweep(args) -> int:
    from safemanip.bench.benchmark import load_benchmark
    from safemanip.bench.sweeps import run_sweeps

    return run_sweeps(load_benchmark(args.benchmark), args.names, workers=args.workers, backend=args.backend,
                      address=args.address, render_only=args.render_only, progress=not args.no_progress)


def _cmd_findings(args) -> int:
    from safemanip.bench.benchmark import load_benchmark
    from safemanip.bench.findings import render
    from safemanip.util.files import atomic_write_text

    doc = Path(args.doc)
    before, after = render(doc, load_benchmark(args.benchmark), _policies(args), Path(args.results))
    if args.check:
        if after != before:
            print(f"{doc} is out of date with the stored cells and policies: run safemanip bench findings and commit "
                  f"it", file=sys.stderr)
            return 1
        return 0
    atomic_write_text(doc, after)  # a crash mid-write leaves the old page, not half a table
    print(after[after.index("<!-- status -->"):])
    return 0


def _cmd_status(args) -> int:
    from safemanip.bench.benchmark import load_benchmark
    from safemanip.bench.status import status_lines

    for line in status_lines(load_benchmark(args.benchmark), Path(args.runs), _policies(args), Path(args.results)):
        print(line)
    return 0


def _add_common(p: argparse.ArgumentParser, command: str) -> None:
    p.add_argument("--benchmark", metavar="FILE", help="a benchmark file of your own (default: the shipped one)")
    p.add_argument("--policies", metavar="DIR", help="the policies folder, with its manifest (default: results/policies)")
    p.set_defaults(command=f"bench {command}")  # errors read "safemanip bench train: error: ..."


def register(sub) -> None:
    from safemanip.evaluation.sweep.spec import available

    bench = sub.add_parser("bench", help="the paper's benchmark: train, promote, sweep, findings, status",
                           description=DESCRIPTION, epilog=EXAMPLES,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
    commands = bench.add_subparsers(dest="bench_command", required=True, metavar="COMMAND")

    tr = commands.add_parser("train", help="train every run of the benchmark (resumable), here or on a Ray cluster",
                             description="Train every run of the benchmark that is not finished or promoted: here "
                                         "one after another, or with --address one Ray task per run. A run stopped "
                                         "part-way is resumed from its newest checkpoint.")
    _add_common(tr, "train")
    tr.add_argument("--out", default="runs/bench", metavar="RUNS_DIR", help="the runs folder (default runs/bench)")
    tr.add_argument("--only", action="append", metavar="PATTERN",
                    help="only the runs whose name matches this shell-style pattern (repeatable), e.g. 'rarl-k2-*'")
    tr.add_argument("--address", help=TRAIN_ADDRESS_HELP)
    tr.add_argument("--cpus-per-run", type=float_in(0, 256, lo_open=True), default=2, metavar="N",
                    help="Ray CPUs each run asks for (default 2: the learner and its rollout worker)")
    tr.set_defaults(func=_cmd_train)

    pr = commands.add_parser("promote", help="final or best of each finished run into the policies folder",
                             description="Evaluate each finished run's final and best policy on the selection block "
                                         "and copy the better one into the policies folder, its training records "
                                         "into results/training/NAME. Everything read is checked first.")
    _add_common(pr, "promote")
    pr.add_argument("--runs", default="runs/bench", metavar="RUNS_DIR", help="the runs folder (default runs/bench)")
    pr.add_argument("--records", default="results/training", metavar="DIR",
                    help="where the training records go (default results/training)")
    pr.set_defaults(func=_cmd_promote)

    sw = commands.add_parser("sweep", help="run the reported sweeps (resumable) and draw their figures and tables",
                             description="Run (or resume) the sweeps the benchmark reports, each on its reporting "
                                         "block, as safemanip sweep NAME does.")
    _add_common(sw, "sweep")
    sw.add_argument("names", nargs="*", metavar="NAME", help=f"sweeps to run (default: all the benchmark reports; "
                                                             f"shipped: {', '.join(available())})")
    sw.add_argument("--render-only", action="store_true", help="only redraw figures and tables from stored results")
    sw.add_argument("--no-progress", action="store_true", help="no progress lines on stderr")
    add_compute_backend(sw)
    sw.set_defaults(func=_cmd_sweep)

    fi = commands.add_parser("findings", help="the status and findings blocks of docs/results.md",
                             description="Rewrite the status and findings blocks of the results page from the "
                                         "policies and the stored sweep cells.")
    _add_common(fi, "findings")
    fi.add_argument("--check", action="store_true",
                    help="write nothing; exit 1 if the page differs from what the stored cells give")
    fi.add_argument("--doc", default="docs/results.md", metavar="FILE",
                    help="the results page (default docs/results.md)")
    fi.add_argument("--results", default="results", metavar="DIR", help="the stored sweep results (default results)")
    fi.set_defaults(func=_cmd_findings)

    st = commands.add_parser("status", help="which runs are trained, promoted or missing, and the sweeps' cells",
                             description="One line per run and per reported sweep, from the records; nothing is run.")
    _add_common(st, "status")
    st.add_argument("--runs", default="runs/bench", metavar="RUNS_DIR", help="the runs folder (default runs/bench)")
    st.add_argument("--results", default="results", metavar="DIR", help="the stored sweep results (default results)")
    st.set_defaults(func=_cmd_status)

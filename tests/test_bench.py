"""``safemanip bench`` (issue 43): benchmark.json's loader and its refusals, ``bench status`` and ``bench promote`` on
runs folders made by hand, and ``bench train`` on two tiny runs, here and as Ray tasks on a cluster started by
``ray start --head`` on this machine, with the same records both ways.

The tiny benchmark is written by the tests: two settings (one selection-aware), one seed, 1200 environment steps, the
inline rollout backend and fp32 with no time limit and no periodic evaluation but the final one, so that a run is
deterministic for its seed wherever it runs. Every folder written is under ``tmp_path``; the policies folder is
always given (``--policies``), so nothing lands in the package's own."""

from __future__ import annotations

import json
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from conftest import ROOT, SUBPROCESS_ENV, TINY_TRAIN, assert_refused, descendants, make_policy, run_cli

from safemanip.bench.benchmark import load_benchmark

RECIPE = {**{k: v for k, v in TINY_TRAIN.items() if k != "k"}, "backend": "inline", "precision": "fp32",
          "minutes": None, "eval_every_s": 86_400}
"""TINY_TRAIN without its k (a setting's), made deterministic: one process, fp32, no clock in the schedule, one
evaluation."""
SETTINGS = [{"name": "rarl-k1-conservative", "group": "a", "algorithm": "rarl", "k": 1,
             "env": {"constraints": "conservative", "layout": "exit"}},
            {"name": "rarl-k1-conservative-selaware", "group": "a", "algorithm": "rarl", "k": 1,
             "env": {"constraints": "conservative", "layout": "exit"}, "scene_objects": 2, "selector": "dynamic-knn"}]
TINY = {"description": "two tiny runs for the tests", "budget_env_steps": 1200, "recipe": RECIPE, "seeds": [0],
        "selection": {"block": 30, "episodes": 2}, "reporting": {"fig4": 31}, "settings": SETTINGS}
RUNS = ("rarl-k1-conservative-s0", "rarl-k1-conservative-selaware-s0")


def write_benchmark(path: Path, **changes) -> Path:
    """The tiny benchmark with ``changes`` to its top-level keys (None: key removed), as a file."""
    data = {**TINY, **changes}
    path.write_text(json.dumps({k: v for k, v in data.items() if v is not None}))
    return path


# ------------------------------------------------------------------------------------------ the loader
def test_the_shipped_benchmark_lists_the_papers_runs_once():
    bench = load_benchmark()
    assert len(bench.settings) == 18 and bench.seeds == (0, 1, 2) and len(bench.runs) == 54
    assert len({r.name for r in bench.runs}) == 54
    assert bench.budget_env_steps == 400_000 and bench.selection_block == 30 and bench.selection_episodes == 200
    assert bench.reporting == {"fig4": 31, "fig5": 32, "fig6": 32, "table1": 43, "table2": 46, "fig4-filter": 49,
                               "table1-filter": 50}
    # the queue goes by finding: Table I's pi_2 first, Table II's two seed by seed, Fig. 4's Vanilla last
    assert [r.name for r in bench.runs[:5]] == ["rarl-k2-conservative-s0", "rarl-k2-conservative-s1",
                                                "rarl-k2-conservative-s2", "rarl-k2-all-s0", "rarl-k3-all-s0"]
    assert bench.runs[-1].name == "vanilla-k6-conservative-s2"
    assert sum(bench.config(r, "runs").selection_aware for r in bench.runs) == 12


def test_the_shipped_benchmark_gives_every_shipped_policy_its_training_config():
    """benchmark.json is the recipe the 54 shipped policies were trained with: each one's recorded training config
    is the one the benchmark gives its run, bar the folder it was written to."""
    from safemanip.rl.checkpoint import load_policy

    bench = load_benchmark()
    for run in bench.runs:
        shipped = load_policy(run.name)[1]["train_config"]
        wanted = json.loads(bench.config(run, shipped["out_dir"]).to_json())
        assert wanted == shipped, (run.name, {k for k in wanted if wanted[k] != shipped.get(k)})


def test_the_recipe_and_budget_are_written_nowhere_else():
    """The budget and the recipe live in benchmark.json only: no module or script of the package or the results
    copies them (the bash queue, the promotion script and the sweep code each used to)."""
    files = [*(ROOT / "src").rglob("*.py"), *(ROOT / "results").rglob("*.py"), *(ROOT / "results").rglob("*.sh")]
    copies = [str(p.relative_to(ROOT)) for p in files if any(s in p.read_text() for s in (
        "400000", "400_000", "--gamma-start 0.9", "--actor-preactivation-penalty 1e-3"))]
    assert not copies, copies


@pytest.mark.parametrize("changes, message", [
    ({"seeds": None}, "missing key 'seeds'"),
    ({"seed": [0]}, "unknown key(s) 'seed'"),
    ({"seeds": [0, 0]}, "seeds must be a non-empty list of distinct training seeds"),
    ({"budget_env_steps": "1200"}, "budget_env_steps must be a positive whole number"),
    ({"recipe": {**RECIPE, "total_env_steps": 5}}, "'total_env_steps' is set per run, from 'budget_env_steps'"),
    ({"recipe": {**RECIPE, "address": "10.0.0.5:6379"}}, "'address' may not be given in a file"),
    ({"recipe": {**RECIPE, "gama": 0.9}}, "unknown training setting 'gama'"),
    ({"recipe": {**RECIPE, "gamma": 2.0}}, "gamma must be in (0, 1)"),
    ({"recipe": {**RECIPE, "env": {"layout": "exit"}}}, "env.layout also in the recipe; set each once"),
    ({"recipe": {**RECIPE, "layout": "exit"}}, "unknown training setting 'layout'"),
    ({"recipe": {**RECIPE, "env": "exit"}}, "'env' must be an object of env settings"),
    ({"settings": [{**SETTINGS[0], "k": 2}]}, "its keys make it 'rarl-k2-conservative'; name it so"),
    ({"settings": [SETTINGS[0], SETTINGS[0]]}, "the name is given twice"),
    ({"settings": [{"algorithm": "rarl"}]}, "settings[0] must be an object with a 'name', a 'group'"),
    ({"selection": {"block": 31, "episodes": 2}}, "reporting.fig4 is block 31, the selection block"),
    ({"selection": {"block": 30}}, "selection must be {\"block\": B, \"episodes\": N}"),
    ({"reporting": {"fig4": 32}}, "reporting.fig4 is block 32 but the sweep's spec reports on block 31"),
    ({"reporting": {"fig9": 31}}, "reporting: no shipped sweep 'fig9'"),
], ids=lambda v: v if isinstance(v, str) else None)
def test_a_bad_benchmark_file_is_refused_naming_the_file_and_the_fix(tmp_path, capsys, changes, message):
    path = write_benchmark(tmp_path / "bench.json", **changes)
    err = assert_refused(capsys, ["bench", "status", "--benchmark", path, "--runs", tmp_path / "runs"], message)
    assert err.startswith(f"safemanip bench status: error: {path} cannot be used:")


def test_every_problem_of_a_benchmark_file_is_listed_at_once(tmp_path, capsys):
    path = write_benchmark(tmp_path / "bench.json", seeds=[-1], recipe={**RECIPE, "gama": 0.9})
    err = assert_refused(capsys, ["bench", "train", "--benchmark", path], "seeds must be a non-empty list")
    assert "unknown training setting 'gama'" in err


def test_a_benchmark_file_that_is_not_json_or_missing_is_one_line(tmp_path, capsys):
    bad = tmp_path / "bench.json"
    bad.write_text("{budget_env_steps: 1")
    assert_refused(capsys, ["bench", "status", "--benchmark", bad], "not a benchmark file")
    assert_refused(capsys, ["bench", "status", "--benchmark", tmp_path / "none.json"], "cannot read the benchmark file")


def test_only_names_runs_and_a_pattern_matching_none_is_refused(tmp_path, capsys):
    bench = load_benchmark(write_benchmark(tmp_path / "bench.json"))
    assert [r.name for r in bench.select(["*selaware*"])] == ["rarl-k1-conservative-selaware-s0"]
    assert_refused(capsys, ["bench", "train", "--benchmark", tmp_path / "bench.json", "--only", "vanilla-*", "--out",
                            tmp_path / "runs", "--policies", tmp_path / "pol"], "--only vanilla-* matches no run")


def test_sweep_runs_the_reported_sweeps_through_the_sweep_runner(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the sweep runner writes under results/ of the working folder
    code, out, err = run_cli(capsys, ["bench", "sweep", "fig4", "table1", "--render-only"])
    assert code == 0, err
    assert out.splitlines()[0] == "== sweep fig4 (block 31)" and "== sweep table1 (block 43)" in out
    assert (tmp_path / "results" / "exit" / "fig4" / "fig4.md").is_file()
    assert_refused(capsys, ["bench", "sweep", "fig9"], "fig9: not a sweep the benchmark reports")


def test_a_cluster_that_does_not_answer_is_refused_before_anything_is_written(tmp_path, capsys, monkeypatch):
    argv = ["bench", "train", "--benchmark", write_benchmark(tmp_path / "bench.json"), "--out", tmp_path / "runs",
            "--policies", tmp_path / "policies"]
    assert_refused(capsys, [*argv, "--address", "127.0.0.1:1"], "--address 127.0.0.1:1: cannot reach a Ray cluster")
    monkeypatch.setenv("RAY_ADDRESS", "no-port")
    assert_refused(capsys, argv, "RAY_ADDRESS 'no-port' is not a Ray cluster address")
    assert not (tmp_path / "runs").exists()


# ------------------------------------------------------------------------------------------ runs folders by hand
def finished_run(t: dict, name: str = RUNS[0], summary=None, policy: bool = True, best: bool = True) -> Path:
    """A run folder in ``t["runs"]`` as bench train leaves a finished run: its config (the one benchmark
    ``t["bench"]`` gives it), periodic evaluations, summary and policies."""
    run = t["runs"] / name
    run.mkdir(parents=True)
    loaded = load_benchmark(t["bench"])
    (run / "config.json").write_text(loaded.config(loaded.select([name])[0], run).to_json())
    (run / "evals.jsonl").write_text(json.dumps({"env_steps": 1280, "success": 0.5}) + "\n")
    summary = {"env_steps": 1280, "interrupted": None} if summary is None else summary
    (run / "summary.json").write_text(summary if isinstance(summary, str) else json.dumps(summary))
    if policy:
        make_policy(run / "policy.safetensors", 1)
    if best:
        make_policy(run / "best.safetensors", 1, seed=1)
    return run


@pytest.fixture
def tiny(tmp_path) -> dict:
    """The tiny benchmark file and empty runs, policies and records folders, as command-line arguments."""
    path = write_benchmark(tmp_path / "bench.json")
    (tmp_path / "runs").mkdir()
    return {"bench": path, "runs": tmp_path / "runs", "policies": tmp_path / "policies", "records": tmp_path / "rec"}


def promote_argv(t: dict) -> list:
    return ["bench", "promote", "--benchmark", t["bench"], "--runs", t["runs"], "--policies", t["policies"],
            "--records", t["records"]]


def test_status_says_what_each_run_and_sweep_has(tiny, capsys, tmp_path):
    bench = write_benchmark(tmp_path / "bench.json", seeds=[0, 1])
    runs = tiny["runs"]
    make_policy(tiny["policies"] / "rarl-k1-conservative-s0.safetensors", 1)  # promoted
    finished_run(tiny, RUNS[1])  # finished
    partial = runs / "rarl-k1-conservative-s1"  # stopped part-way: a checkpoint, a summary saying SIGINT
    (partial / "checkpoint").mkdir(parents=True)
    (partial / "checkpoint" / "meta.json").write_text(json.dumps({"updates": 10, "env_steps": 512, "elapsed_s": 1.0}))
    for f in ("state.safetensors", "replay.npz"):
        (partial / "checkpoint" / f).write_bytes(b"")
    loaded = load_benchmark(bench)
    (partial / "config.json").write_text(loaded.config(loaded.select([partial.name])[0], partial).to_json())
    (partial / "summary.json").write_text(json.dumps({"env_steps": 512, "interrupted": "SIGINT"}))
    code, out, err = run_cli(capsys, ["bench", "status", "--benchmark", bench, "--runs", runs, "--policies",
                                      tiny["policies"], "--results", tmp_path / "results"])
    assert code == 0, err
    lines = out.splitlines()
    assert lines[:4] == [
        "rarl-k1-conservative-s0: promoted",
        "rarl-k1-conservative-selaware-s0: finished (promote it: safemanip bench promote)",
        "rarl-k1-conservative-s1: partial, 512 of 1,200 env steps, stopped by SIGINT "
        "(resume it: safemanip bench train)",
        "rarl-k1-conservative-selaware-s1: missing (train it: safemanip bench train)"]
    assert lines[4] == "4 runs: 1 promoted, 1 finished, 1 partial, 0 started, 1 missing"
    assert lines[5].startswith("sweep fig4: 0 of 42 cells stored in ")


def test_status_shows_a_damaged_record_and_a_run_of_another_recipe(tiny, capsys, tmp_path):
    finished_run(tiny, RUNS[0], summary="[]")
    other = finished_run(tiny, RUNS[1], summary={"env_steps": 512, "interrupted": "SIGINT"})
    (other / "checkpoint").mkdir()
    (other / "checkpoint" / "meta.json").write_text(json.dumps({"updates": 1, "env_steps": 512, "elapsed_s": 1.0}))
    for f in ("state.safetensors", "replay.npz"):
        (other / "checkpoint" / f).write_bytes(b"")
    config = json.loads((other / "config.json").read_text())
    (other / "config.json").write_text(json.dumps({**config, "gamma": 0.95}))
    code, out, _ = run_cli(capsys, ["bench", "status", "--benchmark", tiny["bench"], "--runs", tiny["runs"],
                                    "--policies", tiny["policies"], "--results", tmp_path])
    assert code == 0
    assert "must be a JSON object, got list" in out.splitlines()[0]
    assert "was trained with other settings than" in out and "gamma 0.95 there, 0.99 in the benchmark" in out, out
    # and bench train refuses to resume it, listing both problems before it trains anything
    err = assert_refused(capsys, ["bench", "train", "--benchmark", tiny["bench"], "--out", tiny["runs"],
                                  "--policies", tiny["policies"]], "nothing trained: 2 problem(s)")
    assert "gamma 0.95 there" in err and "must be a JSON object" in err


# ------------------------------------------------------------------------------------------ promote, refused
def assert_promote_refused(capsys, t: dict, message: str) -> str:
    err = assert_refused(capsys, promote_argv(t), message)
    assert not t["policies"].exists() and not t["records"].exists()
    return err


def test_promote_refuses_a_missing_runs_folder_or_a_file(tiny, capsys):
    shutil.rmtree(tiny["runs"])
    assert_promote_refused(capsys, tiny, "no runs folder")
    tiny["runs"].write_text("not a folder")
    assert_promote_refused(capsys, tiny, "is a file, not a runs folder")


@pytest.mark.parametrize("text, message", [
    ("[]", "must be a JSON object, got list"),
    ("{env_steps: 1280", "the summary is not valid JSON"),
    ("", "the summary is not valid JSON"),
    ('{"env_steps": NaN, "interrupted": null}', "the summary is not valid JSON"),
    ('{"env_steps": "1280", "interrupted": null}', "env_steps must be a non-negative integer"),
], ids=["list", "not-json", "empty", "nan", "steps-a-string"])
def test_promote_refuses_a_bad_summary_with_a_message_not_a_traceback(tiny, capsys, text, message):
    finished_run(tiny, summary=text)
    assert_promote_refused(capsys, tiny, message)


def test_promote_refuses_before_any_evaluation_and_lists_every_problem(tiny, capsys):
    finished_run(tiny, RUNS[0], policy=False)  # no final policy: it used to evaluate best first
    broken = finished_run(tiny, RUNS[1])
    data = (broken / "best.safetensors").read_bytes()
    (broken / "best.safetensors").write_bytes(data[:len(data) - 40])
    (broken / "evals.jsonl").unlink()
    err = assert_promote_refused(capsys, tiny, "nothing promoted: 3 problem(s)")
    assert "holds no policy.safetensors" in err and "best.safetensors" in err and "has no evals.jsonl" in err


@pytest.mark.parametrize("text, message", [
    ("{k: 1", "is not valid JSON"),
    ('{"scene_objects": "six"}', "scene_objects"),
], ids=["config-not-json", "config-scene-objects"])
def test_promote_refuses_a_finished_run_with_a_bad_config(tiny, capsys, text, message):
    run = finished_run(tiny)
    (run / "config.json").write_text(text)
    assert_promote_refused(capsys, tiny, message)


def test_promote_skips_runs_not_finished_and_evaluates_nothing(tiny, capsys):
    finished_run(tiny, summary={"env_steps": 512, "interrupted": "SIGINT"}, policy=False)
    (tiny["runs"] / "still-training").mkdir()  # not a run of the benchmark: not looked at
    code, out, err = run_cli(capsys, promote_argv(tiny))
    assert code == 0 and out.startswith("nothing to promote") and not err
    assert not tiny["policies"].exists()


# ------------------------------------------------------------------------------------------ real tiny runs
@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> dict:
    """The tiny benchmark's two runs, trained here one after another by bench train."""
    from safemanip.cli import main

    root = tmp_path_factory.mktemp("bench")
    t = {"bench": write_benchmark(root / "bench.json"), "runs": root / "runs", "policies": root / "policies"}
    code = main(["bench", "train", "--benchmark", str(t["bench"]), "--out", str(t["runs"]), "--policies",
                 str(t["policies"])])
    assert code == 0
    return t


@pytest.mark.slow
def test_train_here_finishes_each_run_and_skips_or_resumes_it_next_time(trained, capsys, tmp_path):
    for name in RUNS:
        summary = json.loads((trained["runs"] / name / "summary.json").read_text())
        assert summary["interrupted"] is None and summary["env_steps"] >= TINY["budget_env_steps"]
        assert "learner: cpu, fp32" in (trained["runs"] / f"{name}.log").read_text()
    argv = ["bench", "train", "--benchmark", trained["bench"], "--policies", trained["policies"]]
    code, out, _ = run_cli(capsys, [*argv, "--out", trained["runs"]])
    assert code == 0 and "2 finished or promoted (skipped), 0 to train" in out
    # a run killed after its last checkpoint (no summary yet) is resumed, not trained again
    runs = tmp_path / "runs"
    shutil.copytree(trained["runs"] / RUNS[0], runs / RUNS[0])
    (runs / RUNS[0] / "summary.json").unlink()
    code, out, err = run_cli(capsys, [*argv, "--out", runs, "--only", RUNS[0]])
    assert code == 0, err
    assert f"resume {RUNS[0]}" in out and f"{RUNS[0]}: resumed, 1,280 env steps" in out
    assert "resuming" in (runs / f"{RUNS[0]}.log").read_text()


@pytest.mark.slow
def test_promote_a_tiny_real_run(trained, capsys, tmp_path, monkeypatch):
    t = {"bench": trained["bench"], "runs": tmp_path / "runs", "policies": tmp_path / "policies",
         "records": tmp_path / "rec"}
    shutil.copytree(trained["runs"] / RUNS[0], t["runs"] / RUNS[0])
    code, out, err = run_cli(capsys, promote_argv(t))
    assert code == 0, err
    choice = json.loads((t["records"] / RUNS[0] / "choice.json").read_text())
    assert choice["block"] == 30 and choice["episodes"] == 2 and set(choice["success"]) == {"policy", "best"}
    chosen = "policy" if choice["chosen"] == "final" else "best"
    promoted = t["policies"] / f"{RUNS[0]}.safetensors"
    assert promoted.read_bytes() == (t["runs"] / RUNS[0] / f"{chosen}.safetensors").read_bytes()
    assert out.startswith(f"{RUNS[0]}: final ")
    # listed in the folder's manifest, through which --policy NAME finds it
    from safemanip.rl.policy_index import ENV_VAR, find_policy, read_manifest

    entry = read_manifest(t["policies"])[RUNS[0]]
    assert (entry.file, entry.chosen, entry.k) == (promoted.name, choice["chosen"], 1)
    assert (t["policies"] / entry.record).resolve() == (t["records"] / RUNS[0]).resolve()
    monkeypatch.setenv(ENV_VAR, str(t["policies"]))
    assert find_policy(RUNS[0]) == t["policies"] / promoted.name
    for name in ("config.json", "evals.jsonl", "summary.json"):
        assert (t["records"] / RUNS[0] / name).read_bytes() == (t["runs"] / RUNS[0] / name).read_bytes()
    code, out, _ = run_cli(capsys, promote_argv(t))
    assert code == 0 and out.startswith("nothing to promote")
    code, out, _ = run_cli(capsys, ["bench", "status", "--benchmark", t["bench"], "--runs", t["runs"], "--policies",
                                    t["policies"], "--results", tmp_path])
    assert out.splitlines()[0] == f"{RUNS[0]}: promoted"


# ------------------------------------------------------------------------------------------ on a Ray cluster
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_until(condition, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")
        time.sleep(0.2)


@pytest.fixture
def ray_cluster():
    """A one-node Ray cluster of 2 CPUs, started by ``ray start --head`` (the venv's) for this test and stopped after
    it; yields (its GCS address on 127.0.0.1, the environment that joins it).

    It runs with ``--block`` and is stopped through that process: SIGTERM makes it end every process it started.
    ``ray stop`` is not used because it ends every Ray process on the machine, whoever started it. The cluster uses
    token authentication (the default of ``ray start`` in this Ray version) with a token made for this test, given
    to the cluster and to the command that joins it through the environment; no token file is read or written."""
    ray_bin = Path(sys.executable).parent / "ray"
    assert ray_bin.is_file(), f"no {ray_bin}: the Ray command comes with the package's dependency ray[default]"
    port = _free_port()
    env = {**SUBPROCESS_ENV, "RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": secrets.token_hex(32),
           "RAY_USAGE_STATS_ENABLED": "0"}
    temp = tempfile.mkdtemp(prefix="smray-", dir="/tmp")  # short: Ray's socket paths must fit in 107 bytes
    output = Path(temp) / "ray-start.log"
    with open(output, "w") as log:
        head = subprocess.Popen([str(ray_bin), "start", "--head", "--block", "--port", str(port), "--num-cpus", "2",
                                 "--include-dashboard=false", "--disable-usage-stats", "--temp-dir", temp],
                                stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True)
    try:
        _wait_until(lambda: "Ray runtime started" in output.read_text() or head.poll() is not None, 120,
                    "ray start --head")
        assert head.poll() is None, f"ray start --head exited with {head.returncode}:\n{output.read_text()[-3000:]}"
        yield f"127.0.0.1:{port}", env
    finally:
        started = descendants(head.pid)
        head.terminate()
        try:
            head.wait(timeout=60)
        except subprocess.TimeoutExpired:
            head.kill()
            head.wait()
        alive = lambda: [p for p in started if Path(f"/proc/{p}").exists()]  # noqa: E731
        try:
            _wait_until(lambda: not alive(), 30, "the cluster's processes to end")
        except AssertionError:
            for pid in alive():  # only the processes this cluster started, by their id
                os.kill(pid, signal.SIGKILL)
        shutil.rmtree(temp, ignore_errors=True)


def _policy(path: Path) -> tuple[dict, dict]:
    """(tensors as bytes, metadata without what the clock or the run folder's name decide) of a policy file."""
    from safetensors import safe_open

    with safe_open(str(path), "numpy") as f:
        tensors = {k: f.get_tensor(k).tobytes() for k in f.keys()}
        meta = json.loads(f.metadata()["meta"])
    for volatile in ("wall_s", "train_command"):
        meta.pop(volatile)
    meta["eval"].pop("wall_s")
    meta["train_config"].pop("out_dir")
    return tensors, meta


def _evals(path: Path) -> list[dict]:
    return [{k: v for k, v in json.loads(line).items() if k != "wall_s"} for line in path.read_text().splitlines()]


@pytest.mark.slow
def test_train_on_a_ray_cluster_writes_the_records_a_local_queue_writes(trained, ray_cluster, tmp_path):
    address, env = ray_cluster
    runs = tmp_path / "runs"
    done = subprocess.run([sys.executable, "-m", "safemanip.cli", "bench", "train", "--benchmark",
                           str(trained["bench"]), "--out", str(runs), "--policies", str(tmp_path / "policies"),
                           "--address", address, "--cpus-per-run", "1"], capture_output=True, text=True, timeout=600,
                          env=env)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-3000:]
    assert f"2 run(s) sent to the Ray cluster at {address}, 1 CPUs each" in done.stdout
    for name in RUNS:
        here, there = trained["runs"] / name, runs / name
        assert f"{name}: trained, 1,280 env steps" in done.stdout
        assert _evals(there / "evals.jsonl") == _evals(here / "evals.jsonl")
        for policy in ("policy.safetensors", "best.safetensors"):
            assert _policy(there / policy) == _policy(here / policy), (name, policy)
        config = {k: v for k, v in json.loads((there / "config.json").read_text()).items() if k != "out_dir"}
        assert config == {k: v for k, v in json.loads((here / "config.json").read_text()).items() if k != "out_dir"}
    # a second pass finds both finished and sends nothing to the cluster
    again = subprocess.run([sys.executable, "-m", "safemanip.cli", "bench", "train", "--benchmark",
                            str(trained["bench"]), "--out", str(runs), "--policies", str(tmp_path / "policies"),
                            "--address", address], capture_output=True, text=True, timeout=120, env=env)
    assert again.returncode == 0 and "2 finished or promoted (skipped), 0 to train" in again.stdout, again.stderr

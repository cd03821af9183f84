"""Shared test set-up and the helpers more than one test file uses.

Headless offscreen rendering goes through Mesa's EGL: MuJoCo picks its OpenGL backend when it is first imported, so
the default is set before any test module imports mujoco (``import safemanip`` sets the same default; a user's own
choice wins).

The helpers are plain functions and constants, imported as ``from conftest import make_policy`` (pytest puts this
folder on ``sys.path``), plus the ``gl`` fixture for render tests. A helper only one file uses stays in that file.
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import json  # noqa: E402  (after the OpenGL default, which must come first)
import subprocess  # noqa: E402
import sys  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
from functools import lru_cache  # noqa: E402
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Callable  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
"""The repository's top folder."""

# ------------------------------------------------------------------------------------------ the command line
SAFEMANIP = [sys.executable, "-m", "safemanip.cli"]
"""The ``safemanip`` command as a subprocess argv prefix (this interpreter, so the venv's package)."""
SUBPROCESS_ENV = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
"""The environment of a subprocess that must import what this test process imports."""


def run_cli(capsys, argv):
    """(exit code, stdout, stderr) of ``safemanip ARGV`` run in this process (fast: no interpreter start)."""
    from safemanip.cli import main

    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def assert_refused(capsys, argv, message):
    """``safemanip ARGV`` is refused the package's way: exit code 2, ``message`` in the one ``error:`` line on
    stderr, no traceback. Returns stderr."""
    code, out, err = run_cli(capsys, argv)
    assert code == 2, (code, out[-500:], err[-1000:])
    assert message in err, err
    assert "Traceback" not in err and "Traceback" not in out
    assert "error:" in err
    return err


def run_safemanip(args, cwd=None, timeout: float = 120) -> subprocess.CompletedProcess:
    """``safemanip ARGS`` as a real subprocess (text output captured)."""
    return subprocess.run([*SAFEMANIP, *map(str, args)], capture_output=True, text=True, timeout=timeout, cwd=cwd,
                          env=SUBPROCESS_ENV)


# ------------------------------------------------------------------------------------------ training
TINY_TRAIN = {"k": 1, "hidden": [32, 32], "batch_size": 32, "buffer_size": 5000, "learning_starts": 300,
              "random_steps": 300, "eval_episodes": 2, "eval_every_s": 3, "checkpoint_every_s": 2, "log_every_s": 1,
              "envs_per_collector": 2, "env_steps_per_update": 2.0}
"""A training config (``--config`` file contents) small enough to learn, checkpoint and evaluate within seconds;
the tests add their own budget."""


# ------------------------------------------------------------------------------------------ policy files
def make_policy(path, k, constraints="conservative", hidden=(16, 16), seed=0, goal_seeker=False, embodiment="panda",
                object_size=None, obs_dim=None):
    """A tiny random MLP policy file, or (goal_seeker) a one-layer one that drives the box at the goal:
    the latter hits clutter within a few steps, so collisions of both kinds show up in short runs.
    ``object_size`` (True/False) is recorded in the metadata when given; ``obs_dim`` overrides the input size."""
    from safemanip.env.observation import observation_dim
    from safemanip.rl.checkpoint import save_policy

    rng = np.random.default_rng(seed)
    d = obs_dim or observation_dim(k, bool(object_size))
    if goal_seeker:
        from safemanip.scene.config import GEOMETRY

        w = np.zeros((3, d), np.float32)
        # obs[6:8] = bottom box x, y; a weak pull across, so that the pull out stays straight (heading 10 deg aside
        # drags the top box along: with a gain of 1 across, every pull did) and the box heads for the goal once out
        w[0, 6], w[1, 7] = -4.0, -0.5
        b = np.array([4.0 * GEOMETRY.goal_xy[0], 0.5 * GEOMETRY.goal_xy[1], 0.0], np.float32)
        arrays, hidden = [w, b], ()
    else:
        sizes = [d, *hidden, 3]
        arrays = []
        for i in range(len(sizes) - 1):
            arrays += [rng.normal(0, 1 / np.sqrt(sizes[i]), (sizes[i + 1], sizes[i])).astype(np.float32),
                       np.zeros(sizes[i + 1], np.float32)]
    meta = {"algorithm": "rarl", "k": k, "constraints": constraints, "obs_dim": d, "act_dim": 3,
            "hidden": list(hidden), "env_kwargs": {"n_objects": k,
                                                   "constraints": "random" if constraints == "all" else constraints,
                                                   "near_path_fraction": 0.5, "max_episode_steps": 300,
                                                   "embodiment": embodiment}}
    if embodiment is None:  # a policy from before the Panda arm: its metadata names no embodiment
        del meta["env_kwargs"]["embodiment"]
    if object_size is not None:
        meta["env_kwargs"]["object_size"] = object_size
    return str(save_policy(path, arrays, meta))


def policy_file(path: Path, tensors=None, meta=None, fmt=None, raw_meta=None) -> str:
    """A policy file written around the package's writer: any tensors, metadata (or raw metadata text) and format
    tag (default: the package's), for the loader's refusals. The default is a valid k = 1 Panda policy."""
    from safetensors.numpy import save_file

    from safemanip.rl.checkpoint import POLICY_FORMAT

    rng = np.random.default_rng(0)
    if tensors is None:
        tensors = {"layer0.weight": rng.normal(size=(8, 26)).astype(np.float32),
                   "layer0.bias": np.zeros(8, np.float32),
                   "layer1.weight": rng.normal(size=(3, 8)).astype(np.float32),
                   "layer1.bias": np.zeros(3, np.float32)}
    if meta is None:
        meta = {"algorithm": "rarl", "k": 1, "constraints": "conservative", "obs_dim": 26, "act_dim": 3,
                "hidden": [8], "env_kwargs": {"n_objects": 1, "max_episode_steps": 300, "embodiment": "panda"}}
    save_file(tensors, str(path), metadata={"format": POLICY_FORMAT if fmt is None else fmt,
                                            "meta": raw_meta if raw_meta is not None else json.dumps(meta)})
    return str(path)


# ------------------------------------------------------------------------------------------ evaluation records
def fake_summary(success, n=100, **fails):
    """An evaluation's summary.json contents with the given success rate, the named failure counts and the rest
    timeouts (what the sweep renderers and findings read)."""
    from safemanip.evaluation.episode import CATEGORIES

    counts = {c: 0 for c in CATEGORIES}
    counts["success"] = int(success * n)
    counts.update(fails)
    counts["timeout"] += n - sum(counts.values())

    def rate(c):
        return {"count": c, "rate": c / n, "ci95": [max(0, c / n - 0.1), min(1, c / n + 0.1)]}

    viol = sum(counts[c] for c in ("top_box", "out_of_workspace", "collision_unselected", "collision_selected",
                                   "soft_contact"))
    return {"episodes": n, "success": rate(counts["success"]), "safety_violation": rate(viol),
            "categories": {c: rate(v) for c, v in counts.items()}, "mean_length": 100.0}


# ------------------------------------------------------------------------------------------ selector views
BOX = np.array([0.0, 0.0, 0.035])
"""The held box's centre in the selector tests' views."""


def scene_view(t, positions, classes=None, box=BOX):
    """What a selector sees at step ``t``: objects at ``positions`` (x, y or x, y, z), at rest, named obj0, obj1,
    ...; the box (and hand) at ``box`` for the whole past; ``classes``: their privileged classes."""
    from safemanip.selection.base import SceneView

    positions = np.asarray(positions, dtype=float)
    if positions.shape[1] == 2:
        positions = np.c_[positions, np.zeros(len(positions))]
    n = len(positions)
    path = np.tile(box, (t + 1, 1))
    return SceneView(t=t, names=tuple(f"obj{i}" for i in range(n)), positions=positions,
                     velocities=np.zeros((n, 3)), ee_path=path, box_path=path, box_velocity=np.zeros(3),
                     privileged_classes=tuple(classes) if classes else None)


# ------------------------------------------------------------------------------------------ processes
def _children() -> dict[int, list[int]]:
    kids: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
            except OSError:
                continue
            ppid = int(stat.rsplit(")", 1)[1].split()[1])
            kids.setdefault(ppid, []).append(int(entry))
    return kids


def descendants(pid: int) -> set[int]:
    """Every living process that descends from ``pid`` (read from /proc)."""
    kids, out, todo = _children(), set(), [pid]
    while todo:
        for c in kids.get(todo.pop(), []):
            if c not in out:
                out.add(c)
                todo.append(c)
    return out


def cmdline(pid: int) -> str:
    """A process's command line ('' once it is gone)."""
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def process_name(pid: int) -> str:
    """A process's name in ps/top (``/proc/PID/comm``; '' once it is gone): the training run's evaluation process
    names itself 'safemanip-eval'."""
    try:
        return Path(f"/proc/{pid}/comm").read_text().strip()
    except OSError:
        return ""


# ------------------------------------------------------------------------------------------ a fake VLM server
VLM_NAMES = ("red mug", "toy sheep", "soda can")
"""The objects of ``vlm_view``."""


def completion(content: str, finish_reason: str = "stop") -> dict:
    """A chat-completions response body whose one choice says ``content``."""
    return {"id": "chatcmpl-test", "object": "chat.completion", "created": int(time.time()), "model": "test-model",
            "choices": [{"index": 0, "finish_reason": finish_reason,
                         "message": {"role": "assistant", "content": content, "refusal": None}}],
            "usage": {"prompt_tokens": 1, "completion_tokens": 1, "total_tokens": 2}}


class FakeServer:
    """A local chat-completions server on 127.0.0.1 (a thread). Records requests; ``reply(request_json) -> (status,
    body bytes, content type)`` decides the answer."""

    def __init__(self, reply: Callable[[dict], tuple[int, bytes, str]]) -> None:
        self.reply = reply
        self.requests: list[dict] = []
        self.headers: list[dict] = []
        outer = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:  # noqa: N802 - http.server naming
                body = self.rfile.read(int(self.headers.get("Content-Length", 0)))
                req = json.loads(body)
                outer.requests.append({"path": self.path, **req})
                outer.headers.append(dict(self.headers))
                status, payload, ctype = outer.reply(req)
                try:
                    self.send_response(status)
                    self.send_header("Content-Type", ctype)
                    self.send_header("Content-Length", str(len(payload)))
                    self.end_headers()
                    self.wfile.write(payload)
                except (BrokenPipeError, ConnectionResetError):
                    pass  # the client gave up (timeout test)

            def log_message(self, *args) -> None:
                pass

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        self.thread = threading.Thread(target=self.httpd.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)

    @property
    def base_url(self) -> str:
        return f"http://127.0.0.1:{self.httpd.server_address[1]}/v1"

    def __enter__(self) -> "FakeServer":
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


def json_reply(answer_for: Callable[[dict], dict]) -> Callable[[dict], tuple[int, bytes, str]]:
    """A ``FakeServer`` reply: HTTP 200 with ``answer_for(request)`` as the structured answer."""
    return lambda req: (200, json.dumps(completion(json.dumps(answer_for(req)))).encode(), "application/json")


def schema_of(req: dict) -> dict:
    """The JSON schema a request asks the model to answer in."""
    return req["response_format"]["json_schema"]["schema"]


def pick_last_k(req: dict) -> dict:
    """A well-behaved 'model': picks the k labels furthest down the list."""
    objects = schema_of(req)["properties"]["objects"]
    labels, k = objects["items"]["enum"], objects["minItems"]
    return {"image_description": "two frames; the box moves right", "explanation": "fragile and close",
            "objects": labels[-k:]}


def backend_for(server: FakeServer, **kw):
    """The openai backend talking to ``server``, with short timeouts and back-off."""
    from safemanip.semantics.openai_backend import OpenAIBackend

    kw.setdefault("timeout_s", 2.0)
    kw.setdefault("backoff_s", 0.01)
    return OpenAIBackend(model="test-model", base_url=server.base_url, **kw)


def vlm_view(t: int = 0, render=None):
    """A three-object view (``VLM_NAMES``) for the VLM selectors."""
    from safemanip.selection.base import SceneView

    pos = np.array([[0.10, 0.0, 0.85], [0.30, 0.0, 0.85], [0.50, 0.1, 0.85]])
    box = np.array([[0.0, 0.0, 0.85]])
    return SceneView(t=t, names=VLM_NAMES, positions=pos, velocities=np.zeros((3, 3)), ee_path=box, box_path=box,
                     box_velocity=np.zeros(3), render=render)


# ------------------------------------------------------------------------------------------ rendering
@lru_cache(maxsize=None)
def gl_context_problem() -> str | None:
    """Why no offscreen OpenGL context can be created in this process (None: one can), with the MUJOCO_GL backend
    MuJoCo picked. Asked once: a render test's own failures are the test's, not this check's."""
    try:
        import mujoco

        context = mujoco.GLContext(64, 64)
        context.make_current()
        context.free()
    except Exception as err:  # noqa: BLE001 - any reason the backend gives is the reason to report
        return f"{type(err).__name__}: {err}"
    return None


def require_gl() -> None:
    """The render tests' rule: skip when no OpenGL context can be created and the environment variable CI is unset
    (a developer's machine without a GPU stack); fail when CI is set (a CI job must render). Without a problem,
    nothing happens and the test renders as it will."""
    problem = gl_context_problem()
    if problem is None:
        return
    backend = os.environ.get("MUJOCO_GL")
    if "CI" in os.environ:
        pytest.fail(f"CI is set, so the render tests must run, but no OpenGL context can be created with "
                    f"MUJOCO_GL={backend!r}: {problem}. Install Mesa's EGL (apt-get install libegl1 libgl1-mesa-dri) "
                    f"and keep MUJOCO_GL=egl, or unset CI to skip them")
    pytest.skip(f"no OpenGL context with MUJOCO_GL={backend!r} ({problem}); to run the render tests install Mesa's "
                f"EGL (apt-get install libegl1 libgl1-mesa-dri; `make test` does so as root) and use MUJOCO_GL=egl, "
                f"or MUJOCO_GL=osmesa with libosmesa6. With CI set this fails instead of skipping")


@pytest.fixture
def gl():
    """A render test asks for this fixture: it skips or fails by ``require_gl``'s rule before the test renders."""
    require_gl()

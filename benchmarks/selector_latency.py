"""Per-query latency (median, p95) of every object and constraint selector, in one run.

    python benchmarks/selector_latency.py [--scenes 4] [--steps 16] [--n-objects 6] [--k 2] [--json out.json]

Views come from scripted rollouts in SlideOutEnv (the same views ``safemanip eval`` builds, lazy
rendering included); only the selector call is timed, never the physics. Every call of a dynamic
selector is made a query (interval 1), so each timed call is one query:

  object selectors      static-knn (its one pick at t = 0), dynamic-knn, privileged, dynamic-vlm with the
                        semantic backend (after the scene's one batched embedding call, timed separately);
  constraint selectors  conservative, ground-truth, vlm with the semantic backend (names already embedded,
                        and at first sight of the names, which includes the embedding call);
  openai backend        dynamic-vlm and vlm constraints on the openai backend replaying from its response
                        cache in cache_only mode. The cache is filled first by running the same rollouts
                        against a tiny chat-completions server on 127.0.0.1 (it answers with the nearest k
                        labels / soft_contact); the replay then never opens a connection. A replayed
                        object query still renders the frame, annotates it, tiles the history, encodes the
                        PNG and hashes it for the cache key -- that is its cost.

Default settings finish in about 20-30 s (most of it the model load and the software rendering of the
two openai passes); the last rows split a replayed image query into rendering, annotation and PNG.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")


# ------------------------------------------------------------------ a minimal chat-completions server
class ChatServer:
    """Answers every structured request validly: the first k labels of the object enum (the nearest to
    the end-effector) or soft_contact for every object. Counts requests."""

    def __init__(self) -> None:
        self.requests = 0
        outer = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:  # noqa: N802 - http.server naming
                req = json.loads(self.rfile.read(int(self.headers.get("Content-Length", 0))))
                outer.requests += 1
                schema = req["response_format"]["json_schema"]["schema"]
                props = schema["properties"]
                if "objects" in props:
                    labels, k = props["objects"]["items"]["enum"], props["objects"]["minItems"]
                    answer = {"image_description": "benchmark", "explanation": "nearest", "objects": labels[:k]}
                else:
                    answer = {"constraints": {lbl: {"explanation": "benchmark", "constraint": "soft_contact"}
                                              for lbl in props["constraints"]["required"]}}
                body = json.dumps({"id": "bench", "object": "chat.completion", "created": int(time.time()),
                                   "model": req["model"], "choices": [{"index": 0, "finish_reason": "stop",
                                   "message": {"role": "assistant", "content": json.dumps(answer), "refusal": None}}],
                                   "usage": {"prompt_tokens": 1, "completion_tokens": 1, "total_tokens": 2}}).encode()
                self.send_response(200)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, *args) -> None:
                pass

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        self.thread = threading.Thread(target=self.httpd.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)

    @property
    def base_url(self) -> str:
        return f"http://127.0.0.1:{self.httpd.server_address[1]}/v1"

    def __enter__(self) -> "ChatServer":
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


# ------------------------------------------------------------------ rollouts
def rollout(env, seed: int, steps: int, on_view) -> None:
    """Scripted rollout; ``on_view(view)`` is called at every control step while the env is in that state."""
    from safemanip.control.scripted import ScriptedController
    from safemanip.selection.view import EnvViewBuilder

    _, info = env.reset(seed=seed)
    ctrl = ScriptedController()
    ctrl.reset()
    builder = EnvViewBuilder()
    builder.reset(env)
    for t in range(steps + 1):
        if t:
            _, _, terminated, truncated, info = env.step(ctrl.act(info, env))
        on_view(builder.view(env, env.scene_state(), t))
        if t and (terminated or truncated):
            break


def timed(fn, *args) -> float:
    start = time.perf_counter()
    fn(*args)
    return time.perf_counter() - start


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", type=int, default=4, help="scripted rollouts (seeds 0..scenes-1), default 4")
    ap.add_argument("--steps", type=int, default=16, help="control steps per rollout (default 16)")
    ap.add_argument("--n-objects", type=int, default=6)
    ap.add_argument("--k", type=int, default=2)
    ap.add_argument("--constraint-repeats", type=int, default=20,
                    help="constraint queries per scene (each after a reset), default 20")
    ap.add_argument("--json", help="also write the table as JSON")
    args = ap.parse_args()
    if min(args.scenes, args.steps, args.n_objects, args.k, args.constraint_repeats) < 1:
        sys.exit("all counts must be >= 1")

    from safemanip.env.slide_out import SlideOutEnv
    from safemanip.selection.selectors import (ConservativeConstraints, DynamicKNN, GroundTruthConstraints,
                                               PrivilegedSelector, StaticKNN)
    from safemanip.semantics.cache import ResponseCache
    from safemanip.semantics.openai_backend import OpenAIBackend
    from safemanip.semantics.selectors import DynamicVLMSelector, VLMConstraintSelector
    from safemanip.semantics.semantic_backend import SemanticBackend

    wall0 = time.perf_counter()
    lat: dict[str, list[float]] = {}
    extra: dict[str, float] = {}

    t0 = time.perf_counter()
    semantic = SemanticBackend()
    semantic.prepare(["warm-up"])  # model load + the 75 example names, once per process
    extra["semantic model load + prototypes [s]"] = time.perf_counter() - t0

    env = SlideOutEnv(n_objects=args.n_objects)
    k = args.k

    # ---- metric, privileged and semantic selectors on the same views
    for seed in range(args.scenes):
        sels = {"static-knn": StaticKNN(), "dynamic-knn": DynamicKNN(1), "privileged": PrivilegedSelector(1),
                "dynamic-vlm (semantic)": DynamicVLMSelector(semantic, query_interval=1)}
        cons = {"conservative": ConservativeConstraints(), "ground-truth": GroundTruthConstraints(),
                "vlm (semantic)": VLMConstraintSelector(semantic)}

        def on_view(view, sels=sels, cons=cons):
            if view.t == 0:
                # a new scene: names the backend has not seen cost one batched embedding call
                for name in view.names:
                    semantic._probs.pop(name, None)
                    semantic._sims.pop(name, None)
                lat.setdefault("vlm (semantic), names not yet embedded", []).append(
                    timed(VLMConstraintSelector(semantic).assign, view))
                for name in view.names:
                    semantic._probs.pop(name, None)
                    semantic._sims.pop(name, None)
                lat.setdefault("scene preparation (semantic, one embedding call)", []).append(
                    timed(sels["dynamic-vlm (semantic)"].reset, view, k))
                sels["dynamic-knn"].reset(view, k)
                sels["privileged"].reset(view, k)
                lat.setdefault("static-knn", []).append(timed(lambda: (sels["static-knn"].reset(view, k),
                                                                       sels["static-knn"].select(view, k))))
                for name, sel in cons.items():
                    for _ in range(args.constraint_repeats):
                        if hasattr(sel, "reset"):
                            sel.reset()
                        lat.setdefault(name, []).append(timed(sel.assign, view))
            for name in ("dynamic-knn", "privileged", "dynamic-vlm (semantic)"):
                lat.setdefault(name, []).append(timed(sels[name].select, view, k))

        rollout(env, seed, args.steps, on_view)

    # ---- openai backend: record against the local server, then replay from the cache only
    with tempfile.TemporaryDirectory(prefix="vlm_cache_") as cache_dir:
        with ChatServer() as server:
            rec = OpenAIBackend(model="bench-model", base_url=server.base_url, cache=ResponseCache(cache_dir),
                                timeout_s=10.0, attempts=1)
            for seed in range(args.scenes):
                obj = DynamicVLMSelector(rec, query_interval=1)
                con = VLMConstraintSelector(rec)

                def record(view, obj=obj, con=con):
                    if view.t == 0:
                        obj.reset(view, k)
                        con.assign(view)
                        lat.setdefault("dynamic-vlm (openai, live local server)", [])
                    lat["dynamic-vlm (openai, live local server)"].append(timed(obj.select, view, k))

                rollout(env, seed, args.steps, record)
            recorded, requests = ResponseCache(cache_dir).count(), server.requests
            fallbacks = 0
        replay = OpenAIBackend(model="bench-model", base_url="http://127.0.0.1:9/v1",
                               cache=ResponseCache(cache_dir, mode="cache_only"), attempts=1)
        for seed in range(args.scenes):
            obj = DynamicVLMSelector(replay, query_interval=1)
            con = VLMConstraintSelector(replay)

            def play(view, obj=obj, con=con):
                if view.t == 0:
                    obj.reset(view, k)
                    for _ in range(args.constraint_repeats):
                        con.reset()
                        lat.setdefault("vlm (openai, cache replay)", []).append(timed(con.assign, view))
                lat.setdefault("dynamic-vlm (openai, cache replay)", []).append(timed(obj.select, view, k))

            rollout(env, seed, args.steps, play)
            fallbacks += obj.stats.fallbacks + con.stats.fallbacks
        if replay.calls or fallbacks:
            sys.exit(f"replay was not served from the cache: {replay.calls} requests sent, {fallbacks} fallbacks")

    # ---- where a replayed image query spends its time (last scene's final state, 5 repetitions each)
    from safemanip.semantics.base import object_label
    from safemanip.semantics.images import annotate, tile, to_png

    frame = env.render_camera("front")
    boxes = {i: b for i, b in env.object_boxes_2d("front").items() if isinstance(i, int)}
    labels = {i: object_label(i, n) for i, n in enumerate(env.names)}
    path_px = np.array([[100.0, 300.0], [150.0, 320.0], [220.0, 330.0]])
    annotated = annotate(frame, boxes, labels, path_px)
    for name, fn in [("  part: render one 640x480 frame", lambda: env.render_camera("front")),
                     ("  part: annotate one frame", lambda: annotate(frame, boxes, labels, path_px)),
                     ("  part: tile two frames + PNG encode", lambda: to_png(tile([annotated, annotated])))]:
        lat[name] = [timed(fn) for _ in range(5)]
    env.close()

    kinds = {"static-knn": "object", "dynamic-knn": "object", "privileged": "object",
             "dynamic-vlm (semantic)": "object",
             "dynamic-vlm (openai, live local server)": "object", "dynamic-vlm (openai, cache replay)": "object",
             "conservative": "constraint", "ground-truth": "constraint", "vlm (semantic)": "constraint",
             "vlm (semantic), names not yet embedded": "constraint", "vlm (openai, cache replay)": "constraint",
             "  part: render one 640x480 frame": "", "  part: annotate one frame": "",
             "  part: tile two frames + PNG encode": "",
             "scene preparation (semantic, one embedding call)": "per scene"}
    rows = []
    for name, kind in kinds.items():
        xs = lat.get(name, [])
        if not xs:
            continue
        rows.append({"selector": name, "kind": kind, "queries": len(xs), "median_ms": 1e3 * statistics.median(xs),
                     "p95_ms": 1e3 * float(np.percentile(xs, 95))})
    print(f"selector latency: {args.scenes} scripted rollouts x up to {args.steps} steps, N = {args.n_objects}, "
          f"k = {k}; every timed call is one query")
    print(f"{'selector':50s} {'kind':>11s} {'queries':>8s} {'median ms':>10s} {'p95 ms':>9s}")
    for r in rows:
        print(f"{r['selector']:50s} {r['kind']:>11s} {r['queries']:>8d} {r['median_ms']:>10.3f} {r['p95_ms']:>9.3f}")
    for key, value in extra.items():
        print(f"{key}: {value:.2f}")
    print(f"openai cache: {recorded} answers recorded from {requests} requests to the local server; replay sent 0 "
          "requests (cache_only)")
    print(f"wall time {time.perf_counter() - wall0:.1f} s")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({"settings": vars(args), "rows": rows, **extra}, f, indent=1)


if __name__ == "__main__":
    main()

"""The package is strictly layered: no module imports (at module level or inside a function) from a
layer above its own, and no two of its packages import each other. Layers, bottom to top:

  0  util, scene                   plain helpers, the catalog, the scene builder and the robot models
  1  control                       the robots' controllers, the scripted controller and the planner
  2  env, toy.system               the Gymnasium envs
  3  rl, selection, safety         the learner, the selectors/reducer, the braking filter
  4  semantics, toy (oracle)       semantic backends and selectors; the learner's exact test oracle
  5  evaluation                    episodes judged on the full scene, the selector registry, sweeps
  6  bench                         the paper's benchmark: its runs, their promotion, the verdicts and findings
  7  demo, cli                     what a person runs
"""

from __future__ import annotations

import ast
from pathlib import Path

import safemanip

ROOT = Path(safemanip.__file__).parent
LAYERS = {"util": 0, "scene": 0, "control": 1, "env": 2, "toy.system": 2, "rl": 3, "selection": 3, "safety": 3,
          "semantics": 4, "toy": 4, "evaluation": 5, "bench": 6, "demo": 7, "cli": 7}


def package_of(module: str) -> str | None:
    """The package of a ``safemanip.x.y`` module as LAYERS names it: the longest matching prefix (None: the package
    root). ``toy.system`` counts apart from the rest of ``toy``: the toy env sits below ``rl``, its oracle above."""
    parts = module.split(".")[1:]
    for n in range(len(parts), 0, -1):
        key = ".".join(parts[:n])
        if key in LAYERS:
            return key
    return None


def layer_of(module: str) -> int | None:
    """Layer of a ``safemanip.x.y`` module (None: the package root)."""
    package = package_of(module)
    return None if package is None else LAYERS[package]


def module_of(path: Path) -> str:
    return "safemanip." + ".".join(path.relative_to(ROOT).with_suffix("").parts)


def imports_of(path: Path) -> list[tuple[int, str]]:
    tree = ast.parse(path.read_text(), filename=str(path))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.append((node.lineno, node.module))
            found += [(node.lineno, f"{node.module}.{a.name}") for a in node.names]
    return [(line, m) for line, m in found if m.startswith("safemanip.")]


def test_every_module_has_a_layer():
    for path in ROOT.rglob("*.py"):
        module = module_of(path)
        if module.endswith("__init__") and path.parent == ROOT:
            continue
        assert layer_of(module) is not None, f"{module} belongs to no layer; add its package to LAYERS"


def test_no_module_imports_a_higher_layer():
    upward = []
    for path in sorted(ROOT.rglob("*.py")):
        module = module_of(path)
        own = layer_of(module)
        if own is None:
            continue
        for line, target in imports_of(path):
            theirs = layer_of(target)
            # "from safemanip.rl import envs" names the module safemanip.rl.envs: judge the deepest known name
            if theirs is not None and theirs > own:
                upward.append(f"{path.relative_to(ROOT)}:{line} ({own}) imports {target} ({theirs})")
    assert not upward, "imports up the layers:\n" + "\n".join(upward)


def test_the_checker_sees_an_upward_import(tmp_path):
    bad = tmp_path / "m.py"
    bad.write_text("def f():\n    from safemanip.evaluation.harness import evaluate\n")
    assert imports_of(bad) == [(2, "safemanip.evaluation.harness"), (2, "safemanip.evaluation.harness.evaluate")]
    assert layer_of("safemanip.evaluation.harness") > layer_of("safemanip.rl.train")
    assert layer_of("safemanip.toy.system") < layer_of("safemanip.rl.envs") < layer_of("safemanip.toy.oracle")
    assert layer_of("safemanip.scene.panda") < layer_of("safemanip.control.planner") < layer_of("safemanip.env.sampling")
    assert layer_of("safemanip.evaluation.sweep") < layer_of("safemanip.bench.train") < layer_of("safemanip.cli.bench")


def package_imports() -> dict[str, set[str]]:
    """Package -> the other packages its modules import (at module level or inside a function)."""
    edges: dict[str, set[str]] = {}
    for path in sorted(ROOT.rglob("*.py")):
        own = package_of(module_of(path))
        for _, target in imports_of(path):
            theirs = package_of(target)
            if own is not None and theirs is not None and theirs != own:
                edges.setdefault(own, set()).add(theirs)
    return edges


def find_cycle(edges: dict[str, set[str]]) -> list[str]:
    """A cycle of ``edges`` as [a, b, ..., a] (a imports b, ..., back to a), or [] when there is none."""
    done: set[str] = set()  # packages from which no cycle can be reached

    def visit(path: list[str]) -> list[str]:
        for nxt in sorted(edges.get(path[-1], ())):
            if nxt in path:
                return path[path.index(nxt):] + [nxt]
            if nxt not in done:
                found = visit(path + [nxt])
                if found:
                    return found
        done.add(path[-1])
        return []

    for start in sorted(edges):
        found = visit([start])
        if found:
            return found
    return []


def test_no_two_packages_import_each_other():
    """A package-level cycle (scene -> control -> scene, or through more packages) is refused even within a layer,
    where the layer test cannot see it."""
    cycle = find_cycle(package_imports())
    assert not cycle, "packages import each other: " + " -> ".join(cycle)


def test_the_cycle_check_sees_a_cycle():
    assert find_cycle({"scene": {"util"}, "control": {"scene"}, "env": {"control", "scene"}}) == []
    assert find_cycle({"scene": {"control"}, "control": {"scene"}}) == ["control", "scene", "control"]
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == ["a", "b", "c", "a"]
    assert "control" in package_imports()["env"] and "scene" in package_imports()["control"]


def test_rl_imports_nothing_from_selection():
    """``rl`` and ``selection`` share a layer and import nothing from each other: the selection-aware training env
    reaches ``rl.train.train`` as its ``env_factory`` argument (``safemanip train`` passes it). ``rl`` never imports
    ``selection``, not even in a function."""
    found = [f"{path.relative_to(ROOT)}:{line} imports {target}" for path in sorted((ROOT / "rl").rglob("*.py"))
             for line, target in imports_of(path) if target.startswith("safemanip.selection")]
    assert not found, "\n".join(found)

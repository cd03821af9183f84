"""The package is strictly layered: no module imports (at module level or inside a function) from a
layer above its own. Layers, bottom to top:

  0  util, scene, control          plain helpers, the catalog and scene builder, the scripted controller
  1  env, toy.system               the Gymnasium envs
  2  rl, selection                 the learner and the selectors/reducer
  3  semantics, toy (oracle)       semantic backends and selectors; the learner's exact test oracle
  4  evaluation                    episodes judged on the full scene, the selector registry, sweeps
  5  demo, cli                     what a person runs
"""

from __future__ import annotations

import ast
from pathlib import Path

import safemanip

ROOT = Path(safemanip.__file__).parent
LAYERS = {"util": 0, "scene": 0, "control": 0, "env": 1, "toy.system": 1, "rl": 2, "selection": 2, "safety": 2, "semantics": 3,
          "toy": 3, "evaluation": 4, "demo": 5, "cli": 5}


def layer_of(module: str) -> int | None:
    """Layer of a ``safemanip.x.y`` module: the longest matching prefix in LAYERS (None: the package root)."""
    parts = module.split(".")[1:]
    for n in range(len(parts), 0, -1):
        key = ".".join(parts[:n])
        if key in LAYERS:
            return LAYERS[key]
    return None


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
        module = "safemanip." + ".".join(path.relative_to(ROOT).with_suffix("").parts)
        if module.endswith("__init__") and path.parent == ROOT:
            continue
        assert layer_of(module) is not None, f"{module} belongs to no layer; add its package to LAYERS"


def test_no_module_imports_a_higher_layer():
    upward = []
    for path in sorted(ROOT.rglob("*.py")):
        module = "safemanip." + ".".join(path.relative_to(ROOT).with_suffix("").parts)
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


def test_rl_imports_nothing_from_selection():
    """``rl`` and ``selection`` share a layer, but only one way: the selection-aware training env registers its
    factory with ``rl.envs`` (``register_env``); ``rl`` never imports ``selection``, not even in a function."""
    found = [f"{path.relative_to(ROOT)}:{line} imports {target}" for path in sorted((ROOT / "rl").rglob("*.py"))
             for line, target in imports_of(path) if target.startswith("safemanip.selection")]
    assert not found, "\n".join(found)

"""The code in the docs runs: the extension guide's example is executed as written."""

from __future__ import annotations

import re
from pathlib import Path

DOCS = Path(__file__).parents[1] / "docs"


def python_blocks(path: Path) -> list[str]:
    return re.findall(r"```python\n(.*?)```", path.read_text(), flags=re.S)


def test_the_extension_guide_example_runs_a_custom_selector_through_run_episode(capsys):
    blocks = python_blocks(DOCS / "extending.md")
    assert len(blocks) == 1
    scope: dict = {}
    exec(compile(blocks[0], "docs/extending.md", "exec"), scope)
    records = scope["records"]
    assert len(records) == 5
    for r in records:
        assert r["outcome"] in ("success", "failure", "timeout") and r["length"] >= 1
        assert r["selections"].startswith("0:") and len(r["names"].split(";")) == 5
    # the selector was consulted: two distinct ids at t = 0 of every episode
    assert all(len(r["selections"].split(";")[0][2:].split(",")) == 2 for r in records)
    printed = capsys.readouterr().out
    assert printed.count("(") == 5 and all(r["outcome"] in printed for r in records)


def _readme_commands() -> list[str]:
    """Every ``safemanip ...`` command in the README's shell blocks, continuation lines joined, comments dropped;
    lines that show alternatives (``a | b``) or optional parts (``[...]``) are left out."""
    text = (DOCS.parent / "README.md").read_text()
    commands = []
    for block in re.findall(r"```bash\n(.*?)```", text, flags=re.S):
        for line in block.replace("\\\n", " ").splitlines():
            line = line.split(" # ")[0].strip()
            if line.startswith("safemanip ") and " | " not in line and "[" not in line:
                commands.append(line)
    return commands


def test_the_readme_s_commands_parse():
    """The commands a reader copies from the README are ones the CLI takes (flags, choices, ranges)."""
    import shlex

    from safemanip.cli import build_parser

    commands = _readme_commands()
    assert len(commands) >= 10
    parser = build_parser()
    for command in commands:
        parser.parse_args(shlex.split(command)[1:])  # argparse exits (SystemExit) on anything it does not take


def test_the_readme_is_short_and_links_resolve():
    readme = (DOCS.parent / "README.md").read_text()
    assert len(readme.splitlines()) <= 250
    for target in re.findall(r"\]\(([^)#]+)\)", readme):
        assert (DOCS.parent / target).exists(), target


def test_the_results_history_is_a_short_table_whose_commits_exist():
    """docs/results-history.md lists each superseded result generation in one table row (date, commit, what changed,
    headline number, why superseded); the full records are in git history at the commits it names (issue 43)."""
    import subprocess

    lines = (DOCS / "results-history.md").read_text().splitlines()
    assert len(lines) <= 60
    rows = [line for line in lines if re.match(r"\| \d{4}-\d{2}-\d{2} \|", line)]
    assert len(rows) >= 10 and all(row.count("|") == 6 for row in rows), "five cells a row"
    commits = {c for row in rows for c in re.findall(r"`([0-9a-f]{7})\^?`", row.split("|")[2])}
    assert all(re.search(r"`[0-9a-f]{7}\^?`", row.split("|")[2]) for row in rows), "every row names its commit"
    root = DOCS.parent
    git = ["git", "-C", str(root)]
    shallow = subprocess.run([*git, "rev-parse", "--is-shallow-repository"], capture_output=True, text=True)
    if shallow.returncode != 0 or shallow.stdout.strip() != "false":
        return  # no history here (an unpacked archive or a shallow clone): nothing to look the commits up in
    missing = [c for c in sorted(commits)
               if subprocess.run([*git, "cat-file", "-e", f"{c}^{{commit}}"], capture_output=True).returncode != 0]
    assert not missing, f"docs/results-history.md names commits this repository does not have: {missing}"


def _help_texts():
    """(where, text) of what `safemanip --help` and `safemanip eval|sweep|train --help` print about each option and
    group of options; for train, the options generated from the training config's and the env config's fields."""
    import argparse
    from dataclasses import fields

    from safemanip.cli import build_parser
    from safemanip.rl.config import TrainConfig

    parser = build_parser()
    texts = [("safemanip", parser.description or "")]
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    texts += [(f"safemanip {c.dest}", c.help or "") for c in sub._choices_actions]
    config_fields = {f.name for f in fields(TrainConfig)}
    for name in ("eval", "sweep", "train"):
        for action in sub.choices[name]._actions:
            if name != "train" or action.dest in config_fields or action.dest.startswith("env:"):
                texts.append((f"safemanip {name} {'/'.join(action.option_strings) or action.dest}", action.help or ""))
        texts += [(f"safemanip {name} [{group.title}]", group.title or "")
                  for group in sub.choices[name]._action_groups]
        texts.append((f"safemanip {name} (description, epilog)", f"{sub.choices[name].description or ''} "
                                                                 f"{sub.choices[name].epilog or ''}"))
    return texts


def test_help_names_no_internal_class_and_the_time_budget_one_way():
    """User-facing help speaks plain words: no class name of the package (EvalRequest, SemanticBackend, ...), no
    ``code`` quoting. --minutes says how to switch its limit off in the one way the flag takes (issue 43)."""
    import ast

    classes = set()
    for path in (DOCS.parent / "src" / "safemanip").rglob("*.py"):
        classes |= {node.name for node in ast.walk(ast.parse(path.read_text())) if isinstance(node, ast.ClassDef)
                    and re.search(r"[a-z0-9][A-Z]", node.name)}  # compound names; one word (Learner) is English
    internal = re.compile(r"``|\b(?:" + "|".join(sorted(classes)) + r")\b")
    offending = [f"{where}: {internal.search(text).group(0)}" for where, text in _help_texts() if internal.search(text)]
    assert not offending, offending
    minutes = next(text for where, text in _help_texts() if where.endswith("--minutes"))
    assert "0 means no time limit" in minutes and "None" not in minutes and "none" not in minutes

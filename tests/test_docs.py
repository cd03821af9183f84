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

"""Every ``safemanip ...`` command shown in README.md and docs/*.md parses with the real command-line parser, and every
shipped policy it names exists: a renamed or removed flag or policy cannot linger in the documentation (issue 43)."""

from __future__ import annotations

import re
import shlex

import pytest

from safemanip.cli import build_parser
from conftest import ROOT

PLACEHOLDERS = re.compile(r"\[|\]|\.\.\.| \| |NAME|FILE|HOST:PORT|\bS\b|\bN\b")
"""Lines that show a command's shape rather than a command (optional parts, alternatives, placeholders)."""


def shown_commands() -> list[tuple[str, str]]:
    """(where, command) for every line of a bash block that runs safemanip, continuation lines joined and trailing
    comments dropped."""
    found = []
    for doc in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        for block in re.findall(r"```bash\n(.*?)```", doc.read_text(), flags=re.DOTALL):
            for line in re.sub(r"\\\n\s*", " ", block).splitlines():
                line = re.sub(r"\s+#.*$", "", line).strip()
                for part in re.split(r";|&&", line):
                    part = part.strip()
                    if part.startswith("safemanip ") and not PLACEHOLDERS.search(part):
                        found.append((doc.name, part))
    return found


COMMANDS = shown_commands()


def test_the_docs_show_commands_at_all():
    assert len(COMMANDS) >= 20


@pytest.mark.parametrize("where, command", COMMANDS, ids=[f"{w}:{c[:60]}" for w, c in COMMANDS])
def test_a_documented_command_parses(where, command):
    argv = shlex.split(command)[1:]
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exit_:
        pytest.fail(f"{where}: `{command}` does not parse (exit {exit_.code})")
    assert callable(getattr(args, "func", None)), f"{where}: `{command}` names no subcommand"
    policy = getattr(args, "policy", None)
    if policy and "/" not in policy and not policy.endswith(".safetensors"):  # a known policy's name
        from safemanip.rl.policy_index import find_policy
        assert find_policy(policy) is not None, f"{where}: no policy {policy!r} in the package or results/policies"

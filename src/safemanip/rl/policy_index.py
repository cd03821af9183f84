"""Where a policy named on the command line is found: the package's own folder (the demo policy) and the benchmark's
policy folders, each indexed by a manifest.

The benchmark's policies (54 files, about 31 MB) are results, not code, so they live outside the package, in the
repository's ``results/policies/``, beside the training records they came from. That folder's ``manifest.json``
lists every policy once: its file, sha256 and size, what it is (algorithm, k, constraints, the env it was trained
in), the command that trained it and where its training record is. ``--policy NAME`` finds a policy through the
manifest, and a file that does not match its entry (edited, truncated, replaced) is refused rather than evaluated.

Folders searched, in order:
  1. ``$SAFEMANIP_POLICIES`` when set (a folder with a manifest, e.g. a copy of results/policies);
  2. ``results/policies`` under the working folder (the repository's top, where the benchmark commands run);
  3. ``results/policies`` of the repository this package was installed from, when installed from a source checkout
     (``pip install -e .``), so the names work from any working folder;
  4. the package's own ``policies/`` folder: the demo policy, no manifest needed.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import asdict, dataclass, fields
from pathlib import Path

from safemanip.util.files import JSONInputError, atomic_write_text, read_json_file

MANIFEST = "manifest.json"
MANIFEST_FORMAT = "safemanip-policies/1"
ENV_VAR = "SAFEMANIP_POLICIES"
PACKAGE_POLICIES = Path(__file__).resolve().parent.parent / "policies"
"""The package's own policies: the demo policy (``safemanip demo``), found by name without a manifest."""
BENCHMARK_POLICIES = Path("results") / "policies"
"""The benchmark's policy folder, relative to the repository's top (``safemanip bench promote`` writes there)."""
_SOURCE_CHECKOUT = PACKAGE_POLICIES.parents[2]  # src/safemanip/policies -> the repository's top, if installed from one


class PolicyIndexError(ValueError):
    """A manifest or a policy file that does not match it; the message says what to do."""


@dataclass(frozen=True)
class PolicyEntry:
    name: str
    """The name ``--policy`` takes (the file name without .safetensors)."""
    file: str
    """The policy file, relative to the manifest's folder."""
    sha256: str
    bytes: int
    algorithm: str
    k: int
    constraints: str
    """The constraint types the policy was trained with ('conservative', 'all', ...)."""
    env: dict
    """The env settings it was trained in (the policy's env_kwargs)."""
    train_command: str
    record: str | None
    """Its training record (config, periodic evaluations, summary, choice), relative to the manifest's folder."""
    chosen: str | None
    """Which of the run's policies was promoted: 'final' or 'best' (None: not promoted by safemanip bench promote)."""


_FIELDS = {f.name for f in fields(PolicyEntry)}


def file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def read_manifest(folder: Path) -> dict[str, PolicyEntry]:
    """The manifest of ``folder`` by policy name ({} when the folder has none); PolicyIndexError if it is damaged."""
    path = Path(folder) / MANIFEST
    if not path.is_file():
        return {}
    try:
        data = read_json_file(path, "the policy manifest")
    except (JSONInputError, OSError) as err:
        raise PolicyIndexError(f"{path}: {err}; restore it (git checkout {path}) or rebuild it with "
                               f"safemanip bench promote") from None
    if not isinstance(data, dict) or data.get("format") != MANIFEST_FORMAT or not isinstance(data.get("policies"), list):
        raise PolicyIndexError(f"{path} is not a policy manifest (expected a JSON object with format "
                               f"{MANIFEST_FORMAT!r} and a list 'policies'); restore it or rebuild it with "
                               f"safemanip bench promote")
    entries: dict[str, PolicyEntry] = {}
    for i, raw in enumerate(data["policies"]):
        problem = _entry_problem(raw)
        if problem:
            raise PolicyIndexError(f"{path}: policy entry {i}: {problem}")
        entry = PolicyEntry(**raw)
        if entry.name in entries:
            raise PolicyIndexError(f"{path}: policy {entry.name!r} is listed twice")
        entries[entry.name] = entry
    return entries


def _entry_problem(raw) -> str | None:
    if not isinstance(raw, dict):
        return "must be a JSON object"
    if set(raw) != set(_FIELDS):
        missing, extra = sorted(set(_FIELDS) - set(raw)), sorted(set(raw) - set(_FIELDS))
        return f"must have exactly the fields {sorted(_FIELDS)} (missing {missing}, unknown {extra})"
    text = ("name", "file", "sha256", "algorithm", "constraints", "train_command")
    if not all(isinstance(raw[f], str) and raw[f] for f in text):
        return f"{', '.join(text)} must be non-empty strings"
    if not all(isinstance(raw[f], int) and not isinstance(raw[f], bool) and raw[f] > 0 for f in ("bytes", "k")):
        return "bytes and k must be positive integers"
    if not isinstance(raw["env"], dict):
        return "env must be a JSON object"
    if any(raw[f] is not None and not isinstance(raw[f], str) for f in ("record", "chosen")):
        return "record and chosen must be strings or null"
    file = Path(raw["file"])
    if file.is_absolute() or ".." in file.parts or file.suffix != ".safetensors":
        return f"file must be a .safetensors file inside the manifest's folder, got {raw['file']!r}"
    return None


def write_manifest(folder: Path, entries: dict[str, PolicyEntry]) -> Path:
    """Write ``folder``'s manifest atomically, sorted by name (so a promotion is a one-entry diff)."""
    import json

    body = {"format": MANIFEST_FORMAT,
            "about": "The benchmark's policies: safemanip eval --policy NAME finds them through this file "
                     "(safemanip/rl/policy_index.py). Written by safemanip bench promote.",
            "policies": [asdict(entries[name]) for name in sorted(entries)]}
    return atomic_write_text(Path(folder) / MANIFEST, json.dumps(body, indent=1) + "\n")


def entry_for(folder: Path, policy_file: Path, meta: dict, record: str | None, chosen: str | None) -> PolicyEntry:
    """The manifest entry of ``policy_file`` (a file in ``folder``), from its metadata (``load_policy``'s meta)."""
    policy_file = Path(policy_file)
    return PolicyEntry(name=policy_file.stem, file=str(policy_file.relative_to(folder)),
                       sha256=file_sha256(policy_file), bytes=policy_file.stat().st_size,
                       algorithm=meta["algorithm"], k=int(meta["k"]), constraints=meta["constraints"],
                       env=dict(meta.get("env_kwargs") or {}), train_command=meta.get("train_command") or "",
                       record=record, chosen=chosen)


def policy_folders() -> list[Path]:
    """The folders searched for a policy name, in order (see the module's docstring); only those that exist."""
    candidates = []
    if os.environ.get(ENV_VAR):
        candidates.append(Path(os.environ[ENV_VAR]))
    candidates += [Path.cwd() / BENCHMARK_POLICIES, _SOURCE_CHECKOUT / BENCHMARK_POLICIES, PACKAGE_POLICIES]
    seen, folders = set(), []
    for folder in candidates:
        key = folder.resolve() if folder.exists() else None
        if key is not None and key.is_dir() and key not in seen:
            seen.add(key)
            folders.append(folder)
    return folders


def _answers(folder: Path) -> dict[str, PolicyEntry | None]:
    """The policy names ``folder`` answers: its manifest's entries; for the package's own folder without one, its
    files by name (None: no entry to check against); for any other folder without one, nothing."""
    entries = read_manifest(folder)
    if entries or folder.resolve() != PACKAGE_POLICIES:
        return entries
    return {p.stem: None for p in folder.glob("*.safetensors")}


def find_policy(name: str) -> Path | None:
    """The file of the policy called ``name`` (with or without .safetensors), or None if no folder has it.

    A folder with a manifest answers through it, and its file must match the entry's sha256 (PolicyIndexError
    otherwise); the package's folder answers by file name."""
    name = name[: -len(".safetensors")] if name.endswith(".safetensors") else name
    for folder in policy_folders():
        answers = _answers(folder)
        if name in answers:
            entry = answers[name]
            return folder / f"{name}.safetensors" if entry is None else _checked(folder, entry)
    return None


def _checked(folder: Path, entry: PolicyEntry) -> Path:
    path = Path(folder) / entry.file
    if not path.is_file():
        raise PolicyIndexError(f"policy {entry.name!r} is listed in {Path(folder) / MANIFEST} but {path} is missing; "
                               f"restore it (git checkout {path}) or promote it again (safemanip bench promote)")
    size = path.stat().st_size
    if size != entry.bytes or file_sha256(path) != entry.sha256:
        raise PolicyIndexError(f"{path} does not match its manifest entry ({size} bytes against {entry.bytes}, or a "
                               f"different sha256): the file was changed after it was promoted; restore it "
                               f"(git checkout {path}) or promote it again (safemanip bench promote)")
    return path


def known_policies() -> list[str]:
    """Every policy name ``find_policy`` answers, for error messages."""
    return sorted({name for folder in policy_folders() for name in _answers(folder)})

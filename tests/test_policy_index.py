"""The benchmark's policies live outside the package (results/policies, with a manifest); the package ships the demo
policy only, and its wheel stays small (issue 43)."""

import json
import shutil
import subprocess
import sys
import zipfile

import pytest

from conftest import ROOT, run_cli
from safemanip.rl.policy_index import (ENV_VAR, MANIFEST, PACKAGE_POLICIES, PolicyIndexError, file_sha256,
                                       find_policy, known_policies, read_manifest)

BENCHMARK = ROOT / "results" / "policies"
MAX_WHEEL_BYTES = 5_000_000


def test_the_manifest_lists_every_benchmark_policy_and_each_file_matches_it():
    entries = read_manifest(BENCHMARK)
    files = {p.name for p in BENCHMARK.glob("*.safetensors")}
    assert len(entries) == 54 and {e.file for e in entries.values()} == files
    for name, entry in entries.items():
        path = BENCHMARK / entry.file
        assert file_sha256(path) == entry.sha256 and path.stat().st_size == entry.bytes
        assert (BENCHMARK / entry.record / "choice.json").is_file(), f"{name}: no training record"
        assert name.startswith(f"{entry.algorithm}-k{entry.k}-{entry.constraints}")
        assert find_policy(name).resolve() == path.resolve()


def test_the_package_ships_only_the_demo_policy():
    from safemanip.demo import DEFAULT_POLICY

    assert [p.stem for p in PACKAGE_POLICIES.glob("*.safetensors")] == [DEFAULT_POLICY]


def test_a_policy_changed_after_promotion_is_refused_with_the_fix(tmp_path, monkeypatch, capsys):
    folder = tmp_path / "policies"
    shutil.copytree(BENCHMARK, folder)
    monkeypatch.setenv(ENV_VAR, str(folder))
    name = "vanilla-k3-conservative-s2"
    data = bytearray((folder / f"{name}.safetensors").read_bytes())
    data[-1] ^= 0xFF  # one weight's last byte: still a loadable file, but not the promoted one
    (folder / f"{name}.safetensors").write_bytes(bytes(data))
    code, out, err = run_cli(capsys, ["eval", "--policy", name, "--episodes", "1", "--out", str(tmp_path / "o")])
    assert code == 2 and "does not match its manifest entry" in err and "git checkout" in err
    assert not (tmp_path / "o").exists()
    (folder / f"{name}.safetensors").unlink()
    with pytest.raises(PolicyIndexError, match="is missing; restore it"):
        find_policy(name)


@pytest.mark.parametrize("text, message", [
    ("{", "not valid JSON"),
    ('{"format": "other", "policies": []}', "is not a policy manifest"),
    ('{"format": "safemanip-policies/1", "policies": [{"name": "x"}]}', "must have exactly the fields"),
])
def test_a_damaged_manifest_is_refused_with_a_message(tmp_path, monkeypatch, text, message):
    (tmp_path / MANIFEST).write_text(text)
    monkeypatch.setenv(ENV_VAR, str(tmp_path))
    with pytest.raises(PolicyIndexError, match=message):
        find_policy("rarl-k2-conservative-s1")


def test_a_manifest_entry_may_not_point_outside_its_folder(tmp_path, monkeypatch):
    entries = json.loads((BENCHMARK / MANIFEST).read_text())
    entries["policies"][0]["file"] = "../elsewhere.safetensors"
    (tmp_path / MANIFEST).write_text(json.dumps(entries))
    monkeypatch.setenv(ENV_VAR, str(tmp_path))
    with pytest.raises(PolicyIndexError, match="inside the manifest's folder"):
        find_policy(entries["policies"][0]["name"])


def test_names_resolve_from_any_working_folder_and_unknown_names_list_the_known_ones(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)  # the source checkout's results/policies still answers
    assert find_policy("rarl-k5-conservative-selaware-s2") is not None
    assert "rarl-k2-conservative-s0" in known_policies() and len(known_policies()) == 54
    code, _, err = run_cli(capsys, ["eval", "--policy", "rarl-k9-conservative-s0", "--episodes", "1"])
    assert code == 2 and "rarl-k5-conservative-selaware-s2" in err and "results/policies" in err


@pytest.mark.slow
def test_the_built_wheel_holds_the_demo_policy_and_is_at_most_5_mb(tmp_path):
    """Built without network (setuptools, a dev dependency, in this environment) from a copy of the project's
    files, so the build's own folders stay out of the checkout."""
    source = tmp_path / "source"
    shutil.copytree(ROOT / "src", source / "src", ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(ROOT / name, source / name)
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w",
                    str(tmp_path / "wheel"), str(source)], check=True, capture_output=True, timeout=600)
    (wheel,) = (tmp_path / "wheel").glob("safemanip-*.whl")
    assert wheel.stat().st_size <= MAX_WHEEL_BYTES
    names = zipfile.ZipFile(wheel).namelist()
    assert [n for n in names if n.endswith(".safetensors")] == ["safemanip/policies/rarl-k2-conservative-s0.safetensors"]
    assert "safemanip/bench/benchmark.json" in names

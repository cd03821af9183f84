"""The held-out name lists measure generalisation: v2 and v3 share no word with any example name, v4 no head noun."""

from __future__ import annotations

import json
import re
from importlib import resources

DATA = resources.files("safemanip.semantics").joinpath("data")


def words(name: str) -> set[str]:
    """Lower-case words of a name and their naive singulars (so 'mugs' and 'mug' count as one word)."""
    out = set()
    for w in re.findall(r"[a-z]+", name.lower()):
        out |= {w, re.sub(r"(es|s)$", "", w)}
    return out


def example_words(up_to_version: int | None = None) -> set[str]:
    vocab: set[str] = set()
    for path in DATA.iterdir():
        if path.name.startswith("class_examples_v") and path.name.endswith(".json"):
            if up_to_version is not None and int(path.name[len("class_examples_v"):-len(".json")]) > up_to_version:
                continue
            for names in json.loads(path.read_text())["classes"].values():
                for n in names:
                    vocab |= words(n)
    return vocab


def heldout_v2() -> dict[str, list[str]]:
    return json.loads(DATA.joinpath("heldout_names_v2.json").read_text())["classes"]


def heldout_v3() -> dict[str, list[str]]:
    return json.loads(DATA.joinpath("heldout_names_v3.json").read_text())["classes"]


def test_heldout_v3_shares_no_word_with_any_example_name_nor_with_heldout_v2():
    """v2 has been measured on, so it may become example data; v3 must be new to both."""
    vocab = example_words()
    for names in heldout_v2().values():
        for n in names:
            vocab |= words(n)
    shared = {n: sorted(words(n) & vocab) for names in heldout_v3().values() for n in names if words(n) & vocab}
    assert not shared, f"held-out v3 names sharing a word with an example or held-out v2 name: {shared}"
    held = heldout_v3()
    assert len(held["fragile"]) >= 50 and min(len(v) for v in held.values()) >= 30
    all_names = [n for v in held.values() for n in v]
    assert len(all_names) == len(set(all_names))


def test_heldout_v2_shares_no_word_with_any_example_name_up_to_v4():
    """v2 was the test for v3 and v4; v5 took its names as examples once it had been measured on."""
    vocab = example_words(up_to_version=4)
    assert len(vocab) > 200
    shared = {n: sorted(words(n) & vocab) for names in heldout_v2().values() for n in names if words(n) & vocab}
    assert not shared, f"held-out names sharing a word with an example name: {shared}"


def test_heldout_v2_is_big_enough_for_a_two_percent_unsafe_rate():
    held = heldout_v2()
    assert len(held["fragile"]) >= 50 and min(len(v) for v in held.values()) >= 30
    all_names = [n for v in held.values() for n in v]
    assert len(all_names) == len(set(all_names))


def heldout_v4() -> dict[str, list[str]]:
    return json.loads(DATA.joinpath("heldout_names_v4.json").read_text())["classes"]


def head_noun(name: str) -> str:
    word = name.lower().split()[-1]
    return word[:-1] if word.endswith("s") and not word.endswith("ss") else word


def test_heldout_v4_is_new_big_and_shares_no_head_noun_with_an_example():
    """Issue 41: at least 150 names, none a catalog, example or earlier held-out name, none sharing its head noun
    with an example name (a name the classifier could match by its last word)."""
    from safemanip.scene.catalog import load_catalog

    held = heldout_v4()
    names = [n for v in held.values() for n in v]
    assert len(names) >= 150 and len(held["fragile"]) >= 50 and len(names) == len(set(names))
    examples = [n for path in DATA.iterdir() if path.name.startswith("class_examples_v")
                for v in json.loads(path.read_text())["classes"].values() for n in v]
    earlier = [n for version in (1, 2, 3) for v in json.loads(DATA.joinpath(f"heldout_names_v{version}.json")
                                                              .read_text())["classes"].values() for n in v]
    taken = {n.lower() for n in examples + earlier + list(load_catalog())}
    assert not [n for n in names if n.lower() in taken]
    heads = {head_noun(n) for n in examples}
    assert not [n for n in names if head_noun(n) in heads]


def test_measured_figures_on_heldout_lists_and_the_catalog():
    """The figures in the README, measured once (each name classified alone; deterministic). No classifier meets
    issue 11's targets (unsafe-error rate <= 2 %, balanced accuracy >= 0.85) on a held-out list: v3 and v4 on
    held-out v2, and v3, v4, v5 on held-out v3 (v5 took held-out v2's names as examples)."""
    from safemanip.semantics.commands import name_confusion
    from safemanip.semantics.semantic_backend import SemanticBackend

    expected = {("v3", "heldout-v2"): (6, 0.790), ("v4", "heldout-v2"): (5, 0.811),
                ("v3", "heldout-v3"): (13, 0.628), ("v4", "heldout-v3"): (10, 0.640), ("v5", "heldout-v3"): (4, 0.613),
                ("v3", "catalog"): (0, 0.861), ("v4", "catalog"): (1, 0.831), ("v5", "catalog"): (0, 0.750),
                # issue 41: v6 (v3 + material cues) on the list written before it, measured once
                ("v3", "heldout-v4"): (7, 0.715), ("v6", "heldout-v4"): (7, 0.706), ("v6", "heldout-v3"): (13, 0.628),
                ("v6", "heldout-v2"): (6, 0.790), ("v6", "catalog"): (0, 0.917)}
    sizes = {"catalog": 35, "heldout-v2": 115, "heldout-v3": 115, "heldout-v4": 160}
    for version in ("v3", "v4", "v5", "v6"):
        backend = SemanticBackend(examples_file=version)
        for objects in ("heldout-v2", "heldout-v3", "heldout-v4", "catalog"):
            if (version, objects) not in expected:
                continue
            r = name_confusion(backend, objects)
            unsafe, bal = expected[(version, objects)]
            assert r["names"] == sizes[objects]
            assert sum(r["counts"]["no_contact"].values()) - r["counts"]["no_contact"]["no_contact"] == unsafe, r["wrong"]
            assert abs(r["balanced_accuracy"] - bal) < 0.0015, r

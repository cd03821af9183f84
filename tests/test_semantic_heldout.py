"""The held-out name list v2 measures generalisation: it shares no word with any example name."""

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


def example_words() -> set[str]:
    vocab: set[str] = set()
    for path in DATA.iterdir():
        if path.name.startswith("class_examples_v") and path.name.endswith(".json"):
            for names in json.loads(path.read_text())["classes"].values():
                for n in names:
                    vocab |= words(n)
    return vocab


def heldout_v2() -> dict[str, list[str]]:
    return json.loads(DATA.joinpath("heldout_names_v2.json").read_text())["classes"]


def test_heldout_v2_shares_no_word_with_any_example_name():
    vocab = example_words()
    assert len(vocab) > 200
    shared = {n: sorted(words(n) & vocab) for names in heldout_v2().values() for n in names if words(n) & vocab}
    assert not shared, f"held-out names sharing a word with an example name: {shared}"


def test_heldout_v2_is_big_enough_for_a_two_percent_unsafe_rate():
    held = heldout_v2()
    assert len(held["fragile"]) >= 50 and min(len(v) for v in held.values()) >= 30
    all_names = [n for v in held.values() for n in v]
    assert len(all_names) == len(set(all_names))

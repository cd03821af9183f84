"""Seed-level intervals (evaluation.stats): a two-stage cluster bootstrap over training seeds, beside the Wilson
interval of all episodes pooled, which treats 3 x 1000 episodes as independent."""

from __future__ import annotations

import pytest

from safemanip.evaluation.stats import seed_bootstrap_difference, seed_bootstrap_interval, wilson_interval

N = 1000


def width(interval):
    return interval[1] - interval[0]


def test_seed_level_interval_is_wider_than_the_pooled_wilson_one_when_seeds_disagree():
    counts = [650, 800, 720]  # 15 points between the worst and the best seed, as on exit scenes
    seeds = seed_bootstrap_interval(counts, [N] * 3)
    pooled = wilson_interval(sum(counts), 3 * N)
    assert width(seeds) > 3 * width(pooled)
    assert seeds[0] < pooled[0] and seeds[1] > pooled[1]
    assert seeds[0] < 0.67 and seeds[1] > 0.78  # about the seeds' own range


def test_seed_level_interval_is_close_to_the_pooled_wilson_one_when_seeds_agree():
    counts = [820, 820, 820]
    seeds = seed_bootstrap_interval(counts, [N] * 3)
    pooled = wilson_interval(sum(counts), 3 * N)
    assert seeds[0] == pytest.approx(pooled[0], abs=0.004) and seeds[1] == pytest.approx(pooled[1], abs=0.004)
    assert 0.8 < width(seeds) / width(pooled) < 1.2


def test_seed_level_intervals_are_deterministic():
    counts = [300, 450, 410]
    assert seed_bootstrap_interval(counts, [N] * 3) == seed_bootstrap_interval(counts, [N] * 3)
    assert seed_bootstrap_difference(counts, [N] * 3, [400] * 3, [N] * 3) == \
        seed_bootstrap_difference(counts, [N] * 3, [400] * 3, [N] * 3)
    assert seed_bootstrap_interval(counts, [N] * 3, seed=1) != seed_bootstrap_interval(counts, [N] * 3)


def test_difference_interval():
    agree_high, agree_low = [825] * 3, [800] * 3
    lo, hi = seed_bootstrap_difference(agree_high, [N] * 3, agree_low, [N] * 3)
    assert 0 < lo < 0.025 < hi  # separated, though the two pooled Wilson intervals overlap
    assert wilson_interval(sum(agree_high), 3 * N)[0] < wilson_interval(sum(agree_low), 3 * N)[1]
    lo, hi = seed_bootstrap_difference([800, 800, 860], [N] * 3, [790] * 3, [N] * 3)
    assert lo < 0 < hi  # two of three seeds barely above: not separated, though the pooled Wilson intervals are
    assert wilson_interval(2460, 3 * N)[0] > wilson_interval(2370, 3 * N)[1]
    lo, hi = seed_bootstrap_difference([800] * 3, [N] * 3, [825] * 3, [N] * 3)
    assert hi < 0


def test_bad_counts_are_refused():
    with pytest.raises(ValueError):
        seed_bootstrap_interval([10, 20], [N])
    with pytest.raises(ValueError):
        seed_bootstrap_interval([1200], [N])
    with pytest.raises(ValueError):
        seed_bootstrap_interval([], [])

"""The rule that judges the benchmark: one method against another in one cell (``compare``), and a finding from its
comparisons (``verdict``). docs/results.md explains it ("How a verdict is reached").

A comparison pools each method's training seeds (``evaluation.sweep.pooling.pool_seeds``). One method is better only
if both tests agree: the 95 % interval of the difference of the two success rates, bootstrapped with training seeds as
the unit, lies wholly above 0, and its lowest training seed scores at least the other's highest; otherwise the cell is
a tie. (Until issue 44 the first test was "its pooled Wilson interval lies wholly above the other's"; the rule changed
after the cells were measured, see docs/results.md.) A finding holds if its method wins at least one of its
comparisons and loses none; it is within the interval if every comparison is a tie; it does not hold if the method
loses at least one and wins none; mixed otherwise.
"""

from __future__ import annotations

from safemanip.evaluation.stats import seed_bootstrap_difference


def entry(r: dict, key: str = "success") -> dict:
    """A stored result's rate entry: success, safety_violation or one failure category."""
    return r["summary"][key] if key in ("success", "safety_violation") else r["summary"]["categories"][key]


def seeds(r: dict) -> int:
    """Training seeds pooled in a result (a result of one policy is one seed)."""
    return len(r["summary"].get("seeds", [0]))


def per_seed(r: dict, key: str = "success") -> tuple[list[int], list[int]]:
    """(successes, episodes) of each training seed of ``r`` on ``key``; a result of one policy is one seed."""
    e = entry(r, key)
    if "seed_counts" in e:
        return list(e["seed_counts"]), list(e["seed_totals"])
    return [int(e["count"])], [int(r["summary"]["episodes"])]


def difference(a: dict, b: dict, key: str = "success") -> tuple[float, float]:
    """95 % interval of ``a``'s rate minus ``b``'s on ``key``, training seeds as the unit (two-stage cluster
    bootstrap of each method, fixed RNG seed: ``stats.seed_bootstrap_difference``)."""
    return seed_bootstrap_difference(*per_seed(a, key), *per_seed(b, key))


def compare(a: dict, b: dict, key: str = "success", lower_is_better: bool = False) -> str:
    """'win', 'tie' or 'loss' of ``a`` against ``b`` on ``key``.

    ``a`` wins only if two tests agree: (1) the 95 % interval of the difference of the two rates, bootstrapped with
    training seeds as the unit (resample each method's seeds, then each seed's episodes from its own rate;
    ``difference``), lies wholly above 0 (below 0 when ``lower_is_better``), and (2) ``a``'s worst training seed
    scores at least ``b``'s best. 'loss' is the same with the roles swapped; anything else is a tie.

    Why the bootstrap: a method's seeds are three different policies that spread up to 12 points (34 on gate
    scenes), so the Wilson interval of 3 x 1000 pooled episodes, which counts every episode as independent,
    understates the uncertainty; and the interval of the difference, not two separate intervals, is the test of
    "a differs from b". Why the seed test is kept: with three seeds the percentile bootstrap is optimistic (it sees
    only 10 distinct seed sets and underestimates the between-seed variance by a third, where a t interval on 2
    degrees of freedom would be more than twice as wide as a normal one); the seed test is distribution-free, and
    with 3 seeds against 3 it is the exact one-sided rank test at its smallest attainable level (1 ordering in
    C(6, 3) = 20, p = 0.05). The bootstrap keeps seeds separated by less than the episodes' noise from deciding a
    cell, the seed test one lucky or unlucky seed. On the stored cells the seed test still decides two: RARL
    against Vanilla at N = 1 (Fig. 4) and dynamic against static kNN for pi_3 at N = 4 (Fig. 5), where the
    bootstrapped difference is above 0 but a seed of the other method beats a seed of the first."""
    lo, hi = difference(a, b, key)
    (a_lo, a_hi), (b_lo, b_hi) = (entry(r, key).get("spread", [entry(r, key)["rate"]] * 2) for r in (a, b))
    if lower_is_better:
        lo, hi = -hi, -lo
        (a_lo, a_hi), (b_lo, b_hi) = (-a_hi, -a_lo), (-b_hi, -b_lo)
    if lo > 0 and a_lo >= b_hi:
        return "win"
    if hi < 0 and b_lo >= a_hi:
        return "loss"
    return "tie"


def verdict(outcomes: list[str], complete: bool, needed: int, missing: tuple[int, int] = (0, 0)) -> str:
    """A finding's verdict from its comparisons' outcomes. ``complete``: every compared result pools ``needed``
    training seeds (the benchmark's); ``missing``: (cells not measured yet, cells in all) of the finding's sweep."""
    if not outcomes:
        return "not measured yet"
    wins, losses = outcomes.count("win"), outcomes.count("loss")
    text = ("holds" if wins and not losses else "within the interval" if not wins and not losses
            else "does not hold" if losses and not wins else "mixed")
    text += f" ({wins} better, {outcomes.count('tie')} tied, {losses} worse)"
    if not complete:
        text += f"; fewer than {needed} training seeds so far"
    if missing[0]:
        text += f"; provisional, {missing[1] - missing[0]} of its {missing[1]} cells measured"
    return text

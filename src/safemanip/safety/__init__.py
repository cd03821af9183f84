"""Safety filters that wrap any policy at deployment (issue 45), by name: ``SHIELDS``.

``brake`` (``braking.BrakingShield``): a least-restrictive braking-envelope check; the policy acts while the held box
can still stop short of every protected object, and the filter brakes otherwise. docs/safety.md says what it
guarantees and what it does not.
"""

from __future__ import annotations

from safemanip.safety.braking import BrakingShield

SHIELDS = {"brake": BrakingShield}
"""Filters by name: the closed set a flag or a sweep spec may name."""


def make_shield(name: str):
    if name not in SHIELDS:
        raise ValueError(f"unknown safety filter {name!r}; choose one of {sorted(SHIELDS)}")
    return SHIELDS[name]()

"""The reach-avoid backup in closed form, and the vanilla target, on small tensors."""

import torch

from safemanip.rl.backup import discounted_return_target, reach_avoid_target


def t(*values):
    return torch.tensor(values, dtype=torch.float32)


def test_non_terminal_matches_closed_form():
    l, g, v = t(-0.5, 0.2, -0.1), t(0.3, 0.1, -0.4), t(0.05, -0.2, 0.9)
    gamma = 0.9
    y = reach_avoid_target(l, g, v, torch.tensor([False] * 3), t(9, 9, 9), t(9, 9, 9), gamma)
    # (1-γ)min(l,g) + γ min(g, max(l, V'))
    expected = [0.1 * -0.5 + 0.9 * min(0.3, max(-0.5, 0.05)),
                0.1 * 0.1 + 0.9 * min(0.1, max(0.2, -0.2)),
                0.1 * -0.4 + 0.9 * min(-0.4, max(-0.1, 0.9))]
    assert torch.allclose(y, t(*expected))


def test_failed_state_caps_the_value_at_g():
    # whatever the future promises, a state inside the failure set is worth g(s)
    y = reach_avoid_target(t(0.5), t(-0.2), t(10.0), torch.tensor([False]), t(0.0), t(0.0), 0.99)
    assert torch.allclose(y, t(-0.2))


def test_terminal_uses_the_absorbing_value_of_the_next_state():
    l, g = t(-0.3, -0.3), t(0.2, 0.2)
    next_l, next_g = t(0.1, 0.4), t(0.5, -0.05)  # success, then failure at s'
    bogus_bootstrap = t(100.0, 100.0)  # must be ignored for terminated transitions
    gamma = 0.95
    y = reach_avoid_target(l, g, bogus_bootstrap, torch.tensor([True, True]), next_l, next_g, gamma)
    expected = [0.05 * -0.3 + 0.95 * min(0.2, max(-0.3, min(0.1, 0.5))),
                0.05 * -0.3 + 0.95 * min(0.2, max(-0.3, min(0.4, -0.05)))]
    assert torch.allclose(y, t(*expected))
    assert y[0] > 0 > y[1]


def test_truncated_transition_keeps_bootstrapping():
    # a time-limit truncation is stored with terminated=False: the bootstrap is used, not min(l', g')
    l, g, v = t(-0.2), t(0.3), t(0.25)
    y = reach_avoid_target(l, g, v, torch.tensor([False]), t(-0.9), t(-0.9), 0.99)
    assert torch.allclose(y, t(0.01 * -0.2 + 0.99 * 0.25))


def test_fixed_point_of_a_reached_safe_state_is_its_margin():
    # a state with l > 0 and g > l is worth at least l: V = min(g, max(l, V)) has V >= l
    l, g = t(0.1), t(0.5)
    v = t(0.0)
    for _ in range(2000):
        v = reach_avoid_target(l, g, v, torch.tensor([False]), t(0), t(0), 0.99)
    assert torch.allclose(v, t(0.1), atol=1e-4)


def test_vanilla_target():
    r, v, r_next = t(-0.1, -0.2), t(1.0, 1.0), t(-0.5, -0.5)
    y = discounted_return_target(r, v, torch.tensor([False, True]), r_next, 0.9)
    # continuing: r + gamma Q'; terminated: s' absorbing, r(s') for ever = -0.5 / (1 - 0.9) = -5
    assert torch.allclose(y, t(-0.1 + 0.9, -0.2 + 0.9 * -5.0))


def test_vanilla_target_makes_failing_early_worse_than_reaching_the_goal():
    """The loophole the absorbing rule closes: with r = min(l, g) < 0 until success, a failure that simply
    ended the episode (V' = 0) beat every slower success. Exact values of two deterministic paths, by
    backing the targets up from their ends."""
    gamma = 0.98

    def path_value(rewards, terminal_reward):
        value = None
        for i in reversed(range(len(rewards))):
            nxt = torch.tensor([0.0]) if value is None else value
            last = value is None
            value = discounted_return_target(torch.tensor([rewards[i]]), nxt, torch.tensor([last]),
                                             torch.tensor([terminal_reward]), gamma)
        return float(value)

    fail_now = path_value([-0.5], terminal_reward=-0.5)  # the top box knocked over far from the goal
    succeed = path_value([-0.5 + 0.025 * i for i in range(20)], terminal_reward=0.03)  # 20 steps to a placed box
    assert succeed > fail_now
    # the textbook target (V' = 0 at the end) prefers the failure: what the old baseline learnt
    textbook_fail = -0.5
    textbook_succeed = sum(gamma ** i * (-0.5 + 0.025 * i) for i in range(20))
    assert textbook_fail > textbook_succeed

"""The learner's pieces on small fixed tensors: fused twin critics, the twin-minimum target, the policy
delay, Polyak averaging, bf16 against fp32, the replay buffer, and the object-set network."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from safemanip.env.observation import ROBOT_DIM, SLOT_DIM, observation_dim
from safemanip.rl.buffer import FIELDS, ReplayBuffer
from safemanip.rl.config import ConfigError, TrainConfig
from safemanip.rl.learner import Learner, polyak_update
from safemanip.rl.networks import Critic, SetActor, SetCritic, actor_arrays, mlp
from safemanip.rl.numpy_actor import NumpyActor, NumpySetActor, make_numpy_actor
from safemanip.rl.precision import Precision, resolve_precision

OBS, ACT = observation_dim(2), 3
SMALL = {"hidden": (32, 32), "batch_size": 16, "learning_starts": 16, "device": "cpu", "precision": "fp32"}


def batch(n: int = 16, obs_dim: int = OBS, seed: int = 0):
    rng = np.random.default_rng(seed)
    buf = ReplayBuffer(n, obs_dim, ACT)
    buf.add_many(transitions(n, obs_dim, rng))
    return buf.sample(n, rng)


def transitions(n: int, obs_dim: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    return {"obs": rng.normal(size=(n, obs_dim)).astype(np.float32), "act": rng.uniform(-1, 1, (n, ACT)).astype(np.float32),
            "next_obs": rng.normal(size=(n, obs_dim)).astype(np.float32),
            **{k: rng.normal(0, 0.3, size=n).astype(np.float32) for k in ("l", "g", "next_l", "next_g")},
            "terminated": rng.random(n) < 0.2}


def params(module) -> list[torch.Tensor]:
    return [p.detach().clone() for p in module.parameters()]


def same(a, b) -> bool:
    return all(torch.equal(x, y) for x, y in zip(a, b))


# ------------------------------------------------------------------------------------------ critics
def test_fused_twin_critic_equals_two_separate_mlps():
    torch.manual_seed(0)
    critic = Critic(OBS, ACT, (32, 32), n_heads=2)
    seps = [mlp([OBS + ACT, 32, 32, 1]) for _ in range(2)]
    for h, sep in enumerate(seps):  # copy head h's stacked weights into a plain nn.Sequential
        linears = [m for m in sep if isinstance(m, torch.nn.Linear)]
        for lin, w, b in zip(linears, critic.q.weights, critic.q.biases):
            lin.weight.data.copy_(w[h].T)
            lin.bias.data.copy_(b[h, 0])
    o, a = torch.randn(7, OBS), torch.rand(7, ACT) * 2 - 1
    qs = critic(o, a)
    assert qs.shape == (2, 7)
    for h, sep in enumerate(seps):
        torch.testing.assert_close(qs[h], sep(torch.cat([o, a], -1)).squeeze(-1), atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(critic(o, a, head=0)[0], qs[0])


def test_critic_loads_the_older_one_module_per_head_state():
    torch.manual_seed(1)
    seps = [mlp([OBS + ACT, 32, 32, 1]) for _ in range(2)]
    old = {f"heads.{h}.{k}": v for h, sep in enumerate(seps) for k, v in sep.state_dict().items()}
    critic = Critic(OBS, ACT, (32, 32), n_heads=2)
    critic.load_state_dict(old)
    o, a = torch.randn(5, OBS), torch.randn(5, ACT)
    for h, sep in enumerate(seps):
        torch.testing.assert_close(critic(o, a)[h], sep(torch.cat([o, a], -1)).squeeze(-1), atol=1e-5, rtol=1e-5)


def test_target_bootstraps_from_the_minimum_of_the_twin_heads():
    torch.manual_seed(2)
    learner = Learner(OBS, ACT, TrainConfig(**SMALL, algorithm="vanilla", target_noise=0.0))
    with torch.no_grad():  # target head 1 := target head 0 + 5, so the minimum is head 0 everywhere
        for w, b in zip(learner.critic_targ.q.weights, learner.critic_targ.q.biases):
            w[1].copy_(w[0])
            b[1].copy_(b[0])
        learner.critic_targ.q.biases[-1][1] += 5.0
    b = batch()
    with torch.no_grad():
        next_a = learner.actor_targ(b.next_obs)
        q0, q1 = learner.critic_targ(b.next_obs, next_a)
    torch.testing.assert_close(q1, q0 + 5.0)
    y = learner.target(b, gamma=0.9)
    absorbing = torch.minimum(b.next_l, b.next_g) / (1 - 0.9)  # a terminated s' pays its reward for ever
    expected = torch.minimum(b.l, b.g) + 0.9 * torch.where(b.terminated, absorbing, q0)  # the smaller head
    torch.testing.assert_close(y, expected)


def test_actor_and_targets_move_only_every_policy_delay_updates():
    torch.manual_seed(3)
    learner = Learner(OBS, ACT, TrainConfig(**SMALL, policy_delay=3))
    b = batch()
    actor0, targ0, critic0 = params(learner.actor), params(learner.critic_targ), params(learner.critic)
    for i in (1, 2):
        metrics = learner.update(b, 0.99)
        assert "loss/actor" not in metrics
        assert same(params(learner.actor), actor0) and same(params(learner.critic_targ), targ0)
        assert not same(params(learner.critic), critic0)  # the critic learns every update
    metrics = learner.update(b, 0.99)
    assert "loss/actor" in metrics
    assert not same(params(learner.actor), actor0) and not same(params(learner.critic_targ), targ0)


def test_an_update_flushes_denormals_and_leaves_ieee_arithmetic_behind():
    """Inside an update denormal floats are zero (the Adam moments of dead units decay through that range, where the
    fused step ran 7x slower); after it, and so in the physics elsewhere in the process, they are kept."""
    learner = Learner(OBS, ACT, TrainConfig(**SMALL))
    tiny = torch.tensor([1e-40], dtype=torch.float32)  # a float32 denormal
    seen = []
    inner = learner._update

    def watched(b, gamma):
        seen.append(float(tiny * 1.0))
        return inner(b, gamma)

    learner._update = watched
    learner.update(batch(), 0.99)
    assert seen == [0.0]  # flushed during the update
    assert float(tiny * 1.0) > 0.0  # and not after it


def test_a_saturated_actor_is_reported():
    torch.manual_seed(3)
    learner = Learner(OBS, ACT, TrainConfig(**SMALL, policy_delay=1))
    healthy = learner.update(batch(), 0.99)["actor/saturated"]
    assert 0.0 <= healthy < 0.5  # a fresh actor's outputs sit well inside (-1, 1)
    with torch.no_grad():
        learner.actor.net[-1].bias.fill_(50.0)  # every pre-activation far past tanh's knee
    assert learner.update(batch(), 0.99)["actor/saturated"] == 1.0


def test_the_preactivation_penalty_adds_its_term_and_pulls_a_saturated_actor_back():
    b = batch()
    losses = {}
    for weight in (0.0, 0.5):
        torch.manual_seed(4)
        learner = Learner(OBS, ACT, TrainConfig(**SMALL, policy_delay=1, actor_preactivation_penalty=weight))
        with torch.no_grad():
            before = learner.actor.pre_tanh(b.obs).pow(2).mean().item()
        losses[weight] = learner.update(b, 0.99)["loss/actor"]
    # the same networks and batch: the critic step is the same, the actor loss differs by the penalty alone
    assert losses[0.5] - losses[0.0] == pytest.approx(0.5 * before, rel=1e-4)

    torch.manual_seed(3)
    learner = Learner(OBS, ACT, TrainConfig(**SMALL, policy_delay=1, actor_preactivation_penalty=1.0))
    with torch.no_grad():
        learner.actor.net[-1].bias.fill_(3.0)  # tanh(3) > 0.99: every action component saturated
    assert learner.update(b, 0.99)["actor/saturated"] == 1.0
    for _ in range(150):
        saturated = learner.update(b, 0.99)["actor/saturated"]
    assert saturated < 0.5, "the penalty should bring the pre-activations back below tanh's knee"
    with pytest.raises(ConfigError, match="actor_preactivation_penalty"):
        TrainConfig(**SMALL, actor_preactivation_penalty=-1.0).validate()


def test_learning_rate_schedule_is_a_cosine_from_the_rate_to_the_final_one_and_reaches_the_optimisers():
    constant = TrainConfig(**SMALL)
    assert constant.learning_rate_at(0.0) == constant.learning_rate_at(0.7) == constant.learning_rate
    cfg = TrainConfig(**SMALL, learning_rate=1e-3, learning_rate_final=1e-4)
    assert cfg.learning_rate_at(0.0) == pytest.approx(1e-3) and cfg.learning_rate_at(1.0) == pytest.approx(1e-4)
    assert cfg.learning_rate_at(0.5) == pytest.approx(5.5e-4) and cfg.learning_rate_at(2.0) == pytest.approx(1e-4)
    rates = [cfg.learning_rate_at(p / 10) for p in range(11)]
    assert all(a > b for a, b in zip(rates, rates[1:]))
    # a step taken at a tenth of the rate moves the weights by about a tenth as much (Adam's first steps are
    # the rate times the gradient's sign)
    moves = []
    for lr in (1e-3, 1e-4):
        torch.manual_seed(0)
        learner = Learner(OBS, ACT, cfg)
        learner.set_learning_rate(lr)
        before = params(learner.critic)
        learner.update(batch(), 0.99)
        moves.append(max(float((a - b).abs().max()) for a, b in zip(params(learner.critic), before)))
    assert moves[1] == pytest.approx(moves[0] / 10, rel=0.05)
    with pytest.raises(ConfigError, match="learning_rate_final"):
        TrainConfig(**SMALL, learning_rate_final=0.01)


def test_polyak_update_in_closed_form():
    online = [torch.tensor([1.0, 2.0]), torch.tensor([[3.0]])]
    target = [torch.tensor([0.0, 0.0]), torch.tensor([[1.0]])]
    polyak_update(online, target, 0.9)
    torch.testing.assert_close(target[0], torch.tensor([0.1, 0.2]))
    torch.testing.assert_close(target[1], torch.tensor([[1.2]]))
    assert torch.equal(online[0], torch.tensor([1.0, 2.0]))  # the online side is untouched


# ------------------------------------------------------------------------------------------ precision
BF16_TARGET_TOL = 0.005
"""|y_bf16 - y_fp32| bound on the Bellman target. bf16 keeps 8 mantissa bits (relative rounding 2^-9 per
operation); through a 2-layer critic on values of order 0.2 the measured gap is 2-4e-4 (most entries are
equal: the margins, kept in fp32, decide them). 0.005 leaves a 10x margin and still fails a wrong target
(e.g. the larger twin head, or a bf16 bootstrap mixed into the fp32 margins without the min/max)."""


@pytest.mark.parametrize("network", ["mlp", "set"])
def test_bf16_and_fp32_give_the_same_target_on_a_fixed_batch(network):
    torch.manual_seed(4)
    cfg = TrainConfig(**{**SMALL, "hidden": (64, 64)}, network=network, set_embed=32, target_noise=0.0)
    fp32 = Learner(OBS, ACT, cfg)
    bf16 = Learner(OBS, ACT, cfg, precision=Precision("cpu", "bf16", "test"))
    bf16.load_state_tensors(fp32.state_tensors())
    b = batch(64)
    b = b._replace(obs=slots_present(b.obs), next_obs=slots_present(b.next_obs))
    y32, y16 = fp32.target(b, 0.99), bf16.target(b, 0.99)
    assert y16.dtype == torch.float32  # the target is fp32 whatever the forward precision
    assert (y16 - y32).abs().max().item() < BF16_TARGET_TOL
    # and bf16 really ran in bf16: the critic's raw output differs from fp32 in the low bits
    with bf16.autocast():
        q16 = bf16.critic(b.obs, b.act)
    assert q16.dtype == torch.bfloat16


@pytest.mark.parametrize("network", ["mlp", "set"])
def test_a_saturated_actor_still_learns_in_bf16(network):
    """tanh of a bf16 pre-activation rounds to exactly 1 beyond |x| ~ 3.5, where its gradient is then exactly 0; an
    actor pinned there never moved again (a bf16 training run sat at zero success for 10 minutes while its fp32
    twin recovered). The squashing runs in fp32, so the actor's weights move in bf16 as they do in fp32."""
    cfg = TrainConfig(**{**SMALL, "hidden": (64, 64)}, network=network, set_embed=32, policy_delay=1)
    moved = {}
    for name in ("fp32", "bf16"):
        torch.manual_seed(5)
        learner = Learner(OBS, ACT, cfg, precision=Precision("cpu", name, "test"))
        with torch.no_grad():  # pin every action component at the bound: pre-activations around 6
            if network == "mlp":
                weight, bias = learner.actor.net[-1].weight, learner.actor.net[-1].bias
            else:
                weight, bias = learner.actor.net.head.weights[-1], learner.actor.net.head.biases[-1]
            weight.mul_(0.01)
            bias.fill_(6.0)
        b = batch(64)
        b = b._replace(obs=slots_present(b.obs), next_obs=slots_present(b.next_obs))
        before = params(learner.actor)
        metrics = learner.update(b, 0.99)
        assert metrics["actor/saturated"] == 1.0
        moved[name] = max(float((a - c).abs().max()) for a, c in zip(params(learner.actor), before))
        with learner.autocast():
            assert learner.actor(b.obs).dtype == torch.float32  # the squashing left autocast's bf16
    assert moved["bf16"] > 0.1 * moved["fp32"] > 0, moved


def test_precision_choice_is_explained():
    fp32 = resolve_precision("fp32", torch.device("cpu"))
    assert fp32.dtype == "fp32" and "asked" in fp32.reason
    auto = resolve_precision("auto", torch.device("cpu"))
    assert auto.dtype in ("fp32", "bf16") and auto.reason.startswith("auto:")
    with pytest.raises(ConfigError, match="precision must be"):
        TrainConfig(precision="fp16")


# ------------------------------------------------------------------------------------------ replay buffer
def test_replay_buffer_wraps_around_and_keeps_the_newest():
    buf = ReplayBuffer(5, 4, ACT)
    rng = np.random.default_rng(0)
    first, second = transitions(3, 4, rng), transitions(4, 4, rng)
    buf.add_many(first)
    buf.add_many(second)  # 7 transitions into 5 slots: the 2 oldest are overwritten
    assert (buf.size, buf.pos) == (5, 2)
    np.testing.assert_array_equal(buf.data["obs"][2], first["obs"][2])
    np.testing.assert_array_equal(buf.data["obs"][[3, 4, 0, 1]], second["obs"])
    sample = buf.sample(50, rng)
    stored = {tuple(r) for r in buf.data["obs"]}
    assert all(tuple(r) in stored for r in sample.obs.numpy())
    assert sample.terminated.dtype == torch.bool


def test_replay_buffer_save_and_load_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    buf = ReplayBuffer(6, 4, ACT)
    buf.add_many(transitions(8, 4, rng))
    buf.save(tmp_path / "replay.npz")
    back = ReplayBuffer(6, 4, ACT)
    back.load(tmp_path / "replay.npz")
    assert (back.size, back.pos) == (buf.size, buf.pos)
    for k in FIELDS:
        np.testing.assert_array_equal(back.data[k], buf.data[k])


# ------------------------------------------------------------------------------------------ set network
def slots_present(obs: torch.Tensor, width: int = SLOT_DIM) -> torch.Tensor:
    """Give every slot a valid one-hot (random observations would otherwise have garbage one-hots)."""
    obs = obs.clone()
    n = (obs.shape[1] - ROBOT_DIM) // width
    for s in range(n):
        onehot = torch.zeros(obs.shape[0], 3)
        onehot[torch.arange(obs.shape[0]), torch.randint(0, 3, (obs.shape[0],))] = 1.0
        obs[:, ROBOT_DIM + s * width + 6:ROBOT_DIM + s * width + 9] = onehot
    return obs


def permute_slots(obs: torch.Tensor, order: list[int], width: int = SLOT_DIM) -> torch.Tensor:
    slots = obs[:, ROBOT_DIM:].reshape(obs.shape[0], -1, width)[:, order]
    return torch.cat([obs[:, :ROBOT_DIM], slots.reshape(obs.shape[0], -1)], dim=1)


def pad_slots(obs: torch.Tensor, extra: int, width: int = SLOT_DIM) -> torch.Tensor:
    return torch.cat([obs, torch.zeros(obs.shape[0], extra * width)], dim=1)


def test_set_network_is_invariant_to_slot_order_and_padding():
    torch.manual_seed(5)
    actor, critic = SetActor(ACT, (32, 32), 16), SetCritic(ACT, (32, 32), 16)
    obs = slots_present(torch.randn(6, observation_dim(3)))
    act = torch.rand(6, ACT) * 2 - 1
    with torch.no_grad():
        a, q = actor(obs), critic(obs, act)
        for variant in (permute_slots(obs, [2, 0, 1]), pad_slots(obs, 4), pad_slots(permute_slots(obs, [1, 2, 0]), 1)):
            torch.testing.assert_close(actor(variant), a, atol=1e-6, rtol=1e-5)
            torch.testing.assert_close(critic(variant, act), q, atol=1e-6, rtol=1e-5)
        # but it does see the objects: dropping one slot changes the output
        assert not torch.allclose(actor(obs[:, :observation_dim(2)]), a, atol=1e-4)
        # zero objects (robot part only) is a valid input
        assert actor(obs[:, :ROBOT_DIM]).shape == (6, ACT)


def test_set_network_with_object_sizes_reads_the_radius_and_stays_invariant(tmp_path):
    """With ``object_size`` a slot is 10 wide (the footprint radius last): the set network still ignores slot
    order and zero padding, its NumPy actor agrees with torch, and a policy file round-trips only with the
    metadata that says the slots are sized."""
    from safemanip.rl.checkpoint import PolicyFileError, load_policy, save_policy

    torch.manual_seed(11)
    width = SLOT_DIM + 1
    actor = SetActor(ACT, (32, 32), 16, object_size=True)
    critic = SetCritic(ACT, (32, 32), 16, object_size=True)
    obs = slots_present(torch.randn(6, observation_dim(3, object_size=True)), width)
    obs[:, ROBOT_DIM + width - 1::width] = torch.rand(6, 3) * 0.1  # radii, 0-10 cm
    act = torch.rand(6, ACT) * 2 - 1
    with torch.no_grad():
        a, q = actor(obs), critic(obs, act)
        for variant in (permute_slots(obs, [2, 0, 1], width), pad_slots(obs, 3, width)):
            torch.testing.assert_close(actor(variant), a, atol=1e-6, rtol=1e-5)
            torch.testing.assert_close(critic(variant, act), q, atol=1e-6, rtol=1e-5)
        bigger = obs.clone()
        bigger[:, ROBOT_DIM + width - 1] += 0.05  # the first object grows by 5 cm: the action changes
        assert not torch.allclose(actor(bigger), a, atol=1e-5)
    meta = {"k": 3, "constraints": "conservative", "env_kwargs": {"object_size": True}}
    save_policy(tmp_path / "sized.safetensors", actor_arrays(actor), meta)
    np_actor, _ = load_policy(tmp_path / "sized.safetensors")
    assert np_actor.slot_width == width
    np.testing.assert_allclose(np_actor(pad_slots(obs, 2, width).numpy()), a.numpy(), atol=1e-5)
    save_policy(tmp_path / "unsized.safetensors", actor_arrays(actor), {**meta, "env_kwargs": {}})
    with pytest.raises(PolicyFileError, match="do not chain"):
        load_policy(tmp_path / "unsized.safetensors")


def test_numpy_actor_uses_the_env_observation_layout():
    from safemanip.rl import numpy_actor

    assert (numpy_actor.ROBOT_DIM, numpy_actor.SLOT_DIM) == (ROBOT_DIM, SLOT_DIM)  # kept torch- and env-free there


def test_numpy_set_actor_matches_torch_for_any_number_of_slots():
    torch.manual_seed(6)
    actor = SetActor(ACT, (32, 32), 16)
    np_actor = make_numpy_actor(actor_arrays(actor))
    assert isinstance(np_actor, NumpySetActor)
    for n in (0, 1, 4):
        obs = slots_present(torch.randn(5, observation_dim(n)))
        with torch.no_grad():
            expected = actor(pad_slots(obs, 2)).numpy()
        np.testing.assert_allclose(np_actor(obs.numpy()), expected, atol=1e-5)
        np.testing.assert_allclose(np_actor(obs.numpy()[0]), expected[0], atol=1e-5)  # a single observation
    assert isinstance(make_numpy_actor([np.zeros((3, 4), np.float32), np.zeros(3, np.float32)]), NumpyActor)


def test_learner_updates_the_set_network_on_padded_batches():
    torch.manual_seed(7)
    learner = Learner(OBS, ACT, TrainConfig(**SMALL, network="set", set_embed=16, policy_delay=1))
    b = batch(16, observation_dim(4))
    b = b._replace(obs=slots_present(b.obs), next_obs=slots_present(b.next_obs))
    before = params(learner.actor)
    metrics = learner.update(b, 0.99)
    assert np.isfinite(list(metrics.values())).all() and not same(params(learner.actor), before)


def test_checkpoint_tensors_round_trip_and_older_critic_checkpoints_resume():
    torch.manual_seed(8)
    cfg = TrainConfig(**SMALL)
    learner = Learner(OBS, ACT, cfg)
    b = batch()
    for _ in range(2):
        learner.update(b, 0.99)
    back = Learner(OBS, ACT, cfg)
    back.load_state_tensors(learner.state_tensors())
    for x, y in zip(learner.state_tensors().values(), back.state_tensors().values()):
        assert torch.equal(x, y)
    # the older layout: one nn.Sequential per critic head, optimiser moments per head
    old = {k: v for k, v in learner.state_tensors().items() if not k.startswith(("critic.", "critic_targ.", "critic_opt."))}
    seps = [mlp([OBS + ACT, 32, 32, 1]) for _ in range(2)]
    for prefix in ("critic.", "critic_targ."):
        old.update({f"{prefix}heads.{h}.{k}": v for h, sep in enumerate(seps) for k, v in sep.state_dict().items()})
    old.update({f"critic_opt.{i}.exp_avg": p.detach().clone() for i, p in enumerate(p for s in seps for p in s.parameters())})
    old.update({f"critic_opt.{i}.exp_avg_sq": p.detach().clone() for i, p in enumerate(p for s in seps for p in s.parameters())})
    old.update({f"critic_opt.{i}.step": torch.tensor(2.0) for i in range(12)})
    resumed = Learner(OBS, ACT, cfg)
    resumed.load_state_tensors(old)
    o, a = torch.randn(3, OBS), torch.randn(3, ACT)
    torch.testing.assert_close(resumed.critic(o, a)[1], seps[1](torch.cat([o, a], -1)).squeeze(-1), atol=1e-5, rtol=1e-5)
    resumed.update(b, 0.99)  # the moments started afresh: it trains on


def test_policy_file_records_the_network_and_loads_the_matching_actor(tmp_path):
    from safemanip.rl.checkpoint import load_policy, save_policy

    torch.manual_seed(9)
    set_actor = SetActor(ACT, (32, 32), 16)
    save_policy(tmp_path / "set.safetensors", actor_arrays(set_actor), {"k": 3, "constraints": "conservative"})
    actor, meta = load_policy(tmp_path / "set.safetensors")
    assert isinstance(actor, NumpySetActor) and meta["network"] == "set" and actor.obs_dim is None
    obs = slots_present(torch.randn(4, observation_dim(3)))
    with torch.no_grad():
        np.testing.assert_allclose(actor(obs.numpy()), set_actor(obs).numpy(), atol=1e-5)
    from safemanip.rl.networks import Actor

    flat = Actor(OBS, ACT, (32, 32))
    save_policy(tmp_path / "mlp.safetensors", actor_arrays(flat), {"k": 2})
    actor, meta = load_policy(tmp_path / "mlp.safetensors")
    assert isinstance(actor, NumpyActor) and meta["network"] == "mlp" and actor.obs_dim == OBS


def test_learner_update_equals_a_plain_td3_step_with_separate_critics():
    """Fused critic, fused AdamW and foreach Polyak change the speed, not the maths: four updates of the
    Learner and of a plain loop (two nn.Sequential critics, default AdamW, a Python Polyak loop) from the
    same weights end at the same parameters."""
    torch.manual_seed(10)
    cfg = TrainConfig(**SMALL, target_noise=0.0, policy_delay=2, polyak=0.9)
    learner = Learner(OBS, ACT, cfg)
    actor, actor_t = mlp([OBS, 32, 32, ACT]), mlp([OBS, 32, 32, ACT])
    qs, qs_t = [mlp([OBS + ACT, 32, 32, 1]) for _ in range(2)], [mlp([OBS + ACT, 32, 32, 1]) for _ in range(2)]
    with torch.no_grad():
        for src, dst in ((learner.actor.net, actor), (learner.actor_targ.net, actor_t)):
            for p, q in zip(src.parameters(), dst.parameters()):
                q.copy_(p)
        for stacked, seps in ((learner.critic.q, qs), (learner.critic_targ.q, qs_t)):
            for h, sep in enumerate(seps):
                for lin, w, b in zip([m for m in sep if isinstance(m, torch.nn.Linear)], stacked.weights, stacked.biases):
                    lin.weight.copy_(w[h].T)
                    lin.bias.copy_(b[h, 0])
    opt_a = torch.optim.AdamW(actor.parameters(), lr=cfg.learning_rate)
    opt_c = torch.optim.AdamW([p for q in qs for p in q.parameters()], lr=cfg.learning_rate)
    gamma = 0.95
    for i in range(1, 5):
        b = batch(16, seed=i)
        learner.update(b, gamma)
        with torch.no_grad():  # the reach-avoid target from the smaller target head
            x2 = torch.cat([b.next_obs, torch.tanh(actor_t(b.next_obs))], -1)
            v = torch.minimum(qs_t[0](x2), qs_t[1](x2)).squeeze(-1)
            v = torch.where(b.terminated, torch.minimum(b.next_l, b.next_g), v)
            y = (1 - gamma) * torch.minimum(b.l, b.g) + gamma * torch.minimum(b.g, torch.maximum(b.l, v))
        x = torch.cat([b.obs, b.act], -1)
        loss = sum(((q(x).squeeze(-1) - y) ** 2).mean() for q in qs)
        opt_c.zero_grad()
        loss.backward()
        opt_c.step()
        if i % 2 == 0:
            loss_a = -qs[0](torch.cat([b.obs, torch.tanh(actor(b.obs))], -1)).mean()
            opt_a.zero_grad()
            loss_a.backward()
            opt_a.step()
            with torch.no_grad():
                for net, targ in [(actor, actor_t), *zip(qs, qs_t)]:
                    for p, pt in zip(net.parameters(), targ.parameters()):
                        pt.mul_(cfg.polyak).add_(p, alpha=1 - cfg.polyak)
    for p, q in zip(learner.actor.net.parameters(), actor.parameters()):
        torch.testing.assert_close(p, q, atol=1e-5, rtol=1e-4)
    for stacked, seps in ((learner.critic.q, qs), (learner.critic_targ.q, qs_t)):
        for h, sep in enumerate(seps):
            for lin, w in zip([m for m in sep if isinstance(m, torch.nn.Linear)], stacked.weights):
                torch.testing.assert_close(w[h].T, lin.weight, atol=1e-5, rtol=1e-4)


def test_init_from_takes_a_runs_networks_and_refuses_one_that_does_not_fit(tmp_path):
    """``init_from`` (fine-tuning) loads the source checkpoint's actor, critics and targets, not its optimiser
    moments; a source with another k or network, or no checkpoint, is refused with the reason."""
    from safemanip.rl.checkpoint import write_checkpoint
    from safemanip.rl.train import warm_start
    from safemanip.util.files import atomic_write_text

    torch.manual_seed(12)
    source_cfg = TrainConfig(**SMALL, k=2, env={"object_size": True}, out_dir=str(tmp_path / "source"))
    source = Learner(observation_dim(2, True), ACT, source_cfg)
    b = batch(16, observation_dim(2, True))
    source.update(b, 0.99)
    (tmp_path / "source").mkdir()
    atomic_write_text(tmp_path / "source" / "config.json", source_cfg.to_json())
    write_checkpoint(tmp_path / "source", source.state_tensors(), ReplayBuffer(10, observation_dim(2, True), ACT),
                     {"updates": 1, "env_steps": 16, "elapsed_s": 3.0})

    cfg = TrainConfig(**SMALL, k=2, env={"object_size": True}, scene_objects=4, learning_rate=3e-4,
                      init_from=str(tmp_path / "source"))
    networks, provenance = warm_start(cfg)
    assert provenance == {"run": str(tmp_path / "source"), "env_steps": 16, "updates": 1, "elapsed_s": 3.0}
    assert not any(k.startswith(("actor_opt", "critic_opt")) for k in networks)
    learner = Learner(observation_dim(2, True), ACT, cfg)
    learner.load_state_tensors(networks)
    assert same(params(learner.actor), params(source.actor)) and same(params(learner.critic), params(source.critic))
    assert not learner.critic_opt.state  # fresh moments
    learner.update(b, 0.99)  # and it trains on

    with pytest.raises(ConfigError, match="k is 2 there but 3 here"):
        warm_start(TrainConfig(**SMALL, k=3, env={"object_size": True}, init_from=str(tmp_path / "source")))
    with pytest.raises(ConfigError, match="network is 'mlp' there but 'set' here"):
        warm_start(TrainConfig(**SMALL, k=2, env={"object_size": True}, network="set", init_from=str(tmp_path / "source")))
    with pytest.raises(ConfigError, match="no complete checkpoint"):
        warm_start(TrainConfig(**SMALL, init_from=str(tmp_path / "nowhere")))

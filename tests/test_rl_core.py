"""The Q-network family, the double-Q target, the episodic replay and recurrent state."""
from types import SimpleNamespace

import numpy as np
import pytest

from minid3rqn import autograd as ag
from minid3rqn.nets.qnet import QNet, QNetConfig, VARIANTS
from minid3rqn.rl.agent import Agent, AgentConfig, FrameStacker, double_q_targets
from minid3rqn.rl.replay import EpisodeReplay
from minid3rqn.rl.mirror import MirroredPolicy, mirror_permutation, mirror_q, mirror_windows
from minid3rqn.rl.policies import EnsemblePolicy, QNetPolicy
from minid3rqn.world import ACTIONS

pytestmark = pytest.mark.rl

H, W = 32, 104


def flights(n: int):
    """What a policy's ``reset`` reads of an env of n flights (its number of flights)."""
    return SimpleNamespace(n_envs=n)


def build_qnet(variant: str = "d3rqn", rng=None, **overrides) -> QNet:
    """A Q-net of ``variant`` with ``overrides`` of its config (QNetConfig.for_variant)."""
    return QNet(QNetConfig.for_variant(variant, **overrides), rng=rng)


@pytest.mark.parametrize("variant", sorted(VARIANTS))
@pytest.mark.parametrize("stack", [1, 5])
def test_qnet_shapes(variant, stack):
    net = build_qnet(variant, rng=0, in_channels=stack, width=32)
    obs = np.random.default_rng(0).random((3, 4, stack, H, W)).astype(np.float32)
    q, state = net(obs)
    assert q.shape == (3, 4, 5)
    if VARIANTS[variant]["recurrent"]:
        assert state[0].shape == (4, 32) and state[1].shape == (4, 32)
    else:
        assert state is None
    assert net.n_features == 8 * 4 * 22     # our scaled Table 1 stack
    q1, _ = net.step(obs[0])
    assert q1.shape == (4, 5)
    with pytest.raises(ValueError, match="obs must have shape"):
        net(obs[0])


def test_recurrent_sequence_equals_stepping():
    net = build_qnet("d3rqn", rng=1, width=16)
    obs = np.random.default_rng(1).random((4, 2, 1, H, W)).astype(np.float32)
    q_seq, _ = net(obs)
    state = None
    for t in range(4):
        q_t, state = net.step(obs[t], state)
        np.testing.assert_allclose(q_t.data, q_seq.data[t], rtol=1e-5, atol=1e-6)


def test_dueling_combination():
    net = build_qnet("d3qn", rng=2, width=16)
    obs = np.random.default_rng(2).random((1, 3, 1, H, W)).astype(np.float32)
    q, _ = net(obs)
    T, B = 1, 3
    z = net.features(ag.reshape(ag.as_tensor(obs), (T * B, 1, H, W)))
    z = ag.relu(net.core(z))
    v = net.value(z).data                       # (B, 1)
    a = net.advantage(z).data                   # (B, A)
    np.testing.assert_allclose(q.data[0], v + a - a.mean(axis=1, keepdims=True), rtol=1e-5,
                               atol=1e-6)
    # mean-subtracted advantage: the mean over actions of Q is V
    np.testing.assert_allclose(q.data[0].mean(axis=1), v[:, 0], rtol=1e-5, atol=1e-6)


def test_double_q_target_by_hand():
    q_online_next = np.array([[1.0, 5.0, 2.0], [0.0, -1.0, 3.0], [4.0, 0.0, 0.0]])
    q_target_next = np.array([[10.0, 20.0, 30.0], [7.0, 8.0, 9.0], [-2.0, 6.0, 6.0]])
    rewards = np.array([1.0, 0.5, -1.0])
    terminals = np.array([0.0, 0.0, 1.0])
    y = double_q_targets(q_online_next, q_target_next, rewards, terminals, gamma=0.9)
    # online argmax: 1, 2, 0 -> target values 20, 9, (terminal: none)
    np.testing.assert_allclose(y, [1.0 + 0.9 * 20.0, 0.5 + 0.9 * 9.0, -1.0])
    # not the target net's own max (that would be plain DQN: 30 for row 0)
    assert y[0] != 1.0 + 0.9 * 30.0


def _fill(replay, episodes, rng):
    """Write whole episodes into stream 0 of a 1-stream replay; frame value = step id."""
    records = []
    for ep_len, crash in episodes:
        replay.start_episodes([0], np.full((1, H, W), 0.0))
        for t in range(ep_len):
            last = t == ep_len - 1
            frame = np.full((1, H, W), ((t + 1) % 250) / 255.0)
            replay.add_step([t % 5], [float(t)], [crash and last], [last and not crash], frame)
        records.append(ep_len)
    return records


def test_sequence_sampling_never_crosses_episodes():
    rng = np.random.default_rng(0)
    replay = EpisodeReplay(capacity=400, n_streams=1, frame_shape=(H, W), seed=3)
    lens = [int(x) for x in rng.integers(1, 12, size=60)]
    _fill(replay, [(n, i % 2 == 0) for i, n in enumerate(lens)], rng)
    for _ in range(20):
        b = replay.sample(32, seq_len=5, stack=3)
        assert b.obs.shape == (6, 32, 3, H, W)
        # frame value encodes the step within its episode: 0 at start, t+1 after action t;
        # rewards encode t. Inside one window both must advance by exactly one.
        steps = np.rint(b.obs[:, :, -1, 0, 0] * 255).astype(int)       # (6, 32)
        for j in range(32):
            m = b.mask[:, j].astype(bool)
            n_ok = int(m.sum())
            assert n_ok >= 1 and m[:n_ok].all()                          # a prefix
            r = b.rewards[:n_ok, j]
            assert np.all(np.diff(r) == 1)                               # consecutive steps
            assert np.all(np.diff(steps[:n_ok + 1, j]) == 1)             # same episode
            assert steps[0, j] == int(r[0])                              # o_t before a_t
            # terminal only at the last valid step
            assert not b.terminals[:max(0, n_ok - 1), j].any()
        # stacked history never reaches into the previous episode
        hist = np.rint(b.obs[0, :, :, 0, 0] * 255).astype(int)          # (32, 3)
        assert np.all(np.diff(hist, axis=1) >= 0)
        assert np.all(np.diff(hist, axis=1) <= 1)


def test_replay_multi_stream_and_truncation():
    replay = EpisodeReplay(capacity=200, n_streams=2, frame_shape=(H, W), seed=0)
    replay.start_episodes([0, 1], np.zeros((2, H, W)))
    for t in range(7):
        trunc = np.array([t == 6, False])
        replay.add_step([1, 2], [1.0, 2.0], [False, t == 3], trunc,
                        np.full((2, H, W), 0.5))
        if t == 3:
            replay.start_episodes([1], np.zeros((1, H, W)))
    assert len(replay) == 14
    b = replay.sample(64, seq_len=5)
    # truncation is not terminal; only stream 1's step 3 is a collision
    assert b.terminals.sum() <= (b.rewards == 2.0).sum()
    assert not b.terminals[b.rewards == 1.0].any()


def test_recurrent_state_reset_and_advanced_on_random_actions():
    cfg = QNetConfig(width=8)
    agent = Agent(cfg, AgentConfig(), rng=0)
    rng = np.random.default_rng(0)
    obs = rng.random((3, 1, H, W)).astype(np.float32)
    state = agent.initial_state(3)
    # epsilon = 1: every action random, yet the state must still advance
    _, _, state1 = agent.act(obs, state, epsilon=1.0, rng=rng)
    assert np.abs(state1[0].data).sum() > 0
    _, _, state2 = agent.act(obs, state1, epsilon=1.0, rng=rng)
    assert not np.allclose(state1[0].data, state2[0].data)
    # reset only flight 1
    state3 = agent.reset_state(state2, np.array([False, True, False]))
    assert np.all(state3[0].data[1] == 0) and np.all(state3[1].data[1] == 0)
    np.testing.assert_array_equal(state3[0].data[0], state2[0].data[0])
    # the greedy policy resets on "started" flights
    pol = QNetPolicy(agent.online)
    pol.reset(flights(3))
    pol.act(obs[:, 0])
    q_fresh = pol.last_q.copy()
    pol.act(obs[:, 0])
    pol.act(obs[:, 0], started=np.array([True, False, False]))
    np.testing.assert_allclose(pol.last_q[0], q_fresh[0], rtol=1e-5, atol=1e-6)


def test_ensemble_acts_greedily_on_the_members_mean_q():
    """Each member carries its own state through the flight (and resets it on a
    restart); the ensemble's Q is their mean, its action that mean's argmax."""
    nets = [build_qnet("d3rqn", rng=k, width=8) for k in range(3)]
    rng = np.random.default_rng(2)
    frames = rng.random((4, 3, H, W)).astype(np.float32)        # 4 steps, 3 flights
    ens, alone = EnsemblePolicy([QNetPolicy(n) for n in nets]), [QNetPolicy(n) for n in nets]
    ens.reset(flights(3))
    for p in alone:
        p.reset(flights(3))
    for t in range(4):
        started = np.array([False, t == 2, False])
        a = ens.act(frames[t], started=started)
        for p in alone:
            p.act(frames[t], started=started)
        mean = np.mean([p.last_q for p in alone], axis=0)
        np.testing.assert_allclose(ens.last_q, mean, rtol=1e-6, atol=1e-7)
        np.testing.assert_array_equal(a, np.argmax(mean, axis=1))
    with pytest.raises(ValueError, match="at least 2"):
        EnsemblePolicy([QNetPolicy(nets[0])])
    with pytest.raises(TypeError, match=r"members\[1\] must be a Q-net policy"):
        EnsemblePolicy([QNetPolicy(nets[0]), "model.npz"])
    with pytest.raises(ValueError, match="must share"):
        EnsemblePolicy([QNetPolicy(nets[0]),
                        QNetPolicy(build_qnet("d3rqn", rng=0, width=8, n_actions=3))])


def test_mirror_permutation():
    from minid3rqn.world import ACTIONS
    perm = mirror_permutation(ACTIONS)
    np.testing.assert_array_equal(ACTIONS[perm], ACTIONS * [1, -1])    # yaw rate negated
    np.testing.assert_array_equal(perm[perm], np.arange(len(ACTIONS)))  # an involution
    with pytest.raises(ValueError, match=r"no mirror image for \[\[2.0, 0.3\]\]"):
        mirror_permutation([[2.0, 0.0], [2.0, 0.3]])


def test_mirrored_policy_flies_the_mirrored_view():
    """MirroredPolicy on frames x is the plain policy on x mirrored, with each action's
    Q-value reported under its mirror image; through a flight and a restart. Plain +
    mirrored as an ensemble is then exactly mirror-symmetric."""
    perm = mirror_permutation(ACTIONS)
    net = build_qnet("d3rqn", rng=0, width=8)
    rng = np.random.default_rng(3)
    frames = rng.random((5, 2, H, W)).astype(np.float32)        # 5 steps, 2 flights
    flipped = np.ascontiguousarray(frames[..., ::-1])
    plain = QNetPolicy(net)
    mirrored = MirroredPolicy(plain, ACTIONS)
    both = EnsemblePolicy([QNetPolicy(net), MirroredPolicy(QNetPolicy(net), ACTIONS)])
    both_flipped = EnsemblePolicy([QNetPolicy(net), MirroredPolicy(QNetPolicy(net), ACTIONS)])
    for p in (plain, mirrored, both, both_flipped):
        p.reset(flights(2))
    for t in range(5):
        started = np.array([False, t == 3])
        plain.act(flipped[t], started=started)
        a = mirrored.act(frames[t], started=started)
        np.testing.assert_allclose(mirrored.last_q, plain.last_q[:, perm], rtol=1e-6)
        np.testing.assert_array_equal(a, np.argmax(plain.last_q[:, perm], axis=1))
        both.act(frames[t], started=started)
        both_flipped.act(flipped[t], started=started)
        np.testing.assert_allclose(both_flipped.last_q, both.last_q[:, perm], rtol=1e-5,
                                   atol=1e-7)
    with pytest.raises(ValueError, match="action table"):
        MirroredPolicy(QNetPolicy(build_qnet("d3rqn", rng=0, width=8, n_actions=3)), ACTIONS)


def test_mirrored_batch_flips_the_chosen_windows_only():
    """mirror_windows: the chosen windows' frames flipped along the width, their actions
    mapped to the mirror images (mirror_q: Q-values likewise); the rest, and rewards,
    terminals and mask, untouched; mirroring twice gives the batch back."""
    from minid3rqn.rl.replay import SequenceBatch
    perm = mirror_permutation(ACTIONS)
    rng = np.random.default_rng(0)
    L, B, A = 3, 4, len(ACTIONS)
    batch = SequenceBatch(obs=rng.random((L + 1, B, 1, 2, 5)).astype(np.float32),
                          actions=rng.integers(0, A, (L, B)), rewards=rng.random((L, B)),
                          terminals=np.zeros((L, B)), mask=np.ones((L, B)))
    labels = rng.random((L, B, A))
    which = np.array([True, False, True, False])
    m = mirror_windows(batch, which, perm)
    np.testing.assert_array_equal(m.obs[:, which], batch.obs[:, which][..., ::-1])
    np.testing.assert_array_equal(m.obs[:, ~which], batch.obs[:, ~which])
    np.testing.assert_array_equal(m.actions[:, which], perm[batch.actions[:, which]])
    np.testing.assert_array_equal(m.actions[:, ~which], batch.actions[:, ~which])
    # the label of action a is the teacher's Q-value of a's mirror image
    ml = mirror_q(labels, which, perm)
    np.testing.assert_array_equal(ml[:, which], labels[:, which][..., perm])
    np.testing.assert_array_equal(ml[:, ~which], labels[:, ~which])
    assert m.rewards is batch.rewards and m.mask is batch.mask
    back = mirror_windows(m, which, perm)
    for name in ("obs", "actions"):
        np.testing.assert_array_equal(getattr(back, name), getattr(batch, name))
    np.testing.assert_array_equal(mirror_q(ml, which, perm), labels)
    assert mirror_windows(batch, which, perm).obs is not batch.obs   # a copy
    with pytest.raises(ValueError, match="which must be a bool mask of the 4 windows"):
        mirror_windows(batch, np.array([True, False]), perm)


def test_mirrored_frames_give_the_mirrored_q_values():
    """What the augmentation teaches is consistent: a net that is exactly mirror-
    symmetric gives, on a mirrored window, the Q-values of the window with each action
    replaced by its mirror image -- the labels mirror_q writes."""
    from minid3rqn.rl.replay import SequenceBatch
    perm = mirror_permutation(ACTIONS)
    net = build_qnet("d3rqn", rng=0, width=8)
    frames = np.random.default_rng(1).random((5, 3, 1, H, W)).astype(np.float32)

    def symmetric_q(obs):           # the plain net averaged with its mirrored twin
        q, _ = net(obs)
        qm, _ = net(np.ascontiguousarray(obs[..., ::-1]))
        return 0.5 * (q.data + qm.data[..., perm])
    q = symmetric_q(frames)
    batch = SequenceBatch(frames, np.zeros((4, 3), np.int64), np.zeros((4, 3)),
                          np.zeros((4, 3)), np.ones((4, 3)))
    which = np.ones(3, bool)
    m = mirror_windows(batch, which, perm)
    np.testing.assert_allclose(symmetric_q(m.obs)[:4], mirror_q(q[:4], which, perm),
                               rtol=1e-5, atol=1e-6)


def test_frame_stacker():
    fs = FrameStacker(2, 3, (1, 1))
    fs.reset([0, 1], np.array([[[1.0]], [[5.0]]]))
    fs.push(np.array([[[2.0]]]), np.array([0]))
    assert fs.obs[0, :, 0, 0].tolist() == [1.0, 1.0, 2.0]
    assert fs.obs[1, :, 0, 0].tolist() == [5.0, 5.0, 5.0]


def test_update_reduces_loss_on_fixed_batch():
    replay = EpisodeReplay(capacity=200, n_streams=1, frame_shape=(H, W), seed=0)
    _fill(replay, [(8, True), (6, False), (9, True)], np.random.default_rng(0))
    agent = Agent(QNetConfig(width=16), AgentConfig(lr=1e-3), rng=0)
    batch = replay.sample(8, seq_len=5)
    first = agent.update(batch)["loss"]
    for _ in range(30):
        last = agent.update(batch)["loss"]
    assert last < first


def test_agent_state_dict_roundtrip():
    a = Agent(QNetConfig(width=8, recurrent=False), rng=0)
    b = Agent(QNetConfig(width=8, recurrent=False), rng=1)
    b.load_state_dict(a.state_dict())
    for p, q in zip(a.online.parameters(), b.online.parameters()):
        np.testing.assert_array_equal(p.data, q.data)

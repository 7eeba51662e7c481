"""Two training options (ours): weight averaging at the end of training (``--average-last``;
rl/train.py) and growing a net's LSTM with the same Q-values (``--init-widen``; nets/qnet.py)."""
import argparse

import numpy as np
import pytest

from minid3rqn.io import load_npz
from minid3rqn.rl import commands
from minid3rqn.rl.flights import FlightsConfig
from minid3rqn.rl.policies import QNetPolicy
from minid3rqn.rl.train import TrainConfig, Trainer, WeightAverage

pytestmark = pytest.mark.rl


def small_config(**kw) -> TrainConfig:
    base = dict(total_steps=96, learning_starts=32, n_envs=4, log_every=32, checkpoint_every=48,
                hidden=16, replay_capacity=1000, flights=FlightsConfig(n_worlds=2))
    base.update(kw)
    return TrainConfig(**base)


class Recorder(Trainer):
    """A trainer that keeps a copy of the online weights after every update."""

    def learn(self, batch):
        info = super().learn(batch)
        self.snapshots.append((self.steps, self.agent.online.state_dict()))
        return info

    def __init__(self, *a, **kw):
        super().__init__(*a, **kw)
        self.snapshots = []


def test_weight_average_is_the_mean_of_its_snapshots():
    class Net:                                        # two named parameters, float32
        def __init__(self, a, b):
            from minid3rqn.autograd import Tensor
            self.params = [("w", Tensor(np.float32(a) * np.ones((2, 3), np.float32))),
                           ("b", Tensor(np.float32(b) * np.ones(4, np.float32)))]

        def named_parameters(self):
            return iter(self.params)

    avg = WeightAverage()
    with pytest.raises(RuntimeError, match="no snapshot"):
        avg.mean(Net(0, 0))
    for a, b in [(1.0, -2.0), (2.0, 4.0), (6.0, 1.0)]:
        avg.add(Net(a, b))
    got = avg.mean(Net(0, 0))
    assert avg.count == 3 and got["w"].dtype == np.float32
    np.testing.assert_allclose(got["w"], 3.0)
    np.testing.assert_allclose(got["b"], 1.0)


def test_the_saved_model_is_the_mean_over_the_last_transitions(tmp_path):
    """model.npz holds the mean of the weights after every update whose vector step ends
    within the last ``average_last`` transitions, model_last.npz the last weights; the
    run itself (its last weights) is the same as without averaging."""
    cfg = small_config(average_last=40)
    tr = Recorder(cfg, tmp_path / "a", progress=False)
    tr.run()
    late = [w for steps, w in tr.snapshots if steps > cfg.total_steps - cfg.average_last]
    assert 1 < len(late) < len(tr.snapshots) and tr.averager.count == len(late)
    arrays, meta = load_npz(tmp_path / "a" / "model.npz")
    last, _ = load_npz(tmp_path / "a" / "model_last.npz")
    for name in late[0]:
        want = np.mean([w[name].astype(np.float64) for w in late], axis=0)
        np.testing.assert_allclose(arrays[name], want, rtol=1e-6, atol=1e-7)
        np.testing.assert_array_equal(last[name], tr.snapshots[-1][1][name])
    assert meta["averaged_updates"] == len(late)
    assert any(not np.allclose(arrays[n], last[n]) for n in arrays)
    QNetPolicy.load(tmp_path / "a" / "model.npz")    # flies like any other model file
    plain = Trainer(small_config(), tmp_path / "p", progress=False)
    plain.run()
    for p, q in zip(plain.agent.online.parameters(), tr.agent.online.parameters()):
        np.testing.assert_array_equal(p.data, q.data)
    assert not (tmp_path / "p" / "model_last.npz").exists()


def test_averaging_resumes_exactly(tmp_path):
    """A run stopped inside the averaging window and resumed saves the same mean."""
    cfg = small_config(average_last=64)
    a = Trainer(cfg, tmp_path / "a", progress=False)
    a.run(until=48)
    assert a.averager.count > 0                      # stopped inside the window
    a.save_checkpoint()
    b = Trainer.resume(tmp_path / "a", progress=False)
    assert b.averager.count == a.averager.count
    b.run()
    c = Trainer(cfg, tmp_path / "c", progress=False)
    c.run()
    got, _ = load_npz(tmp_path / "a" / "model.npz")
    want, _ = load_npz(tmp_path / "c" / "model.npz")
    assert got.keys() == want.keys()
    for name in want:
        np.testing.assert_array_equal(got[name], want[name])


def test_bad_average_last_gets_a_clear_error(tmp_path):
    for bad in (-1, 97, 2.5, True):
        with pytest.raises(ValueError, match="average_last.*got"):
            Trainer(small_config(average_last=bad), tmp_path, progress=False)
    p = argparse.ArgumentParser()
    commands.add_arguments_train_agent(p)
    args = p.parse_args(["--smoke", "--average-last", "1000", "--out", str(tmp_path / "cli")])
    with pytest.raises(SystemExit, match="--average-last.*1000"):
        commands.config_from_args(args)
    args = p.parse_args(["--smoke", "--average-last", "64", "--out", str(tmp_path / "cli")])
    assert commands.config_from_args(args).average_last == 64


# -- growing the LSTM (--init-widen; nets/qnet.py, widen_recurrent_state) -------------------

def _qnet(width, variant="d3rqn", seed=0, convs=None):
    from minid3rqn.nets.qnet import QNet, QNetConfig
    extra = {"convs": convs} if convs else {}
    return QNet(QNetConfig.for_variant(variant, height=32, width_px=104, n_actions=5,
                                       width=width, **extra), rng=seed)


@pytest.mark.parametrize("variant", ["d3rqn", "ddrqn"])
def test_a_widened_net_starts_with_the_same_q_values_and_can_learn(variant):
    from minid3rqn import autograd as ag
    from minid3rqn.nets.qnet import widen_recurrent_state
    narrow, wide = _qnet(8, variant, seed=1), _qnet(13, variant, seed=2)
    wide.load_state_dict(widen_recurrent_state(narrow.state_dict(), wide.state_dict()))
    obs = np.random.default_rng(3).random((6, 2, 1, 32, 104)).astype(np.float32)
    q0, _ = narrow(obs)
    q1, (h, _) = wide(obs)
    np.testing.assert_allclose(q1.data, q0.data, rtol=1e-5, atol=1e-6)
    assert np.abs(h.data[:, 8:]).max() > 0          # the new units run ...
    ag.sum(q1 * q1).backward()                      # ... and their path to the heads opens
    head = wide.advantage if variant == "d3rqn" else wide.q_head
    assert np.abs(head.weight.grad[:, 8:]).max() > 0


def test_widening_refuses_what_it_cannot_do(tmp_path):
    from minid3rqn.nets.qnet import widen_recurrent_state
    wide = _qnet(16)
    with pytest.raises(ValueError, match="at least as wide.*16.*got 8"):
        widen_recurrent_state(wide.state_dict(), _qnet(8).state_dict())
    with pytest.raises(ValueError, match="only a recurrent"):
        widen_recurrent_state(_qnet(8, "d3qn").state_dict(), _qnet(16, "d3qn").state_dict())
    other = _qnet(16, convs=[[4, 4, 2], [8, 4, 2], [6, 3, 1]])
    with pytest.raises(ValueError, match="only the LSTM may be wider|LSTM's input"):
        widen_recurrent_state(_qnet(8).state_dict(), other.state_dict())
    p = argparse.ArgumentParser()
    commands.add_arguments_train_agent(p)
    args = p.parse_args(["--smoke", "--init-widen", "--out", str(tmp_path / "cli")])
    with pytest.raises(SystemExit, match="--init-widen.*needs --init-model"):
        commands.config_from_args(args)
    narrow = tmp_path / "narrow.npz"
    _qnet(32).save(narrow)                          # wider than --smoke's 16 units
    args = p.parse_args(["--smoke", "--quiet", "--init-widen", "--init-model", str(narrow),
                         "--out", str(tmp_path / "cli")])
    with pytest.raises(SystemExit, match="--init-widen.*at least as wide"):
        commands.run_train_agent(args)


def test_training_from_a_widened_net(tmp_path):
    """A run from a widened --init-model starts from its Q-values and resumes exactly."""
    narrow = tmp_path / "narrow.npz"
    _qnet(8).save(narrow, {"kind": "qnet"})
    cfg = small_config(init_model=str(narrow), init_widen=True)
    a = Trainer(cfg, tmp_path / "a", progress=False)
    obs = np.random.default_rng(0).random((3, 2, 1, 32, 104)).astype(np.float32)
    np.testing.assert_allclose(a.agent.online(obs)[0].data, _qnet(8)(obs)[0].data,
                               rtol=1e-5, atol=1e-6)
    a.run(until=48)
    a.save_checkpoint()
    b = Trainer.resume(tmp_path / "a", progress=False)
    a.run()
    b.run()
    for p, q in zip(a.agent.online.parameters(), b.agent.online.parameters()):
        np.testing.assert_array_equal(p.data, q.data)


def test_a_run_without_a_bar_prints_one_line_per_checkpoint(tmp_path, capsys):
    """With no progress bar (--quiet; reproduce's parallel runs) a run still says how far
    it is: its folder, steps of the total and the success so far, at each checkpoint."""
    Trainer(small_config(), tmp_path / "quiet_run", progress=False).run()
    lines = [l for l in capsys.readouterr().out.splitlines() if l.startswith("quiet_run: ")]
    assert [l.split()[1] for l in lines] == ["48/96", "96/96"]
    assert all("success" in l and l.endswith(" s") for l in lines)

"""The training loop: many flights stepped together, one replay, one agent.

Per vector step (``n_envs`` flights at once):

    1. act: epsilon-greedy on the batched Q-net; the recurrent state advances for every
       flight, and is zeroed for a flight that has just started a new episode;
    2. step the flights; store (a, r, collision, o') in the flight's replay stream;
       a finished flight (collision, or the 50-step limit: not terminal) restarts;
    3. after ``learning_starts`` transitions, ``updates_per_step`` double-Q updates on
       windows sampled from the replay.

Everything random comes from ``seed``: the networks, the worlds, exploration and
sampling. A checkpoint holds the agent (weights, target, Adam), the replay, the
flights' state and every generator, so ``resume`` continues the exact same run.
"""
from __future__ import annotations

import csv
import json
import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np

from ..io import load_npz, save_npz
from ..nets.qnet import QNetConfig
from ..world import Camera
from .agent import Agent, AgentConfig, FrameStacker
from .flights import Flights, FlightsConfig
from .replay import EpisodeReplay


@dataclass
class TrainConfig:
    variant: str = "d3rqn"         # ddqn | d3qn | ddrqn | d3rqn
    stack: int = 1                 # frames per observation (5: the window as channels)
    seq_len: int = 5               # paper, Table 4 (recurrent); non-recurrent use 1
    scenario: str = "basic"
    seed: int = 0
    n_envs: int = 16               # ours: parallel flights
    total_steps: int = 60_000      # ours: environment transitions (all flights)
    learning_starts: int = 5_000   # ours
    updates_per_step: float = 4.0  # ours: updates per vector step (16 transitions); 1.0 was
                                   # 0.764 vs 0.871 for D3RQN (docs/results.md, budgets A, B)
    batch_size: int = 32           # paper, Table 4
    replay_capacity: int = 100_000  # ours: frames (uint8, ~340 MB)
    eps_start: float = 1.0         # ours
    eps_end: float = 0.05          # ours
    eps_decay_steps: int = 50_000  # ours: transitions for the linear decay
    hidden: int = 128              # ours: LSTM / FC width
    conv_channels: list | None = None  # ours: out channels of the conv layers (None: the
                                       # QNetConfig's 4, 8, 8; kernels and strides stay)
    depth: str = "gt"              # gt | pred (the DispNet's depth maps)
    horizon_row: float | None = None  # ours: the camera's horizon row (Camera.horizon_row;
                                      # None: the middle row; docs/depth.md section 7)
    log_every: int = 2_000         # transitions between learning-curve rows
    checkpoint_every: int = 10_000  # transitions between checkpoints
    init_model: str = ""           # start from these Q-net weights (fine-tuning), if set
    init_widen: bool = False       # ours: init_model has a narrower LSTM; grow it to `hidden`
                                   # units, same Q-values at the start (widen_recurrent_state)
    # -- distillation (ours, optional; rl/distill.py): a teacher, on GT depth by default
    teachers: str = ""             # '+'-joined Q-net files; set -> learn the teacher's Q-values
    teacher_mix: float = 0.5       # probability of flying the teacher's action at the start,
    teacher_mix_steps: int = 10_000  # decayed linearly to 0 over this many transitions
    teacher_mirror: bool = False   # ours: each teacher net also flies the mirrored view
    teacher_depth: str = "gt"      # ours: what the teacher reads: gt (privileged) | pred (the
                                   # student's own frames: distilling nets that fly on them)
    base_teachers: str = ""        # ours: in a mixed pool, a second teacher for the flights in
                                   # the scenario's own worlds ('teachers' teach in the rest)
    distil_kl: float = 0.0         # ours: weight of a KL term on the teacher's action
                                   # preferences, softmax(Q_T / T), added to the Huber loss
    distil_temperature: float = 0.1  # T of that term, in the units of the Q-values
    mirror_augment: bool = False   # ours: learn from each sampled window mirrored left-right
                                   # with probability 1/2 (SequenceBatch.mirrored)
    average_last: int = 0          # ours: the saved model is the mean of the online weights
                                   # after every update of the last this-many transitions
                                   # (weight averaging, "SWA"; 0: the last weights)
    agent: AgentConfig = field(default_factory=AgentConfig)
    flights: FlightsConfig = field(default_factory=FlightsConfig)

    def __post_init__(self):
        if isinstance(self.agent, dict):
            self.agent = AgentConfig(**self.agent)
        if isinstance(self.flights, dict):
            self.flights = FlightsConfig(**self.flights)

    def qnet_config(self, n_actions: int, frame_shape) -> QNetConfig:
        extra = {}
        if self.conv_channels is not None:
            convs = QNetConfig().convs
            chans = list(self.conv_channels)
            if len(chans) != len(convs) or not all(
                    isinstance(c, (int, np.integer)) and not isinstance(c, bool) and c >= 1
                    for c in chans):
                raise ValueError(f"TrainConfig: conv_channels must be {len(convs)} ints >= 1 "
                                 f"(one per conv layer); got {self.conv_channels!r}")
            extra["convs"] = [[int(c), k, s] for c, (_, k, s) in zip(chans, convs)]
        return QNetConfig.for_variant(self.variant, in_channels=self.stack,
                                      height=frame_shape[0], width_px=frame_shape[1],
                                      n_actions=n_actions, width=self.hidden, **extra)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "TrainConfig":
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in names})


def epsilon_at(cfg: TrainConfig, step: int) -> float:
    """Linear from eps_start to eps_end over eps_decay_steps transitions, then flat."""
    frac = min(1.0, step / max(1, cfg.eps_decay_steps))
    return cfg.eps_start + frac * (cfg.eps_end - cfg.eps_start)


def _rng_state(rng: np.random.Generator) -> str:
    return json.dumps(rng.bit_generator.state)


def _set_rng_state(rng: np.random.Generator, s: str) -> None:
    rng.bit_generator.state = json.loads(s)


class WeightAverage:
    """The running mean of a net's weights over snapshots (our addition).

    Stochastic weight averaging (Izmailov et al. 2018): the weights at the end of training
    still jump from update to update with the noise of each minibatch; their mean over many
    late updates lies nearer the middle of the region they wander in, and often predicts
    better than any one of them. For a net without batch statistics (ours) the mean is the
    whole method. Sums are float64, so thousands of snapshots lose nothing.
    """

    def __init__(self):
        self.sums: dict[str, np.ndarray] = {}
        self.count = 0

    def add(self, net) -> None:
        for name, p in net.named_parameters():
            if name in self.sums:
                self.sums[name] += p.data
            else:
                self.sums[name] = p.data.astype(np.float64)
        self.count += 1

    def mean(self, net) -> dict[str, np.ndarray]:
        """The mean weights, in each parameter's own dtype, named as ``net.state_dict()``."""
        if self.count == 0:
            raise RuntimeError("WeightAverage.mean: no snapshot has been added")
        return {name: (self.sums[name] / self.count).astype(p.dtype)
                for name, p in net.named_parameters()}

    def load(self, sums: dict[str, np.ndarray], count: int) -> None:
        self.sums = {k: np.asarray(v, dtype=np.float64).copy() for k, v in sums.items()}
        self.count = int(count)


class Trainer:
    """Holds the run's state; ``run()`` trains to ``total_steps`` (resumable)."""

    learns_from_teacher = False          # rl.distill.Distiller: True

    def __init__(self, cfg: TrainConfig, out_dir, depth_estimator=None, progress: bool = True):
        if cfg.teachers and not self.learns_from_teacher:
            raise ValueError("Trainer: cfg.teachers is set, which asks for distillation; "
                             "use rl.distill.Distiller (or rl.train.train, which picks it)")
        if (isinstance(cfg.average_last, bool) or not isinstance(cfg.average_last, (int, np.integer))
                or not 0 <= cfg.average_last <= cfg.total_steps):
            raise ValueError(f"Trainer: average_last (--average-last) is a number of "
                             f"transitions in [0, total_steps = {cfg.total_steps}]; got "
                             f"{cfg.average_last!r}")
        for name, flag in (("seq_len", "--seq-len"), ("batch_size", "--batch-size")):
            value = getattr(cfg, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"Trainer: {name} ({flag}) must be an int >= 1; got {value!r}")
        self.cfg = cfg
        self.out = Path(out_dir)
        self.out.mkdir(parents=True, exist_ok=True)
        self.progress = progress
        ss = np.random.SeedSequence(cfg.seed)
        net_seed, world_seed, act_seed, replay_seed = (int(s.generate_state(1)[0])
                                                       for s in ss.spawn(4))
        self.flights = Flights(cfg.scenario, cfg.n_envs, seed=world_seed, config=cfg.flights,
                               depth=cfg.depth, depth_estimator=depth_estimator,
                               camera=Camera(horizon_row=cfg.horizon_row))
        self.frame_shape = self.flights.frame_shape
        self.agent = Agent(cfg.qnet_config(self.flights.n_actions, self.frame_shape),
                           cfg.agent, rng=net_seed)
        if cfg.init_model and cfg.init_widen:
            from ..nets.qnet import widen_recurrent_state
            old, _ = load_npz(cfg.init_model)
            self.agent.online.load_state_dict(
                widen_recurrent_state(old, self.agent.online.state_dict()))
            self.agent.target.copy_from(self.agent.online)
        elif cfg.init_model:
            self.agent.online.load(cfg.init_model)
            self.agent.target.copy_from(self.agent.online)
        self.replay = self.make_replay(replay_seed)
        self.rng = np.random.default_rng(act_seed)
        # a fifth stream for the mirror augmentation (the first four, hence every run
        # without it, are unchanged by its existence)
        self.aug_rng = np.random.default_rng(ss.spawn(1)[0])
        self.mirror_of = None
        if cfg.mirror_augment:
            from .policies import mirror_permutation
            try:
                self.mirror_of = mirror_permutation(self.flights.actions)
            except ValueError as e:
                raise ValueError(f"TrainConfig.mirror_augment (--mirror-augment) needs a "
                                 f"symmetric action table: {e}") from None
        self.steps = 0
        self.update_credit = 0.0
        self.episodes = 0
        self.averager = WeightAverage()
        self.curve: list[dict] = []
        self._window = {"returns": [], "success": [], "lengths": [], "loss": [], "q": []}
        self._ret = np.zeros(cfg.n_envs)
        self._len = np.zeros(cfg.n_envs, dtype=np.int64)
        self._started = False
        self.state = None
        self.stacker = FrameStacker(cfg.n_envs, cfg.stack, self.frame_shape)

    def make_replay(self, seed) -> EpisodeReplay:
        return EpisodeReplay(self.cfg.replay_capacity, self.cfg.n_envs, self.frame_shape,
                             seed=seed)

    # -- the loop -------------------------------------------------------------------
    def _start(self):
        frames = self.flights.reset()
        self.replay.start_episodes(np.arange(self.cfg.n_envs), frames)
        self.stacker.reset(np.arange(self.cfg.n_envs), frames)
        self.state = self.agent.initial_state(self.cfg.n_envs)

    def choose_actions(self) -> np.ndarray:
        """Step 1: epsilon-greedy on the online net; the recurrent state advances."""
        eps = epsilon_at(self.cfg, self.steps)
        actions, _, self.state = self.agent.act(self.stacker.obs, self.state, eps, self.rng)
        return actions

    def episodes_ended(self, done: np.ndarray) -> None:
        """Flights in ``done`` (bool (n,)) start a new episode: zero their state."""
        self.state = self.agent.reset_state(self.state, done)

    def learn(self, batch) -> dict:
        """Step 3: one double-Q update on a window batch."""
        return self.agent.update(batch)

    def vector_step(self):
        cfg = self.cfg
        actions = self.choose_actions()
        res = self.flights.step(actions)
        done = res.terminated | res.truncated
        self.replay.add_step(actions, res.rewards, res.terminated, res.truncated,
                             res.final_frames)
        self._ret += res.rewards
        self._len += 1
        if done.any():
            idx = np.flatnonzero(done)
            for i in idx:
                self._window["returns"].append(float(self._ret[i]))
                self._window["success"].append(float(res.success[i]))
                self._window["lengths"].append(int(self._len[i]))
            self._ret[idx] = 0
            self._len[idx] = 0
            self.episodes += len(idx)
            self.replay.start_episodes(idx, res.frames[idx])
            self.episodes_ended(done)
        live = np.flatnonzero(~done)
        self.stacker.push(res.frames[live], live)
        if done.any():
            self.stacker.reset(np.flatnonzero(done), res.frames[done])
        self.steps += cfg.n_envs
        if self.steps >= cfg.learning_starts:
            self.update_credit += cfg.updates_per_step
            while self.update_credit >= 1.0:
                self.update_credit -= 1.0
                batch = self.replay.sample(cfg.batch_size, cfg.seq_len, cfg.stack)
                if self.mirror_of is not None:
                    which = self.aug_rng.random(batch.actions.shape[1]) < 0.5
                    batch = batch.mirrored(which, self.mirror_of)
                info = self.learn(batch)
                if self.steps > cfg.total_steps - cfg.average_last:
                    self.averager.add(self.agent.online)
                self._window["loss"].append(info["loss"])
                self._window["q"].append(info["q_mean"])

    def _log_row(self, elapsed: float):
        w = self._window
        row = {"steps": self.steps, "updates": self.agent.updates, "episodes": self.episodes,
               "epsilon": round(epsilon_at(self.cfg, self.steps), 4),
               "return": float(np.mean(w["returns"])) if w["returns"] else float("nan"),
               "success": float(np.mean(w["success"])) if w["success"] else float("nan"),
               "length": float(np.mean(w["lengths"])) if w["lengths"] else float("nan"),
               "loss": float(np.mean(w["loss"])) if w["loss"] else float("nan"),
               "q_mean": float(np.mean(w["q"])) if w["q"] else float("nan"),
               "seconds": round(elapsed, 1), **self.extra_row()}
        self.curve.append(row)
        for v in w.values():
            v.clear()
        self.write_curve()
        return row

    def extra_row(self) -> dict:
        """More learning-curve columns (a subclass's); reads ``self._window`` before it is
        cleared."""
        return {}

    def write_curve(self):
        if not self.curve:
            return
        path = self.out / "curve.csv"
        with open(path, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(self.curve[0]))
            writer.writeheader()
            writer.writerows(self.curve)
        try:
            from ..viz import learning_curve_png
            learning_curve_png(self.curve, self.out / "curve.png",
                               title=f"{self.cfg.variant} on {self.cfg.scenario}, seed {self.cfg.seed}")
        except Exception as e:  # a plotting problem must never stop a training run
            print(f"warning: learning-curve PNG not written: {e}")

    def run(self, until: int | None = None) -> dict:
        cfg = self.cfg
        until = cfg.total_steps if until is None else min(until, cfg.total_steps)
        if not self._started:
            self._start()
            self._started = True
        t0 = time.time() - (self.curve[-1]["seconds"] if self.curve else 0.0)
        bar = None
        if self.progress:
            from tqdm import tqdm
            bar = tqdm(total=cfg.total_steps, initial=self.steps, unit="step",
                       desc=f"train {cfg.variant}", dynamic_ncols=True)
        next_log = (self.steps // cfg.log_every + 1) * cfg.log_every
        next_ckpt = (self.steps // cfg.checkpoint_every + 1) * cfg.checkpoint_every
        while self.steps < until:
            self.vector_step()
            if bar is not None:
                bar.update(cfg.n_envs)
            if self.steps >= next_log:
                row = self._log_row(time.time() - t0)
                next_log += cfg.log_every
                if bar is not None:
                    bar.set_postfix(success=f"{row['success']:.2f}", ret=f"{row['return']:.1f}",
                                    eps=f"{row['epsilon']:.2f}")
            if self.steps >= next_ckpt:
                self.save_checkpoint()
                next_ckpt += cfg.checkpoint_every
                if bar is None:           # no bar (--quiet, parallel runs): one line instead
                    self._report_line(time.time() - t0)
        if bar is not None:
            bar.close()
        self.save_checkpoint()
        return self.curve[-1] if self.curve else {}

    def _report_line(self, seconds: float) -> None:
        last = self.curve[-1] if self.curve else {}
        success = f", success {last['success']:.2f}" if "success" in last else ""
        print(f"{self.out.name}: {self.steps}/{self.cfg.total_steps} steps{success}, "
              f"{seconds:.0f} s", flush=True)

    # -- checkpoints ----------------------------------------------------------------
    def save_checkpoint(self, path=None) -> Path:
        path = Path(path or self.out / "checkpoint.npz")
        arrays = {f"agent.{k}": v for k, v in self.agent.state_dict().items()}
        arrays.update({f"replay.{k}": v for k, v in self.replay.state_dict().items()})
        arrays.update({f"flights.{k}": v for k, v in self.flights.state_dict().items()})
        arrays["stacker"] = self.stacker.buf
        arrays["ret"] = self._ret
        arrays["len"] = self._len
        if self.state is not None:
            arrays["state_h"], arrays["state_c"] = self.state[0].data, self.state[1].data
        arrays.update(self.extra_state())
        arrays.update({f"average.{k}": v for k, v in self.averager.sums.items()})
        meta = {"config": self.cfg.to_dict(), "steps": self.steps, "episodes": self.episodes,
                "average_count": self.averager.count,
                "update_credit": self.update_credit, "curve": self.curve,
                "window": self._window, "rng": _rng_state(self.rng),
                "replay_rng": _rng_state(self.replay.rng), "aug_rng": _rng_state(self.aug_rng),
                "flights_meta": self.flights.meta_state()}
        save_npz(path, arrays, meta)
        self.save_model(self.out / "model.npz")
        return path

    def save_model(self, path, extra: dict | None = None) -> Path:
        """The model file: the online weights; with weight averaging under way, the mean
        so far (``average_last``), and the online weights beside it as ``model_last.npz``
        so the two can be flown against each other."""
        meta = {"kind": "qnet", "qnet_config": self.agent.qnet_config.to_dict(),
                "train_config": self.cfg.to_dict(), "steps": self.steps,
                "updates": self.agent.updates, **(extra or {})}
        if self.averager.count == 0:
            return self.agent.online.save(path, meta)
        path = Path(path)
        self.agent.online.save(path.with_name(path.stem + "_last.npz"),
                               {**meta, "weights": "the last update's (online)"})
        meta["weights"] = (f"the mean after each of the last {self.averager.count} updates "
                           f"(--average-last {self.cfg.average_last})")
        meta["averaged_updates"] = self.averager.count
        return save_npz(path, self.averager.mean(self.agent.online), meta)

    def extra_state(self) -> dict[str, np.ndarray]:
        """More arrays for the checkpoint (a subclass's), given back to ``load_extra_state``."""
        return {}

    def load_extra_state(self, arrays: dict[str, np.ndarray]) -> None:
        pass

    @classmethod
    def resume(cls, out_dir, depth_estimator=None, progress: bool = True,
               total_steps: int | None = None) -> "Trainer":
        from ..autograd import Tensor
        arrays, meta = load_npz(Path(out_dir) / "checkpoint.npz")
        cfg = TrainConfig.from_dict(meta["config"])
        if total_steps is not None:
            cfg.total_steps = total_steps
        tr = cls(cfg, out_dir, depth_estimator=depth_estimator, progress=progress)

        def part(prefix):
            return {k[len(prefix):]: v for k, v in arrays.items() if k.startswith(prefix)}
        tr.agent.load_state_dict(part("agent."))
        tr.replay.load_state_dict(part("replay."))
        tr.flights.load_state_dict(part("flights."), meta["flights_meta"])
        tr.stacker.buf[...] = arrays["stacker"]
        tr._ret[...] = arrays["ret"]
        tr._len[...] = arrays["len"]
        if "state_h" in arrays:
            tr.state = (Tensor(arrays["state_h"].copy()), Tensor(arrays["state_c"].copy()))
        tr.load_extra_state(arrays)
        tr.averager.load(part("average."), meta.get("average_count", 0))
        tr.steps, tr.episodes = meta["steps"], meta["episodes"]
        tr.update_credit = meta["update_credit"]
        tr.curve = meta["curve"]
        tr._window = meta["window"]
        _set_rng_state(tr.rng, meta["rng"])
        _set_rng_state(tr.replay.rng, meta["replay_rng"])
        if "aug_rng" in meta:                # checkpoints before the fourteenth session
            _set_rng_state(tr.aug_rng, meta["aug_rng"])
        tr._started = True
        return tr


def train(cfg: TrainConfig, out_dir, depth_estimator=None, progress: bool = True,
          resume: bool = False) -> Trainer:
    """Train (or resume, if ``resume`` and a checkpoint exists) and return the trainer."""
    cls = Trainer
    if cfg.teachers:                      # distillation from a privileged teacher
        from .distill import Distiller
        cls = Distiller
    ckpt = Path(out_dir) / "checkpoint.npz"
    if resume and ckpt.exists():
        tr = cls.resume(out_dir, depth_estimator, progress, total_steps=cfg.total_steps)
    else:
        tr = cls(cfg, out_dir, depth_estimator, progress)
    tr.run()
    return tr


__all__ = ["TrainConfig", "Trainer", "WeightAverage", "train", "epsilon_at"]

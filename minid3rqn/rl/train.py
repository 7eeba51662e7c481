"""Training a Q-network: many flights stepped together, one episodic replay, one agent.

``train`` is the algorithm, one step per line block (``n_envs`` flights at once):

    1. act: epsilon-greedy on the online net; the recurrent state advances for every
       flight (whichever action is taken), and is zeroed when a flight starts anew;
    2. step the flights (``world.DroneEnv``): one action each (0.4 s), reward (Eq. 4),
       the next depth map, encoded for the Q-net (``rl.observe.encode_depth``);
    3. store (a, r, collision, o') in the flight's replay stream; a finished flight
       (collision, or the 50-step limit: not terminal) restarts in a new world, and its
       frame stack (``agent.FrameStacker``) starts again;
    4. learn: after ``learning_starts`` transitions, ``updates_per_step`` double-Q
       updates per step, each on ``batch_size`` windows of ``seq_len`` steps;
    5. log a learning-curve row every ``log_every`` transitions;
    6. checkpoint every ``checkpoint_every`` transitions.

Everything random comes from ``seed``: the networks, the worlds, exploration and
sampling. A checkpoint holds the agent (weights, target, Adam), the replay, the
flights' state and every generator, so a resumed run is the run that was cut off.
"""
from __future__ import annotations

import csv
import io
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..config import (FLIGHT_BYTES, FLIGHT_STEPS, ConfigError, as_dict, at_least, between,
                      changed_settings, fits_memory, flat_settings, positive, setting, up_to,
                      validate)
from ..io import (RunStopped, StopRequest, check_checkpoint_weights, load_npz,
                  reading_checkpoint, save_npz, write_file)
from ..nets.qnet import QNetConfig
from ..world import DroneEnv
from .agent import Agent, AgentConfig, FrameStacker
from .observe import encode_depth
from .replay import EpisodeReplay

RECURRENT = ("ddrqn", "d3rqn")
# The settings a resumed run may change: how far it goes (steps: train a run on) and how
# it reports; every other one must be its checkpoint's.
MAY_CHANGE_ON_RESUME = ("steps", "log_every", "checkpoint_every")
# A few hundred steps on a small net, for tests (train-agent --smoke).
SMOKE = dict(steps=128, learning_starts=64, n_envs=8, log_every=64, checkpoint_every=1000,
             hidden=16, replay_capacity=2000, eps_decay_steps=200, n_worlds=2)


def _conv_channels(v):
    return None if len(v) == 3 and all(isinstance(c, int) and c >= 1 for c in v) \
        else "three whole numbers >= 1"


def _action_table(v):
    rows = all(isinstance(r, list) and len(r) == 2 and all(map(math.isfinite, r))
               and r[0] >= 0 for r in v)
    return None if v and rows else "rows of (speed >= 0, yaw rate), e.g. 2,-0.5;2,0;2,0.5"


@dataclass
class TrainConfig:
    # -- the paper's settings (Table 4; gamma, lr and the target update are the agent's)
    batch_size: int = setting(32, "replay windows per update", source="paper",
                              check=at_least(1))
    seq_len: int | None = setting(None, "steps per replay window (5; none: 5 for the "
                                        "recurrent variants, 1 for the others; at most "
                                        "a flight's 50 steps)",
                                  source="paper",
                                  check=up_to(1, FLIGHT_STEPS, "a flight's 50 steps"))
    agent: AgentConfig = setting(default_factory=AgentConfig)
    # -- the budget (ours: scaled to a laptop)
    steps: int = setting(60_000, "environment transitions (all flights)", source="budget",
                         check=at_least(1))
    learning_starts: int = setting(5_000, "transitions before the first update",
                                   source="budget", check=at_least(0))
    replay_capacity: int = setting(100_000, "frames in the replay (3.3 KB each: 100,000 "
                                            "take 333 MB)", source="budget",
                                   check=fits_memory(64, 3.3e3, "replay frames"))
    eps_decay_steps: int = setting(50_000, "transitions over which epsilon falls",
                                   source="budget", check=at_least(1))
    hidden: int = setting(128, "LSTM / fully connected width", source="budget",
                          check=at_least(1))
    eps_start: float = setting(1.0, "epsilon at the start", source="budget",
                               check=between(0, 1), cli="more")
    eps_end: float = setting(0.05, "epsilon after eps_decay_steps", source="budget",
                             check=between(0, 1), cli="more")
    n_envs: int = setting(16, "flights stepped together", source="budget",
                          check=fits_memory(1, FLIGHT_BYTES, "flights stepped together"),
                          cli="more")
    updates_per_step: float = setting(4.0, "updates per step of all flights (1.0 gave 0.764 "
                                           "against 0.871: docs/results.md)",
                                      source="budget", check=positive, cli="more")
    n_worlds: int = setting(32, "worlds in the training pool", source="budget",
                            check=at_least(1), cli="more")
    # -- the run
    variant: str = setting("d3rqn", "the Q-network", source="run",
                           choices=("ddqn", "d3qn", "ddrqn", "d3rqn"))
    scenario: str = setting("basic", "the training worlds", source="run",
                            choices=("basic", "channel", "intersections", "corners"))
    seed: int = setting(0, "seeds the nets, the worlds, exploration and sampling",
                        source="run", check=at_least(0))
    depth: str = setting("gt", "what the Q-net reads: GT depth or the DispNet's",
                         source="run", choices=("gt", "pred"))
    init_model: str = setting("", "start from this Q-net .npz (fine-tuning)", source="run")
    stack: int = setting(1, "frames per observation (5: a window as channels; at most a "
                            "flight's 50 steps)",
                         source="run", check=up_to(1, FLIGHT_STEPS, "a flight's 50 steps"),
                         cli="more")
    log_every: int = setting(2_000, "transitions between learning-curve rows",
                             source="run", check=at_least(1), cli="more")
    checkpoint_every: int = setting(10_000, "transitions between checkpoints",
                                    source="run", check=at_least(1), cli="more")
    # -- what the net is trained with, recorded in its file (evaluate and fly use it)
    actions: list | None = setting(None, "the action table: speed,yaw-rate rows joined by "
                                         "';' (none: the paper's Table 3)", check=_action_table)
    hfov_deg: float = setting(90.0, "the camera's horizontal field of view (degrees)",
                              check=lambda v: None if 0 < v < 180 else "a number in (0, 180)")
    conv_channels: list | None = setting(None, "out channels of the three conv layers "
                                               "(none: 4,8,8)", check=_conv_channels)

    def __post_init__(self):
        if isinstance(self.actions, np.ndarray):
            self.actions = self.actions.tolist()
        validate(self)
        if self.replay_capacity < 4 * self.n_envs:    # each flight's stream holds 4 frames
            raise ConfigError("replay_capacity", self.replay_capacity,
                              f"at least 4 frames per flight ({4 * self.n_envs})")

    def window(self) -> int:
        """The replay windows' length: ``seq_len``, else 5 (recurrent) or 1."""
        return self.seq_len or (5 if self.variant in RECURRENT else 1)

    def qnet_config(self, n_actions: int, frame_shape) -> QNetConfig:
        extra = {}
        if self.conv_channels is not None:
            extra["convs"] = [[int(c), k, s] for c, (_, k, s)
                              in zip(self.conv_channels, QNetConfig().convs)]
        return QNetConfig.for_variant(self.variant, in_channels=self.stack,
                                      height=frame_shape[0], width_px=frame_shape[1],
                                      n_actions=n_actions, width=self.hidden, **extra)


def run_seeds(seed: int) -> list[int]:
    """The seeds of a run's networks, worlds, exploration and replay sampling: the
    first four children of ``SeedSequence(seed)``."""
    return [int(s.generate_state(1)[0]) for s in np.random.SeedSequence(seed).spawn(4)]


def training_worlds(seed: int, n_worlds: int = 32) -> np.ndarray:
    """The world seeds a run of ``seed`` trains in (its env's pool; ``evaluate --worlds
    train`` flies them, the paper's protocol)."""
    from ..world.env import draw_worlds
    return draw_worlds("train", np.random.default_rng(run_seeds(seed)[1]), n_worlds)


def epsilon_at(cfg: TrainConfig, step: int) -> float:
    """Linear from eps_start to eps_end over eps_decay_steps transitions, then flat."""
    frac = min(1.0, step / max(1, cfg.eps_decay_steps))
    return cfg.eps_start + frac * (cfg.eps_end - cfg.eps_start)


class Run:
    """Everything a training run holds: the flights (``env``), the agent, the replay, the
    frame stacks and recurrent state of the flights, the counters and the learning curve.

    ``reward_fn``, ``depth_fn``: the env's (``world.DroneEnv``); ``td_target``: the agent's;
    ``replay``: makes the replay, ``(capacity, n_streams, frame_shape, seed)``;
    ``extra``: more state for the checkpoint, {name: object with ``state_dict`` and
    ``load_state_dict``}; ``settings``: what a resumed run must share with its
    checkpoint besides ``cfg``'s settings ({name: value}: a method's own settings, the
    depth model file)."""

    def __init__(self, cfg: TrainConfig, out_dir, depth_estimator=None, *, reward_fn=None,
                 depth_fn=None, td_target=None, replay=EpisodeReplay, extra=None,
                 settings: dict | None = None):
        from ..world import Camera
        self.cfg, self.out = cfg, Path(out_dir)
        self.settings = {**flat_settings(as_dict(cfg)), **(settings or {})}
        net_seed, world_seed, act_seed, replay_seed = run_seeds(cfg.seed)
        self.env = DroneEnv(cfg.scenario, cfg.n_envs, seed=world_seed, worlds="train",
                            n_worlds=cfg.n_worlds,
                            observation={"gt": "depth", "pred": "pred"}[cfg.depth],
                            depth_model=depth_estimator if cfg.depth == "pred" else None,
                            camera=Camera(hfov_deg=cfg.hfov_deg), actions=cfg.actions,
                            reward_fn=reward_fn, depth_fn=depth_fn, autoreset=True)
        shape = self.env.frame_shape
        self.agent = Agent(cfg.qnet_config(self.env.n_actions, shape), cfg.agent,
                           rng=net_seed, td_target=td_target)
        self.replay = replay(cfg.replay_capacity, cfg.n_envs, shape, seed=replay_seed)
        self.rng = np.random.default_rng(act_seed)
        self.stacker = FrameStacker(cfg.n_envs, cfg.stack, shape)
        self.state = None
        self.extra = dict(extra or {})
        self.steps = self.episodes = 0
        self.update_credit = 0.0
        self.curve: list[dict] = []
        self.notes: dict[str, list] = {}
        self.returns = np.zeros(cfg.n_envs)
        self.lengths = np.zeros(cfg.n_envs, dtype=np.int64)
        self.out.mkdir(parents=True, exist_ok=True)      # made once the run could be

    def start(self) -> None:
        """Every flight takes off; its first frame opens its replay stream."""
        frames = encode_depth(self.env.reset()[0])
        self.replay.start_episodes(np.arange(self.cfg.n_envs), frames)
        self.stacker.reset(np.arange(self.cfg.n_envs), frames)
        self.state = self.agent.initial_state(self.cfg.n_envs)

    def note(self, key: str, value: float) -> None:
        """A number for the next learning-curve row (the mean of those noted)."""
        self.notes.setdefault(key, []).append(float(value))

    def episodes_end(self, rewards, success, done: np.ndarray) -> None:
        """Note the finished flights' return, success and length; count the rest."""
        self.returns += rewards
        self.lengths += 1
        for i in np.flatnonzero(done):
            self.note("return", self.returns[i])
            self.note("success", success[i])
            self.note("length", self.lengths[i])
        self.returns[done], self.lengths[done] = 0, 0
        self.episodes += int(done.sum())

    def log_row(self, seconds: float) -> dict:
        mean = {k: float(np.mean(v)) if v else float("nan") for k, v in self.notes.items()}
        row = {"steps": self.steps, "updates": self.agent.updates, "episodes": self.episodes,
               "epsilon": round(epsilon_at(self.cfg, self.steps), 4)}
        for key in ("return", "success", "length", "loss", "q_mean"):
            row[key] = mean.pop(key, float("nan"))
        row.update(mean)
        row["seconds"] = round(seconds, 1)
        self.curve.append(row)
        self.notes = {k: [] for k in self.notes}
        self.write_curve()
        return row

    def write_curve(self) -> None:
        keys = list(dict.fromkeys(k for row in self.curve for k in row))
        text = io.StringIO(newline="")
        writer = csv.DictWriter(text, fieldnames=keys, restval="")
        writer.writeheader()
        writer.writerows(self.curve)
        write_file(self.out / "curve.csv", text.getvalue())
        try:
            from ..viz import learning_curve_png
            learning_curve_png(self.curve, self.out / "curve.png", title=f"{self.run_name()}: "
                               f"{self.cfg.variant} on {self.cfg.scenario}, seed {self.cfg.seed}")
        except Exception as e:  # a plotting problem must never stop a training run
            print(f"warning: learning-curve PNG not written: {e}")

    def run_name(self) -> str:
        """The run's folder and its parent (``reward/yours``, ``agent/d3rqn_s0``): what
        names the run in its learning curve's title."""
        return "/".join(self.out.resolve().parts[-2:])

    # -- files ---------------------------------------------------------------------------
    def save_model(self, path, extra: dict | None = None) -> Path:
        """The online weights, with how they were trained (``train_config``: evaluate and
        fly read its action table and camera)."""
        meta = {"kind": "qnet", "qnet_config": self.agent.qnet_config.to_dict(),
                "train_config": as_dict(self.cfg), "steps": self.steps,
                "updates": self.agent.updates, **(extra or {})}
        return self.agent.online.save(path, meta)

    def save_checkpoint(self) -> Path:
        parts = {"agent": self.agent, "replay": self.replay, "env": self.env,
                 **self.extra}
        arrays = {f"{name}.{k}": v for name, part in parts.items()
                  for k, v in part.state_dict().items()}
        arrays.update(stacker=self.stacker.buf, returns=self.returns, lengths=self.lengths)
        if self.state is not None:
            arrays["state_h"], arrays["state_c"] = self.state[0].data, self.state[1].data
        meta = {"config": as_dict(self.cfg), "settings": self.settings,
                "steps": self.steps, "episodes": self.episodes,
                "update_credit": self.update_credit, "curve": self.curve, "notes": self.notes,
                "rng": json.dumps(self.rng.bit_generator.state),
                "replay_rng": json.dumps(self.replay.rng.bit_generator.state),
                "env_meta": self.env.meta_state()}
        path = save_npz(self.out / "checkpoint.npz", arrays, meta)
        self.save_model(self.out / "model.npz")
        return path

    def load_checkpoint(self) -> None:
        """Continue from ``out_dir/checkpoint.npz`` (``check_resume``: ValueError if it was
        made with other settings; ``DamagedCheckpoint`` if its contents do not fit)."""
        from ..autograd import Tensor
        arrays, meta = load_npz(self.out / "checkpoint.npz")
        check_resume(meta, self.settings, self.out)

        def part(prefix):
            return {k[len(prefix) + 1:]: v for k, v in arrays.items()
                    if k.startswith(prefix + ".")}
        with reading_checkpoint(self.out / "checkpoint.npz"):
            check_checkpoint_weights(arrays)
            self.agent.load_state_dict(part("agent"))
            self.replay.load_state_dict(part("replay"))
            self.env.load_state_dict(part("env"), meta["env_meta"])
            for name, obj in self.extra.items():
                obj.load_state_dict(part(name))
            self.stacker.buf[...] = arrays["stacker"]
            self.returns[...], self.lengths[...] = arrays["returns"], arrays["lengths"]
            if "state_h" in arrays:
                self.state = (Tensor(arrays["state_h"].copy()),
                              Tensor(arrays["state_c"].copy()))
            self.steps, self.episodes = meta["steps"], meta["episodes"]
            self.update_credit, self.curve, self.notes = (meta["update_credit"],
                                                          meta["curve"], meta["notes"])
            self.rng.bit_generator.state = json.loads(meta["rng"])
            self.replay.rng.bit_generator.state = json.loads(meta["replay_rng"])


def check_resume(meta: dict, settings: dict, where) -> None:
    """ValueError unless a run of ``settings`` ({name: value}) may continue the checkpoint
    with metadata ``meta`` (in folder ``where``): every setting the same but those of
    MAY_CHANGE_ON_RESUME, and no fewer steps than it has done. The message names each
    differing setting with both values."""
    if not (isinstance(meta, dict) and isinstance(meta.get("steps"), int)
            and isinstance(meta.get("settings") or meta.get("config"), dict)):
        raise ValueError(f"resume: the checkpoint in {str(where)!r} is not one of train-agent "
                         f"or distil")
    if meta["steps"] < 0 or not isinstance(meta.get("episodes", 0), int) \
            or meta.get("episodes", 0) < 0:
        raise ValueError(f"resume: the checkpoint in {str(where)!r} records an impossible "
                         f"count ({meta['steps']} steps, {meta.get('episodes')} episodes); "
                         f"start afresh with --overwrite")
    saved = meta.get("settings") or flat_settings(meta["config"])
    made, now = (("distil" if "teachers" in s else "train-agent") for s in (saved, settings))
    if made != now:
        raise ValueError(f"resume: the run in {str(where)!r} was made by {made}, not {now}")
    changed = changed_settings(saved, settings, MAY_CHANGE_ON_RESUME)
    if changed:
        raise ValueError(f"resume: the checkpoint in {str(where)!r} was made with other "
                         f"settings: {'; '.join(changed)}; give the run's own (its model "
                         f"file records its command), or start afresh")
    if meta["steps"] > settings["steps"]:
        raise ValueError(f"resume: the run in {str(where)!r} is at {meta['steps']} steps "
                         f"already, beyond steps {settings['steps']}; give at least "
                         f"{meta['steps']}")


def epsilon_greedy(run: Run) -> np.ndarray:
    """Step 1 of the paper's loop: epsilon-greedy actions on the online net, the
    recurrent state advanced for every flight."""
    eps = epsilon_at(run.cfg, run.steps)
    actions, _, run.state = run.agent.act(run.stacker.obs, run.state, eps, run.rng)
    return actions


def double_q_update(run: Run, batch) -> dict:
    """Step 4 of the paper's loop: one double-Q update on a batch of windows."""
    return run.agent.update(batch)


def start_run(cfg: TrainConfig, out_dir, depth_estimator=None, resume: bool = False,
              load_init=None, **kwargs) -> Run:
    """A new run (the online net from ``cfg.init_model`` if set, read by
    ``load_init(agent, path)`` if given), or with ``resume`` the run in ``out_dir``
    continued from its checkpoint, if it has one. ``kwargs``: Run's."""
    run = Run(cfg, out_dir, depth_estimator, **kwargs)
    if resume and (run.out / "checkpoint.npz").is_file():
        run.load_checkpoint()
        return run
    if cfg.init_model:
        if load_init is None:
            run.agent.online.load(cfg.init_model)
        else:
            load_init(run.agent, cfg.init_model)
        run.agent.target.copy_from(run.agent.online)
    run.start()
    return run


def train(cfg: TrainConfig, out_dir, depth_estimator=None, *, reward_fn=None, depth_fn=None,
          td_target=None, progress: bool = True, resume: bool = False, run: Run | None = None,
          act=epsilon_greedy, learn=double_q_update, settings: dict | None = None) -> Run:
    """Train a Q-net as the module docstring says; returns the run (``run.agent.online``
    is the net; ``out_dir`` holds model.npz, checkpoint.npz and the learning curve).

    ``depth_estimator``: the DispNet for ``cfg.depth="pred"``. ``reward_fn(d_nearest,
    collided[, yaw_rate])``: the reward (default the paper's Eq. 4); ``depth_fn(depth,
    rng)``: a change of every depth map the Q-net sees; ``td_target``: the TD target
    (default ``agent.double_q_targets``). ``resume``: continue the run in ``out_dir``
    from its checkpoint (``settings``: Run's). A method built on this loop passes its own
    ``run`` (made by ``start_run``) and steps 1 and 4 (``act(run) -> actions``,
    ``learn(run, batch) -> {"loss", "q_mean", ...}``). Ctrl-C stops the loop at the end
    of a step: the checkpoint is saved, then ``io.RunStopped`` is raised."""
    if run is None:
        run = start_run(cfg, out_dir, depth_estimator, resume, reward_fn=reward_fn,
                        depth_fn=depth_fn, td_target=td_target, settings=settings)
    cfg = run.cfg
    t0 = time.time() - (run.curve[-1]["seconds"] if run.curve else 0.0)
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=cfg.steps, initial=run.steps, unit="step", dynamic_ncols=True,
                   desc=f"train {cfg.variant}")
    next_log = (run.steps // cfg.log_every + 1) * cfg.log_every
    next_checkpoint = (run.steps // cfg.checkpoint_every + 1) * cfg.checkpoint_every
    with StopRequest() as stop:      # Ctrl-C: stop at the end of a step, checkpoint saved
        while run.steps < cfg.steps and not stop.requested:
            # 1. act
            actions = act(run)
            # 2. step the flights; what the Q-net reads of the depth they see
            obs, rewards, terminated, truncated, info = run.env.step(actions)
            done = terminated | truncated
            final = encode_depth(info["final_obs"])     # before a finished flight restarts
            frames = final.copy()
            frames[done] = encode_depth(obs[done])      # a new episode's first frame
            # 3. store the transitions; a finished flight starts a new episode
            run.replay.add_step(actions, rewards, terminated, truncated, final)
            run.episodes_end(rewards, info["is_success"], done)
            if done.any():
                run.replay.start_episodes(np.flatnonzero(done), frames[done])
                run.state = run.agent.reset_state(run.state, done)
            run.stacker.push(frames[~done], np.flatnonzero(~done))
            if done.any():
                run.stacker.reset(np.flatnonzero(done), frames[done])
            run.steps += cfg.n_envs
            # 4. learn from windows of the replay
            if run.steps >= cfg.learning_starts:
                run.update_credit += cfg.updates_per_step
                while run.update_credit >= 1.0:
                    run.update_credit -= 1.0
                    info = learn(run, run.replay.sample(cfg.batch_size, cfg.window(), cfg.stack))
                    run.note("loss", info["loss"])
                    run.note("q_mean", info["q_mean"])
            if bar is not None:
                bar.update(cfg.n_envs)
            # 5. log
            if run.steps >= next_log:
                row = run.log_row(time.time() - t0)
                next_log += cfg.log_every
                if bar is not None:
                    bar.set_postfix(success=f"{row['success']:.2f}", ret=f"{row['return']:.1f}",
                                    eps=f"{row['epsilon']:.2f}")
            # 6. checkpoint
            if run.steps >= next_checkpoint:
                run.save_checkpoint()
                next_checkpoint += cfg.checkpoint_every
                if bar is None:                   # no bar: one line per checkpoint instead
                    success = run.curve[-1]["success"] if run.curve else float("nan")
                    print(f"{run.out.name}: {run.steps}/{cfg.steps} steps, success "
                          f"{success:.2f}, {time.time() - t0:.0f} s", flush=True)
        if bar is not None:
            bar.close()
        run.save_checkpoint()
    if run.steps < cfg.steps:
        raise RunStopped(f"stopped at {run.steps} of {cfg.steps} steps; the checkpoint is in "
                         f"{str(run.out)!r}")
    return run

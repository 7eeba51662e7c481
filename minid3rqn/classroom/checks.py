"""The eight exercises, one checker each: does the student's change work, and does it
reach the code?

A checker loads the student's file, calls what it defines on known inputs, then pushes
it through the real library code (the environment, the Q-network, the replay,
gradcheck, the depth loss) on tiny problems. Every call into the student's code goes
through ``student.call`` (a time limit, and one readable line for anything that goes
wrong). Every failure says what was expected, what came, and how to fix it. Checkers run
in a second and never train anything.

    check_reward(path) -> Report        (one ``check_<exercise>`` per exercise)
    EXERCISES["reward"].checker(path)   the same, found by name; ``find("1")``
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..depth.evaluate import log_error_parts
from ..world.stepper import accepts_yaw_rate
from .student import TEMPLATES, Report, Stop, call, describe, get, load, where_in


@dataclass(frozen=True)
class Exercise:
    number: int
    name: str            # what the student types: python -m minid3rqn check <name>
    title: str
    filename: str        # the template in classroom/templates/, the student's copy in exercises/
    checker: Callable    # checker(path) -> Report
    doc: str             # the sheet, in docs/exercises/
    trains: str          # "agent", "depth" or "" (nothing to run beyond the check)


EXERCISES: dict[str, Exercise] = {}


def exercise(number: int, name: str, title: str, filename: str, doc: str, trains: str = ""):
    """Register ``body(module, report)`` as the checker of an exercise: the returned
    ``check(path) -> Report`` loads the file, runs ``body``, and records what broke."""
    def register(body):
        def check(path) -> Report:
            r = Report(f"{number} ({name})", path, TEMPLATES / filename)
            try:
                r.module = load(path, r)
                body(r.module, r)
            except Stop:
                pass
            except Exception as e:  # noqa: BLE001
                if where_in(path, e):       # raised inside the student's file
                    r.fail(f"your code raised {describe(e, path)}")
                else:                       # the library broke, not the student's file
                    r.fail(f"the checker itself failed: {describe(e, path)}",
                           hint="this looks like a problem in minid3rqn, not in your file: "
                                "tell your teacher, with this message")
            return r
        check.__name__, check.__doc__ = body.__name__, body.__doc__
        EXERCISES[name] = Exercise(number, name, title, filename, check,
                                   f"docs/exercises/{doc}", trains)
        return check
    return register


def find(name_or_number: str) -> Exercise:
    """'reward', '1', 'depth_loss' ... -> the Exercise; ValueError listing them otherwise."""
    key = str(name_or_number).strip().lower().replace("_", "-")
    for e in EXERCISES.values():
        if key in (e.name, str(e.number), f"{e.number:02d}", e.filename[:-3].replace("_", "-")):
            return e
    names = ", ".join(f"{e.number}={e.name}" for e in EXERCISES.values())
    raise ValueError(f"unknown exercise {name_or_number!r}; choose one of: {names}")


def _env(n: int, **params):
    """The env training, evaluation and ``fly`` fly, with the student's ``params``; a pool
    of 2 worlds, not 32: a check must be quick."""
    from ..world import DroneEnv
    return DroneEnv("basic", n, seed=0, n_worlds=2, **params)


# -- Exercise 1: the reward ------------------------------------------------------------
D_GRID = np.array([0.5, 0.6, 0.8, 1.0, 1.5, 2.0, 3.0, 5.0, 8.0, 12.0])
RATES = [0.0, 0.25, -0.25, 0.5, -0.5]            # the yaw rates of the paper's Table 3


def _number(r: Report, value, what: str) -> float:
    if value is None:
        r.fail(f"{what} returned None", hint="did you forget the `return`?", stop=True)
    arr = np.asarray(value)
    if arr.dtype.kind not in "fiub" or arr.size != 1:
        r.fail(f"{what} must return one number for number inputs; got {value!r}", stop=True)
    x = float(arr.reshape(()))
    if not math.isfinite(x):
        r.fail(f"{what} returned {x}; rewards must be finite numbers",
               hint="look for a division by zero or a log of 0", stop=True)
    return x


@exercise(1, "reward", "Reward: penalise turning, or clip/scale d_nearest", "reward.py",
          "01_reward.md", "agent")
def check_reward(m, r):
    fn = get(r, m, "reward", function=True)
    sees_yaw = accepts_yaw_rate(fn)
    rates = RATES if sees_yaw else [0.0]

    def R(d, c, w=0.0):
        args = (d, c, w) if sees_yaw else (d, c)
        return _number(r, call(r, f"reward{args}", fn, *args), f"reward{args}")

    safe = {(d, w): R(float(d), False, w) for d in D_GRID for w in rates}
    r.ok("reward(d_nearest, collided" + (", yaw_rate)" if sees_yaw else ")") + " gives finite "
         "numbers for d_nearest from 0.5 to 12 m"
         + (" and every yaw rate of the paper's table" if sees_yaw else ""))
    hit = {w: R(0.3, True, w) for w in rates}
    worst = min(safe.values())
    bad = [w for w, v in hit.items() if not v < worst]
    if bad:
        r.fail("a collision must be worse than any safe step: reward(0.3, True"
               + (f", {bad[0]}" if sees_yaw else "") + f") = {hit[bad[0]]:g}, but a safe step "
               f"can earn as little as {worst:g}",
               hint="keep -1 on collision (np.where(collided, -1.0, ...)), and make sure "
                    "safe rewards stay above it")
    else:
        r.ok(f"a collision gives {hit[0.0]:g}, below every safe reward (lowest {worst:g})")
        if any(abs(v + 1.0) > 1e-12 for v in hit.values()):
            r.note(f"the paper gives -1 on collision; yours gives {hit[0.0]:g}")
    _reward_on_arrays(r, fn, sees_yaw, R)
    _reward_changes(r, safe, hit, sees_yaw)
    _reward_reaches_training(r, fn)
    r.summary = {"sees_yaw_rate": sees_yaw, "collision_reward": hit[0.0]}


def _reward_on_arrays(r, fn, sees_yaw: bool, R) -> None:
    """Arrays in, arrays out, the same values as number by number (``R``: one call)."""
    ds = np.array([0.5, 0.7, 1.2, 2.5, 4.0, 9.0, 0.4, 0.45])
    cs = np.array([False, False, False, False, False, False, True, True])
    ws = np.array([0.0, 0.25, -0.5, 0.5, -0.25, 0.0, 0.5, 0.0])
    what = "reward(array_of_d, array_of_collided" + (", array_of_yaw)" if sees_yaw else ")")
    out = call(r, what, fn, *((ds, cs, ws) if sees_yaw else (ds, cs)))
    arr = None if out is None else np.asarray(out, dtype=np.float64)
    if arr is None or arr.shape != ds.shape:
        r.fail(f"with arrays of {len(ds)} flights reward must return an array of shape "
               f"{ds.shape}; got {None if arr is None else arr.shape}",
               hint="use np.where / np.minimum / np.abs so every entry is handled; "
                    "`float(...)` or `if` would squash the array", stop=True)
    one_by_one = np.array([R(float(d), bool(c), float(w)) for d, c, w in zip(ds, cs, ws)])
    if not np.allclose(arr, one_by_one, rtol=1e-6, atol=1e-9):
        k = int(np.argmax(np.abs(arr - one_by_one)))
        r.fail(f"arrays and numbers disagree: for flight {k} (d={ds[k]}, collided={cs[k]}"
               + (f", yaw={ws[k]}" if sees_yaw else "") + f") the array call gives "
               f"{arr[k]:g} but the number call gives {one_by_one[k]:g}", stop=True)
    r.ok("works on arrays (all flights at once), same values as one by one")


def _reward_changes(r, safe: dict, hit: dict, sees_yaw: bool) -> None:
    """Did the reward change from the paper's, and how (``safe``: safe steps by (d, yaw);
    ``hit``: collisions by yaw)?"""
    from ..world import paper_reward
    changed = [k for k in safe if abs(safe[k] - float(paper_reward(k[0], False))) > 1e-9]
    if not changed and all(abs(v + 1.0) <= 1e-12 for v in hit.values()):
        r.fail("your reward is still the paper's (d_nearest, or -1 on collision)",
               hint="penalise turning (e.g. d_nearest - 2.0 * np.abs(yaw_rate)) or clip or "
                    "scale d_nearest (e.g. np.minimum(d_nearest, 3.0)); see the docstring",
               stop=True)
    cost = {w: safe[(2.0, 0.0)] - safe[(2.0, w)] for w in RATES[1:]} if sees_yaw else {}
    if any(abs(c) > 1e-9 for c in cost.values()):
        if all(c > 0 for c in cost.values()):
            r.ok("turning is penalised: at d = 2 m, " + ", ".join(
                f"yaw {w:+.2f} costs {c:.3g}" for w, c in cost.items()))
            if abs(cost[0.5] - cost[-0.5]) > 1e-9:
                r.note("left and right turns are penalised differently; intended?")
            if cost[0.5] + 1e-12 < cost[0.25]:
                r.note("a sharp turn costs less than a gentle one; intended?")
        else:
            w = min(cost, key=cost.get)
            r.fail(f"your reward depends on the yaw rate but does not penalise turning: "
                   f"reward(2.0, False, {w}) = {safe[(2.0, w)]:g} >= reward(2.0, False, 0.0) "
                   f"= {safe[(2.0, 0.0)]:g}", hint="subtract a positive cost that grows with "
                                                  "|yaw_rate|")
    straight = np.array([safe[(d, 0.0)] for d in D_GRID])
    if np.any(np.abs(straight - D_GRID) > 1e-9):
        pairs = ", ".join(f"d={d:g}: {v:.3g}"
                          for d, v in zip(D_GRID[[0, 5, 9]], straight[[0, 5, 9]]))
        r.ok(f"flying straight, your reward differs from the paper's d_nearest ({pairs})")
    if np.any(np.diff(straight) < -1e-9):
        r.note("your reward decreases with the distance to obstacles somewhere: flying "
               "farther from obstacles should not be worse")
    if np.max(np.abs(list(safe.values()))) > 100:
        r.note("rewards above 100 in size make Q-values large; the agent multiplies "
               "rewards by 0.1, but consider scaling down")


def _reward_reaches_training(r, fn) -> None:
    """The reward reaches the environment (the one that trains and flies)."""
    env = _env(4, reward_fn=fn, observation=None)
    env.reset()
    _, rewards, *_ = call(r, "DroneEnv(reward_fn=reward).step", env.step, np.array([0, 1, 3, 4]))
    if not np.all(np.isfinite(rewards)):
        r.fail(f"in the environment your reward gave {rewards}", stop=True)
    shown = [round(float(x), 3) for x in rewards]
    r.ok(f"reaches the environment that trains and flies (rewards {shown})")


# -- Exercise 2: the action table ------------------------------------------------------
PAPER_ACTIONS = np.array([[2.0, 0.0], [2.0, 0.25], [2.0, -0.25], [2.0, 0.5], [2.0, -0.5]])


@exercise(2, "actions", "Actions: a sharper turn or a second speed", "actions.py",
          "02_actions.md", "agent")
def check_actions(m, r):
    raw = get(r, m, "ACTIONS")
    try:
        table = np.array(raw, dtype=np.float64)
    except (TypeError, ValueError) as e:
        r.fail(f"ACTIONS must be a list of [speed, yaw_rate] rows of numbers; NumPy could "
               f"not read it ({e})", stop=True)
    if table.ndim != 2 or table.shape[1] != 2:
        r.fail(f"ACTIONS must be rows of two numbers [forward speed, yaw rate]; got shape "
               f"{table.shape}", hint="e.g. [[2.0, 0.0], [2.0, 0.25], ...]", stop=True)
    n = len(table)
    if n < 2:
        r.fail(f"ACTIONS needs at least 2 rows; got {n}", stop=True)
    if not np.all(np.isfinite(table)):
        r.fail("ACTIONS holds a non-finite number (nan or inf)", stop=True)
    r.ok(f"{n} actions of (forward speed, yaw rate)")
    if np.any(table[:, 0] <= 0):
        k = int(np.flatnonzero(table[:, 0] <= 0)[0])
        r.fail(f"row {k} {table[k].tolist()} has forward speed {table[k, 0]:g}: every speed "
               f"must be > 0", hint="a drone that can stop would hover and 'survive' 50 steps "
                                    "without flying anywhere; use a slower speed such as 1.0 "
                                    "instead", stop=True)
    if len(np.unique(table, axis=0)) < n:
        r.fail("two rows of ACTIONS are identical; each action must be different",
               hint="two identical actions share one Q-value and split the learning", stop=True)
    new = [row.tolist() for row in table if not any(np.allclose(row, p) for p in PAPER_ACTIONS)]
    gone = [p.tolist() for p in PAPER_ACTIONS if not any(np.allclose(row, p) for row in table)]
    if not new and not gone:
        r.fail("ACTIONS is still the paper's Table 3",
               hint="add rows, e.g. [2.0, 0.75] and [2.0, -0.75] (sharper turns) or "
                    "[1.0, 0.0] (a second, slower speed)", stop=True)
    r.ok("changed from the paper's table: added " + (str(new) if new else "nothing")
         + (f", removed {gone}" if gone else ""))
    _actions_notes(r, table)
    _actions_reach_training(r, table)
    r.summary = {"n_actions": n, "added": new, "removed": gone}


def _actions_notes(r, table: np.ndarray) -> None:
    rates = table[:, 1]
    if not np.any(np.abs(rates) < 1e-12):
        r.note("no action flies straight (yaw rate 0): the drone will always be turning")
    if any(not np.any(np.isclose(rates, -w)) for w in rates):
        r.note("the turns are not symmetric (some left turn has no matching right turn)")
    turning = np.abs(rates) > 1e-12
    if turning.any():
        radius = float(np.min(table[turning, 0] / np.abs(rates[turning])))
        r.note(f"tightest turning radius v/|yaw rate| = {radius:.2f} m (paper: 4 m)")
    if np.any(table[:, 0] > 4.0):
        r.note("speeds above 4 m/s cover a lot of ground in 0.4 s: obstacles get close fast")
    if len(table) > 11:
        r.note(f"{len(table)} actions: a large head learns slowly within a short budget")


def _actions_reach_training(r, table: np.ndarray) -> None:
    """The table reaches the environment (the one that trains and flies) and the Q-net's
    head."""
    from ..nets.qnet import QNet
    from ..rl.train import TrainConfig
    from ..world import sample_start_pose
    n = len(table)
    env = _env(1, actions=table, observation=None)
    env.reset()
    room = sample_start_pose(env.scenes[0], np.random.default_rng(0), env.actions, env.dt,
                             env.safe_distance)         # room to fly any action for a step
    env.reset(options={"pose": room})
    before = env.poses[0, 2]
    _, _, term, _, _ = call(r, f"DroneEnv(actions=ACTIONS).step([{n - 1}])", env.step,
                            np.array([n - 1]))
    turned, want = float(env.poses[0, 2] - before), table[n - 1, 1] * env.dt
    if env.n_actions != n or (not term[0] and abs(turned - want) > 1e-6):
        r.fail(f"the environment sees {env.n_actions} actions (expected {n}), and after "
               f"action {n - 1} the drone turned {turned:.3f} rad (expected {want:.3f})",
               stop=True)
    r.ok(f"the environment that trains and flies flies the new action {n - 1} "
         f"({table[n - 1].tolist()}: turned {turned:+.2f} rad in 0.4 s)")
    cfg = TrainConfig(hidden=16).qnet_config(env.n_actions, env.frame_shape)
    q, _ = QNet(cfg, rng=0)(np.zeros((1, 1, cfg.in_channels) + tuple(env.frame_shape),
                                     np.float32))
    if q.shape[-1] != n:
        r.fail(f"the Q-network has {q.shape[-1]} outputs, not {n}", stop=True)
    r.ok(f"the Q-network's head has {n} outputs, one per action")


# -- Exercise 3: the field of view -----------------------------------------------------
@exercise(3, "fov", "Field of view: narrow the camera, D3RQN vs D3QN", "camera.py",
          "03_field_of_view.md", "agent")
def check_fov(m, r):
    from ..world import Camera
    fov = get(r, m, "HFOV_DEG")
    if isinstance(fov, bool) or not isinstance(fov, (int, float, np.integer, np.floating)):
        r.fail(f"HFOV_DEG must be a number of degrees; got {fov!r}", stop=True)
    fov = float(fov)
    if not 0.0 < fov < 180.0:
        r.fail(f"HFOV_DEG must lie between 0 and 180 degrees; got {fov:g}", stop=True)
    cam = call(r, f"Camera(hfov_deg={fov:g})", Camera, 32, 104, fov)
    r.ok(f"a 32x104 camera with a {fov:g} degree view: fx = {cam.fx:.1f} px "
         f"(90 degrees: 52.0 px)")
    if fov == 90.0:
        r.fail("HFOV_DEG is still 90 degrees",
               hint="narrow it, e.g. HFOV_DEG = 60 (then 45)", stop=True)
    if fov > 90.0:
        r.note("wider than 90 degrees: the exercise asks for a narrower view, but a wider "
               "one is a fine extra experiment (memory should matter less)")
    if fov < 20:
        r.note(f"{fov:g} degrees is a keyhole: the drone sees about one obstacle at a time")
    frames, _ = _env(2, camera=cam).reset()
    if frames.shape != (2, 32, 104):
        r.fail(f"frames came out {frames.shape}, expected (2, 32, 104)", stop=True)
    r.ok(f"the environment renders with your camera (each column spans "
         f"{fov / 104:.2f} degrees instead of {90 / 104:.2f})")
    r.summary = {"hfov_deg": fov}


# -- Exercise 4: memory ----------------------------------------------------------------
@exercise(4, "memory", "Memory: sequence length 1 vs 5 vs 10", "memory.py", "04_memory.md",
          "agent")
def check_memory(m, r):
    from ..rl.replay import EpisodeReplay
    L = get(r, m, "SEQ_LEN")
    if isinstance(L, bool) or not isinstance(L, (int, np.integer)):
        r.fail(f"SEQ_LEN must be a whole number such as 1, 5 or 10; got {L!r}",
               hint="no quotes, no decimal point: SEQ_LEN = 10", stop=True)
    L = int(L)
    if not 1 <= L <= 50:
        r.fail(f"SEQ_LEN must be from 1 to 50 (a flight lasts at most 50 steps); got {L}",
               stop=True)
    r.ok(f"SEQ_LEN = {L}")
    if L == 5:
        r.note("5 is the paper's value: run it once, then try 1 and 10")
    if L == 1:
        r.note("with windows of 1 step the LSTM always starts from a zero state in "
               "training: it cannot learn to use what it saw before")
    if L > 20:
        r.note(f"an update costs about {L / 5:.0f}x the paper's: training gets slower")
    rep = EpisodeReplay(200, 1, (4, 6), seed=0)
    frame = np.zeros((1, 4, 6), np.float32)
    for _ in range(2):
        rep.start_episodes(np.array([0]), frame)
        for t in range(max(L, 3) + 2):
            rep.add_step(np.array([t % 5]), np.ones(1, np.float32), np.array([False]),
                         np.array([False]), frame)
    batch = call(r, f"replay.sample(batch 8, seq_len {L})", rep.sample, 8, L)
    if batch.actions.shape != (L, 8):
        r.fail(f"the replay gave windows of shape {batch.actions.shape}, expected {(L, 8)}",
               stop=True)
    r.ok(f"the replay samples windows of {L} step{'s' if L > 1 else ''}")
    r.summary = {"seq_len": L}


# -- Exercise 5: ablations (dueling, double-Q) -----------------------------------------
def _targets_reference(qo, qt, rew, term, gamma):
    best = np.argmax(qo, axis=-1)
    double = np.take_along_axis(qt, best[..., None], -1)[..., 0]
    boot = gamma * (1.0 - term)
    return {"double": rew + boot * double, "single": rew + boot * qt.max(-1),
            "online": rew + boot * qo.max(-1)}


TARGETS = {"double": "double Q-learning (the online net picks a', the target net values it)",
           "single": "no double-Q: the target net picks and values a' (classic DQN)",
           "online": "the online net picks and values a': this removes the target network too"}


@exercise(5, "ablation", "Ablations: remove dueling, remove double-Q", "ablation.py",
          "05_ablations.md", "agent")
def check_ablation(m, r):
    dueling = get(r, m, "DUELING")
    if not isinstance(dueling, (bool, np.bool_)):
        r.fail(f"DUELING must be True or False; got {dueling!r}", stop=True)
    fn = get(r, m, "td_target", function=True)
    rng = np.random.default_rng(0)
    L, B, A = 4, 6, 5
    qo, qt = rng.standard_normal((2, L, B, A))
    rew = rng.uniform(-1, 3, (L, B))
    term = (rng.random((L, B)) < 0.3).astype(np.float64)
    term[0, 0], term[0, 1] = 1.0, 0.0
    qo[0, 1], qt[0, 1] = [0, 3, 0, 0, 0], [0, 0, 2, 0, 0]   # they disagree on the best a'
    y = call(r, "td_target(...) on a batch of shape (L=4, B=6, A=5)", fn, qo.copy(),
             qt.copy(), rew.copy(), term.copy(), 0.99)
    y = None if y is None else np.asarray(y, dtype=np.float64)
    if y is None or y.shape != (L, B):
        r.fail(f"td_target must return one target per step, shape {(L, B)}; got "
               f"{None if y is None else y.shape}",
               hint="reduce over the action axis (axis=-1), e.g. with .max(axis=-1)", stop=True)
    if not np.all(np.isfinite(y)):
        r.fail("td_target returned non-finite values", stop=True)
    if not np.allclose(y[term == 1], rew[term == 1]):
        r.fail("on a collision step (terminal = 1) the target must be the reward alone: "
               "there is no next state to bootstrap from",
               hint="multiply the bootstrap term by (1 - terminals)", stop=True)
    r.ok("terminal steps: y = r")
    refs = _targets_reference(qo, qt, rew, term, 0.99)
    kind = next((k for k, v in refs.items() if np.allclose(y, v, atol=1e-6)), None)
    if kind is None:
        r.fail("td_target matches neither the double-Q target nor the classic DQN target",
               hint="classic DQN: "
                    "rewards + gamma * (1 - terminals) * q_target_next.max(axis=-1)", stop=True)
    r.ok(f"td_target is {TARGETS[kind]}")
    if kind == "online":
        r.note("a bigger change than asked: the exercise keeps the target network and "
               "uses q_target_next.max(axis=-1)")
    r.ok(f"DUELING = {bool(dueling)}: " + ("value + advantage streams" if dueling else
                                            "a single Q head (no dueling)"))
    if dueling and kind == "double":
        r.fail("nothing is removed yet: this is the full D3RQN",
               hint="set DUELING = False, or write the classic DQN target in td_target "
                    "(one change at a time is the cleanest ablation)", stop=True)
    if not dueling and kind != "double":
        r.note("two ingredients removed at once: compare with single ablations too")
    variant = "d3rqn" if dueling else "ddrqn"
    r.ok(f"trains as variant {variant} (dueling={bool(dueling)}, recurrent=True)")
    r.summary = {"dueling": bool(dueling), "target": kind, "variant": variant}


# -- Exercise 6: a new autograd op -----------------------------------------------------
@exercise(6, "op", "Autograd: a new op (leaky ReLU) with its backward", "my_op.py",
          "06_autograd_op.md")
def check_op(m, r):
    from ..autograd import Tensor
    fn = get(r, m, "leaky_relu", function=True)
    x = np.array([[-2.0, -0.5, -0.1, 0.3], [0.7, 1.5, -1.2, 2.2]])
    for slope in (0.01, 0.2):
        out = call(r, f"leaky_relu(Tensor(x), slope={slope})", fn, Tensor(x), slope)
        if not isinstance(out, Tensor):
            r.fail(f"leaky_relu must return a Tensor; got {type(out).__name__}",
                   hint="return Tensor.from_op(y, (x,), vjp, 'leaky_relu')", stop=True)
        want = np.where(x > 0, x, slope * x)
        if out.shape != x.shape:
            r.fail(f"output shape {out.shape} differs from the input's {x.shape}", stop=True)
        if not np.allclose(out.data, want, rtol=1e-12, atol=1e-12):
            k = np.unravel_index(np.argmax(np.abs(out.data - want)), x.shape)
            r.fail(f"forward is wrong at x = {x[k]}: got {out.data[k]:g}, expected "
                   f"{want[k]:g} (slope {slope})",
                   hint="y = x where x > 0, else slope * x: np.where(x.data > 0, ...)",
                   stop=True)
    r.ok("forward: y = x for x > 0, slope * x otherwise (slopes 0.01 and 0.2)")
    out32 = call(r, "leaky_relu on float32", fn, Tensor(x.astype(np.float32)), 0.1)
    if out32.dtype != np.float32:
        r.fail(f"float32 in must give float32 out (training runs in float32); got "
               f"{out32.dtype}", hint="multiply by the slope without making a float64 array, "
                                      "e.g. x.data * np.asarray(slope, x.dtype)")
    else:
        r.ok("keeps float32 as float32")
    default = call(r, "leaky_relu(x) with the default slope", fn, Tensor(x))
    if not np.allclose(default.data, np.where(x > 0, x, 0.01 * x)):
        r.note("the default slope is not 0.01")
    _op_backward(r, fn, x)


def _op_backward(r, fn, x: np.ndarray) -> None:
    """The op's backward: its own vjp, checked by gradcheck; no graph inside no_grad()."""
    from ..autograd import Tensor, gradcheck, no_grad
    leaf = Tensor(x.copy(), requires_grad=True)
    y = call(r, "leaky_relu(leaf with requires_grad)", fn, leaf, 0.2)
    if not y.requires_grad:
        r.fail("the output does not require grad although the input does: the graph is cut",
               hint="build the output with Tensor.from_op(y, (x,), vjp, name)", stop=True)
    parents = getattr(y, "_parents", ())
    if len(parents) != 1 or parents[0] is not leaf:
        r.fail("leaky_relu is built from other Tensor ops, so autograd wrote the backward "
               "for you",
               hint="compute y with NumPy on x.data and return Tensor.from_op(y, (x,), vjp, "
                    "'leaky_relu') with your own vjp(g)", stop=True)
    xs = np.random.default_rng(0).standard_normal((3, 5))
    xs = np.where(np.abs(xs) < 0.05, 0.3, xs)           # stay off the kink at 0
    hint = ("dy/dx = 1 for x > 0, slope otherwise: vjp(g) must return "
            "(g * (1 where x > 0, slope elsewhere),), a tuple")
    call(r, "leaky_relu(x) * x, slope 0.1", gradcheck, lambda t: fn(t, 0.1) * t, [xs], hint=hint)
    call(r, "leaky_relu(x), slope 0.3", gradcheck, lambda t: fn(t, 0.3), [xs], hint=hint)
    r.ok("backward: passes gradcheck (dy/dx agrees with central differences, float64)")
    with no_grad():
        z = call(r, "leaky_relu inside no_grad()", fn, Tensor(x, requires_grad=True))
    if z.requires_grad:
        r.fail("inside no_grad() the output must not record a graph", stop=True)
    r.ok("records no graph inside no_grad()")


# -- Exercise 7: the photometric error of the depth loss -------------------------------
@exercise(7, "depth-loss", "Depth: photometric loss L1 vs SSIM + L1", "photometric.py",
          "07_depth_loss.md", "depth")
def check_photometric(m, r):
    from ..autograd import Tensor, gradcheck
    fn = get(r, m, "photometric_error", function=True)
    rng = np.random.default_rng(0)
    t = rng.uniform(0.2, 0.8, (2, 3, 8, 10))
    p = np.clip(t + rng.normal(0, 0.1, t.shape), 0, 1)
    out = call(r, "photometric_error(pred, target) on (2, 3, 8, 10) images", fn,
               Tensor(p), Tensor(t))
    if not isinstance(out, Tensor):
        r.fail(f"photometric_error must return a Tensor; got {type(out).__name__}",
               hint="use autograd ops (ag.mean, ag.abs, +, *) on the inputs", stop=True)
    if out.shape != (2, 1, 8, 10):
        r.fail(f"the error must have shape (N, 1, H, W) = (2, 1, 8, 10); got {out.shape}",
               hint="average over the colours with ag.mean(..., axis=1, keepdims=True)",
               stop=True)
    e = out.data
    if not np.all(np.isfinite(e)) or np.any(e < -1e-12):
        r.fail("the error must be finite and >= 0 at every pixel", stop=True)
    r.ok("(N, 3, H, W) images -> (N, 1, H, W) finite, non-negative error")
    same = call(r, "photometric_error(x, x)", fn, Tensor(t), Tensor(t)).data
    if np.max(np.abs(same)) > 1e-6:
        r.fail(f"identical images must give zero error; got up to {np.max(np.abs(same)):.3g}",
               stop=True)
    far = np.clip(t + rng.normal(0, 0.3, t.shape), 0, 1)
    if not call(r, "photometric_error on more different images", fn, Tensor(far),
                Tensor(t)).data.mean() > e.mean():
        r.fail("a more different image must give a larger error on average", stop=True)
    r.ok("zero for identical images, larger for more different ones")
    alone = call(r, "photometric_error on image 0 alone", fn, Tensor(p[:1]), Tensor(t[:1]))
    if not np.allclose(alone.data, e[:1], atol=1e-9):
        r.fail("the error of image 0 changes when image 1 is in the batch: do not average "
               "over the batch (axis 0) or over pixels", stop=True)
    r.ok("each image's error depends on that image only")
    pg, tg = rng.uniform(0.3, 0.7, (2, 1, 3, 4, 5))
    call(r, "the gradients into the warped image", gradcheck, lambda a: fn(a, Tensor(tg)), [pg],
         atol=1e-5, rtol=1e-4, hint="use autograd ops only (no .data, no NumPy on the "
                                    "inputs), so the depth network gets gradients")
    r.ok("gradients flow back to the warped image (gradcheck)")
    _photometric_kind(r, p, t, e)
    _photometric_reaches_training(r, fn, rng)


def _photometric_kind(r, p: np.ndarray, t: np.ndarray, e: np.ndarray) -> None:
    """Name the error ``e`` of ``p`` against ``t``: fit e = a (1 - SSIM) / 2 + b L1."""
    from ..autograd import Tensor
    from ..depth.losses import ssim_dissimilarity
    l1 = np.abs(p - t).mean(axis=1).ravel()
    ss = ssim_dissimilarity(Tensor(p), Tensor(t)).data.mean(axis=1).ravel()
    A = np.stack([ss, l1], 1)
    (a, b), *_ = np.linalg.lstsq(A, e.ravel(), rcond=None)
    fit = np.abs(A @ np.array([a, b]) - e.ravel()).max()
    if fit < 1e-6 and abs(a) < 1e-6 and abs(b - 1) < 1e-6:
        r.fail("this is still plain L1 (the paper's Eq. 2)",
               hint="return alpha * SSIM term + (1 - alpha) * L1 term with alpha = 0.85; "
                    "the SSIM term is ag.mean(ssim_dissimilarity(pred, target), axis=1, "
                    "keepdims=True)", stop=True)
    if fit >= 1e-6:
        r.note("your error is neither L1 nor an SSIM + L1 blend: fine if intended "
               "(the checker cannot name it)")
        return
    alpha = a / (a + b) if abs(a + b) > 1e-12 else float("nan")
    r.ok(f"SSIM + L1 with alpha = {alpha:.3f} (monodepth2: 0.85)")
    if abs(a + b - 1) > 1e-3:
        r.note(f"the two weights add up to {a + b:.3f}, not 1: that rescales the "
               f"photometric term against the smoothness term")
    if a < -1e-9 or b < -1e-9:
        r.fail("a negative weight rewards mismatching images", stop=True)
    r.summary = {"alpha": float(alpha)}


def _photometric_reaches_training(r, fn, rng) -> None:
    """The error reaches the view-synthesis loss, and gradients the disparity."""
    from ..autograd import Tensor
    from ..depth.losses import view_synthesis_loss
    from ..world import Camera
    tgt = rng.uniform(0.2, 0.8, (1, 3, 8, 16)).astype(np.float32)
    srcs = [rng.uniform(0.2, 0.8, (1, 3, 8, 16)).astype(np.float32) for _ in range(2)]
    disp = Tensor(np.full((1, 1, 8, 16), 0.5, np.float32), requires_grad=True)
    poses = Tensor(np.array([[[0.05, 0.0, 0.3, 0.0, 0.01, 0.0],
                              [-0.05, 0.0, -0.3, 0.0, -0.01, 0.0]]], np.float32))
    loss, _ = call(r, "the view-synthesis loss with your error", view_synthesis_loss, tgt,
                   srcs, [disp], poses, Camera(8, 16).K, photometric_error=fn)
    call(r, "backward through the view-synthesis loss", loss.backward)
    if not math.isfinite(float(loss.data)) or disp.grad is None or not np.any(disp.grad):
        r.fail("the view-synthesis loss with your error is not finite, or gives no gradient "
               "to the disparity", stop=True)
    r.ok(f"reaches the depth training loss (loss {float(loss.data):.4f}, gradient to the "
         f"disparity)")


# -- Exercise 8: errors in the depth seen in training ----------------------------------
# The DispNet's error e = ln(predicted / GT depth) as measured on 1280 frames of test
# flights (docs/beyond.md, "What the analyses found"),
# split as ``depth.evaluate.log_error_parts`` splits a student's.
DISPNET_LOG_ERROR = {"total": 0.146, "per frame": 0.044, "per column": 0.103,
                     "per row": 0.038, "rest": 0.086}
RESULTS_SECTION = '"What the analyses found"'
TOO_STRONG = 0.5          # std of the log-depth error above which the checker warns


def _gt_frames(flights: int = 8, steps: int = 3, seed: int = 0) -> np.ndarray:
    """GT depth maps (metres, float32 (flights * (steps + 1), 32, 104)) of a few training
    flights: their first views, then after each of ``steps`` random actions."""
    from ..world import DroneEnv
    env = DroneEnv("basic", flights, seed=seed, n_worlds=2, autoreset=True)
    out = [env.reset()[0]]
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        out.append(env.step(rng.integers(env.n_actions, size=flights))[0])
    return np.concatenate(out)


def _as_depths(r: Report, value, like: np.ndarray, what: str) -> np.ndarray:
    """``value`` as an array of positive finite float depths of ``like``'s shape; else
    record a failure naming what was expected and what came, and Stop."""
    if value is None:
        r.fail(f"{what} returned None; expected an array of shape {like.shape}",
               hint="did you forget the `return`? The template ends with `return depth`",
               stop=True)
    arr = np.asarray(value)
    if arr.shape != like.shape:
        r.fail(f"{what} must return an array of the input's shape {like.shape} (frames, "
               f"rows, columns); got shape {arr.shape}",
               hint="return one depth per pixel of every frame; to draw one number per "
                    "frame, draw shape (n, 1, 1) and let NumPy broadcast, e.g. "
                    "depth * np.exp(rng.normal(0.0, 0.05, (len(depth), 1, 1)))", stop=True)
    if arr.dtype.kind != "f":
        r.fail(f"{what} must return floating-point depths (metres) like its input "
               f"({like.dtype}); got dtype {arr.dtype}",
               hint="do not round or cast the depths to integers or booleans", stop=True)
    for bad, name, hint in [
            (~np.isfinite(arr), "non-finite depth(s) (nan or inf)",
             "look for a division by zero (a frame's std is 0 when its depth is constant) or "
             "a log of 0 or of a negative number"),
            (arr <= 0, "depth(s) <= 0",
             "an added error (depth + e) can cross zero near the drone: multiply instead, "
             "depth * np.exp(e) (an error in log depth), which is positive for any e")]:
        if bad.any():
            k = tuple(int(i) for i in np.argwhere(bad)[0])
            r.fail(f"{what} returned {int(bad.sum())} {name}, e.g. {arr[k]:.3g} at (frame, "
                   f"row, column) {k}, where the input is {float(like[k]):.3g} m; every depth "
                   f"must be a finite number > 0", hint=hint, stop=True)
    return arr


def _global_random_state():
    import random
    kind, keys, pos, has_gauss, gauss = np.random.get_state()
    return (keys.tobytes(), pos, has_gauss, gauss), random.getstate()


@exercise(8, "depth-errors", "Depth errors: corrupt the GT depth seen in training",
          "depth_errors.py", "08_depth_errors.md", "agent")
def check_depth_errors(m, r):
    fn = get(r, m, "corrupt", function=True)
    depth = _gt_frames()                     # real GT frames of a few training flights
    n, H, W = depth.shape
    x = depth.copy()
    before = _global_random_state()
    what = f"corrupt(depth of shape {depth.shape}, rng)"
    y = _as_depths(r, call(r, what, fn, x, np.random.default_rng(0)), depth, what)
    used_global = _global_random_state() != before
    r.ok(f"{n} GT depth maps of {H}x{W} from a few training flights -> positive, finite "
         f"depths of the same shape")
    in_place = not np.array_equal(x, depth)
    if in_place:
        r.fail("corrupt changed its input `depth` in place; it must leave it as it is "
               "and return a new array",
               hint="write `depth = depth * np.exp(e)`, not `depth *= np.exp(e)`, and do "
                    "not assign into depth[...]; or start from `out = depth.copy()`")
    else:
        r.ok("the input `depth` is left as it was (not modified in place)")
    y2 = np.asarray(call(r, what + " a second time, same seed", fn, depth.copy(),
                         np.random.default_rng(0)))
    if used_global:
        r.fail("corrupt draws from NumPy's or Python's global random generator "
               "(np.random.normal, np.random.rand, random.random ...): the library's "
               "seed cannot fix those draws",
               hint="draw every random number from the `rng` argument: rng.normal(...), "
                    "rng.uniform(...), rng.integers(...)")
    elif y2.shape != y.shape or not np.array_equal(y, y2):
        diff = float(np.max(np.abs(y2 - y))) if y2.shape == y.shape else float("nan")
        r.fail(f"the same rng seed gave a different corruption the second time (largest "
               f"difference {diff:.3g} m): corrupt must draw its random numbers from "
               f"`rng` only, so that the library's seed fixes the run",
               hint="use rng.normal(...), rng.uniform(...) ...; do not make a generator "
                    "of your own inside corrupt (np.random.default_rng())")
    else:
        r.ok("the same rng seed gives the same corruption")
    _depth_edge_cases(r, fn, depth, in_place)
    _depth_error_size(r, fn, what, depth, y)
    _depth_reaches_training(r, fn)


def _depth_edge_cases(r, fn, depth: np.ndarray, in_place: bool) -> None:
    """One frame, everything near, everything far."""
    _, H, W = depth.shape
    cases = [("a single frame, shape (1, 32, 104)", depth[:1].copy()),
             ("a frame where everything is 0.4 m away (near)",
              np.full((1, H, W), 0.4, np.float32)),
             ("a frame where everything is 30 m away (far)",
              np.full((1, H, W), 30.0, np.float32))]
    for name, d in cases:
        xd = d.copy()
        what = f"corrupt on {name}"
        _as_depths(r, call(r, what, fn, xd, np.random.default_rng(1)), d, what)
        if not in_place and not np.array_equal(xd, d):
            r.fail(f"{what} changed its input `depth` in place",
                   hint="return a new array; leave `depth` as it is", stop=True)
    r.ok("also works on a single frame, and on frames all near (0.4 m) or all far (30 m)")


def _depth_error_size(r, fn, what: str, depth: np.ndarray, y: np.ndarray) -> None:
    """How big the error is, and of what shape, next to the DispNet's."""
    parts = log_error_parts(depth, y)
    r.summary = {"log_error": parts}
    if parts["total"] < 1e-9 and np.allclose(y, depth, rtol=1e-6, atol=0):
        r.fail("corrupt returns the depth unchanged: that is the paper's setting (train on "
               "clean GT depth), which `exercise depth-errors --baseline` trains",
               hint="write a corruption, e.g. `return depth * np.exp(rng.normal(0.0, 0.1, "
                    "depth.shape))`; the docstring has more ideas", stop=True)
    keys = ["total", "per frame", "per column", "per row", "rest"]
    table = "\n".join([f"{'':10}" + "".join(f"{k:>11}" for k in keys) + f"{'mean':>8}",
                       f"{'yours':10}" + "".join(f"{parts[k]:11.3f}" for k in keys)
                       + f"{parts['mean']:+8.3f}",
                       f"{'DispNet':10}" + "".join(f"{DISPNET_LOG_ERROR[k]:11.3f}" for k in keys)])
    r.note(f"std of your error in ln(depth), ln(corrupt(depth) / depth), on these "
           f"{len(depth)} frames (both clipped to 0.5-10 m, the range the Q-net reads), split "
           f"per frame / column / row / rest, next to the DispNet's (docs/beyond.md, "
           f"{RESULTS_SECTION}):\n{table}")
    if parts["total"] > TOO_STRONG:
        r.note(f"a std of {parts['total']:.2f} in ln(depth) (a typical depth off by a "
               f"factor {math.exp(parts['total']):.2f}) is probably too strong: the "
               f"DispNet's is {DISPNET_LOG_ERROR['total']}, and a smooth noise of std "
               f"about 0.38 in training already cost flights on GT depth (docs/beyond.md, "
               f"\"What did not help, and the options removed\")")
    y3 = np.asarray(call(r, what + " with another seed", fn, depth.copy(),
                         np.random.default_rng(1)))
    if y3.shape == y.shape and np.array_equal(y3, y):
        r.note("the same corruption for every seed: a fixed distortion, which a "
               "network can learn to undo, rather than a random error")


def _depth_reaches_training(r, fn) -> None:
    """The corruption reaches the depth the training flights see."""
    from ..rl.observe import encode_depth
    env = _env(4, depth_fn=fn)
    obs, _ = call(r, "the training env's reset, with your corrupt", env.reset)
    frames = encode_depth(obs)
    obs, *_ = call(r, "the training env's step, with your corrupt", env.step,
                   np.zeros(4, np.int64))
    if not (np.all(np.isfinite(frames)) and frames.min() >= 0 and frames.max() <= 1):
        r.fail("the Q-net's frames of your corrupted depth are not in [0, 1]", stop=True)
    changed = not np.allclose(obs, env.gt_depth(), rtol=1e-6, atol=0)
    r.ok("reaches the training flights: the Q-net trains on " +
         ("your corrupted depth" if changed else "GT depth (unchanged)") +
         "; the test flights stay on the depth as it is")

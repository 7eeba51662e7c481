"""One checker per exercise: does the student's change work, and does it reach the code?

Each ``check_<exercise>(path) -> Report`` loads the student's file, calls what it
defines on known inputs, and then pushes it through the real library code (the
environment, the Q-network, the replay, gradcheck, the depth loss) on tiny problems.
Every failure says what was expected, what came, and how to fix it. Checkers run in a
few seconds and never train anything.
"""
from __future__ import annotations

import inspect
import math

import numpy as np

from ..depth.evaluate import log_error_parts
from ..world.stepper import accepts_yaw_rate
from .loader import describe, get_callable, get_value, load_student_module, where_in
from .report import Report, Stop

PAPER_ACTIONS = np.array([[2.0, 0.0], [2.0, 0.25], [2.0, -0.25], [2.0, 0.5], [2.0, -0.5]])
PAPER_HFOV = 90.0


def _run(report: Report, path, body):
    try:
        module = load_student_module(path, report)
        body(module, report)
    except Stop:
        pass
    except Exception as e:  # noqa: BLE001
        if where_in(path, e):       # raised inside the student's file
            report.fail(f"your code raised {describe(e, path)}")
        else:                       # the library broke, not the student's file
            report.fail(f"the checker itself failed: {describe(e, path)}",
                        hint="this looks like a problem in minid3rqn, not in your file: "
                             "tell your teacher, with this message")
    return report


def _call(report: Report, path, what: str, fn, *args, **kwargs):
    """fn(*args); on an exception record a failure naming the call, and Stop."""
    try:
        return fn(*args, **kwargs)
    except Stop:
        raise
    except Exception as e:  # noqa: BLE001 - report anything the student's code raises
        hint = None
        if isinstance(e, ValueError) and "truth value of an array" in str(e):
            hint = ("the code is called with arrays (one entry per flight): replace "
                    "`if x:` / `and` / `or` by np.where(...), np.logical_and(...), ...")
        if isinstance(e, NotImplementedError):
            report.fail(f"not written yet: calling {what} raised {describe(e, path)}",
                        hint="this part is yours to write: replace the `raise "
                             "NotImplementedError(...)` line by your code", stop=True)
        report.fail(f"calling {what} raised {describe(e, path)}", hint=hint, stop=True)


# =====================================================================================
# Exercise 1: the reward
# =====================================================================================
D_GRID = np.array([0.5, 0.6, 0.8, 1.0, 1.5, 2.0, 3.0, 5.0, 8.0, 12.0])


def _as_float(report, value, what, path):
    if value is None:
        report.fail(f"{what} returned None", hint="did you forget the `return`?", stop=True)
    arr = np.asarray(value)
    if arr.dtype.kind not in "fiub" or arr.size != 1:
        report.fail(f"{what} must return one number for number inputs; got {value!r}",
                    stop=True)
    x = float(arr.reshape(()))
    if not math.isfinite(x):
        report.fail(f"{what} returned {x}; rewards must be finite numbers",
                    hint="look for a division by zero or a log of 0", stop=True)
    return x


def check_reward(path) -> Report:
    def body(m, r):
        fn = get_callable(m, "reward", r, path)
        params = list(inspect.signature(fn).parameters.values())
        positional = [p for p in params if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]
        required = [p for p in positional if p.default is p.empty]
        if len(positional) < 2 and not any(p.kind == p.VAR_POSITIONAL for p in params):
            r.fail(f"reward must take (d_nearest, collided[, yaw_rate]); yours takes "
                   f"({', '.join(p.name for p in params)})", stop=True)
        if len(required) > 2:
            names = ", ".join(p.name for p in required)
            r.fail(f"reward requires {len(required)} arguments ({names}); the environment "
                   f"calls reward(d_nearest, collided)",
                   hint="give the third one a default: "
                        "def reward(d_nearest, collided, yaw_rate=0.0)", stop=True)
        sees_yaw = accepts_yaw_rate(fn)
        r.ok("signature reward(d_nearest, collided" + (", yaw_rate=...)" if sees_yaw else ")"))
        rates = [0.0, 0.25, -0.25, 0.5, -0.5]

        def R(d, c, w=0.0):
            what = f"reward({d}, {c}" + (f", {w})" if sees_yaw else ")")
            out = _call(r, path, what, fn, *((d, c, w) if sees_yaw else (d, c)))
            return _as_float(r, out, what, path)

        # numbers in, finite floats out
        yaws = rates if sees_yaw else [0.0]
        table = {(d, w): R(float(d), False, w) for d in D_GRID for w in yaws}
        two_args = _call(r, path, "reward(2.0, False)", fn, 2.0, False)
        _as_float(r, two_args, "reward(2.0, False)", path)
        r.ok(f"finite numbers for d_nearest from 0.5 to 12 m"
             + (" and every yaw rate of the paper's table" if sees_yaw else ""))

        # collision is the worst outcome
        hit = {w: R(0.3, True, w) for w in (rates if sees_yaw else [0.0])}
        worst_safe = min(table.values())
        bad = {w: v for w, v in hit.items() if not v < worst_safe}
        if bad:
            w, v = next(iter(bad.items()))
            r.fail(f"a collision must be worse than any safe step: reward(0.3, True"
                   + (f", {w}" if sees_yaw else "") + f") = {v:g}, but a safe step can earn as "
                   f"little as {worst_safe:g}",
                   hint="keep -1 on collision (np.where(collided, -1.0, ...)), and make sure "
                        "safe rewards stay above it")
        else:
            r.ok(f"a collision gives {hit[0.0]:g}, below every safe reward (lowest {worst_safe:g})")
            if any(abs(v + 1.0) > 1e-12 for v in hit.values()):
                r.note(f"the paper gives -1 on collision; yours gives {hit[0.0]:g}")

        _reward_on_arrays(r, path, fn, sees_yaw, R)

        _reward_changes(r, table, hit, rates, sees_yaw)
        _reward_reaches_training(r, path, fn)
        r.summary = {"sees_yaw_rate": sees_yaw, "collision_reward": hit[0.0]}

    return _run(Report("1 (reward)", path), path, body)


def _reward_on_arrays(r, path, fn, sees_yaw: bool, R) -> None:
    """Arrays in, arrays out, the same values as number by number (``R``: one call)."""
    ds = np.array([0.5, 0.7, 1.2, 2.5, 4.0, 9.0, 0.4, 0.45])
    cs = np.array([False, False, False, False, False, False, True, True])
    ws = np.array([0.0, 0.25, -0.5, 0.5, -0.25, 0.0, 0.5, 0.0])
    args = (ds, cs, ws) if sees_yaw else (ds, cs)
    what = "reward(array_of_d, array_of_collided" + (", array_of_yaw)" if sees_yaw else ")")
    out = _call(r, path, what, fn, *args)
    arr = np.asarray(out, dtype=np.float64) if out is not None else None
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


def _reward_changes(r, table: dict, hit: dict, rates: list, sees_yaw: bool) -> None:
    """Did the reward change from the paper's, and how (``table``: safe steps by (d, yaw);
    ``hit``: collisions by yaw)?"""
    from ..world import paper_reward
    paper = {(d, w): float(paper_reward(d, False)) for (d, w) in table}
    changed = [k for k in table if abs(table[k] - paper[k]) > 1e-9]
    if not changed and all(abs(v + 1.0) <= 1e-12 for v in hit.values()):
        r.fail("your reward is still the paper's (d_nearest, or -1 on collision)",
               hint="penalise turning (e.g. d_nearest - 2.0 * np.abs(yaw_rate)) or clip or "
                    "scale d_nearest (e.g. np.minimum(d_nearest, 3.0)); see the docstring",
               stop=True)
    if sees_yaw:
        penalties = {w: table[(2.0, 0.0)] - table[(2.0, w)] for w in rates[1:]}
        if any(abs(p) > 1e-9 for p in penalties.values()):
            if all(p > 0 for p in penalties.values()):
                r.ok("turning is penalised: at d = 2 m, " + ", ".join(
                    f"yaw {w:+.2f} costs {p:.3g}" for w, p in penalties.items()))
                if abs(penalties[0.5] - penalties[-0.5]) > 1e-9:
                    r.note("left and right turns are penalised differently; intended?")
                if penalties[0.5] + 1e-12 < penalties[0.25]:
                    r.note("a sharp turn costs less than a gentle one; intended?")
            else:
                worst = min(penalties, key=penalties.get)
                r.fail(f"your reward depends on the yaw rate but does not penalise turning: "
                       f"reward(2.0, False, {worst}) = {table[(2.0, worst)]:g} >= reward(2.0, "
                       f"False, 0.0) = {table[(2.0, 0.0)]:g}",
                       hint="subtract a positive cost that grows with |yaw_rate|")
    straight = np.array([table[(d, 0.0)] for d in D_GRID])
    if np.any(np.abs(straight - D_GRID) > 1e-9):
        pairs = ", ".join(f"d={d:g}: {v:.3g}"
                          for d, v in zip(D_GRID[[0, 5, 9]], straight[[0, 5, 9]]))
        r.ok(f"flying straight, your reward differs from the paper's d_nearest ({pairs})")
    if np.any(np.diff(straight) < -1e-9):
        r.note("your reward decreases with the distance to obstacles somewhere: flying "
               "farther from obstacles should not be worse")
    if np.max(np.abs(list(table.values()))) > 100:
        r.note("rewards above 100 in size make Q-values large; the agent multiplies "
               "rewards by 0.1, but consider scaling down")


def _reward_reaches_training(r, path, fn) -> None:
    """The reward reaches the environment and the training flights."""
    from ..world import DroneEnv
    env = DroneEnv("basic", seed=0, reward_fn=fn, observe=False)
    env.reset(seed=0)
    _, rew, *_ = _call(r, path, "DroneEnv(reward_fn=reward).step(0)", env.step, 0)
    if not math.isfinite(rew):
        r.fail(f"in the environment your reward gave {rew}", stop=True)
    from ..rl.flights import Flights
    fl = Flights("basic", 4, seed=0, reward_fn=fn, config=_small_pool())
    fl.reset()
    res = _call(r, path, "the training flights' step", fl.step, np.array([0, 1, 3, 4]))
    if not np.all(np.isfinite(res.rewards)):
        r.fail(f"in the training flights your reward gave {res.rewards}", stop=True)
    shown = [round(float(x), 3) for x in res.rewards]
    r.ok(f"reaches the environment and the training flights (rewards {shown})")


# =====================================================================================
# Exercise 2: the action table
# =====================================================================================
def check_actions(path) -> Report:
    def body(m, r):
        raw = get_value(m, "ACTIONS", r, path)
        try:
            table = np.array(raw, dtype=np.float64)
        except (TypeError, ValueError) as e:
            r.fail(f"ACTIONS must be a list of [speed, yaw_rate] rows of numbers; "
                   f"NumPy could not read it ({e})", stop=True)
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
                   f"must be > 0",
                   hint="a drone that can stop would hover and 'survive' 50 steps without "
                        "flying anywhere; use a slower speed such as 1.0 instead", stop=True)
        if len(np.unique(table, axis=0)) < n:
            r.fail("two rows of ACTIONS are identical; each action must be different",
                   hint="two identical actions share one Q-value and split the learning", stop=True)
        if n == len(PAPER_ACTIONS) and all(np.any(np.all(np.isclose(table, p), axis=1))
                                           for p in PAPER_ACTIONS):
            r.fail("ACTIONS is still the paper's Table 3",
                   hint="add rows, e.g. [2.0, 0.75] and [2.0, -0.75] (sharper turns) or "
                        "[1.0, 0.0] (a second, slower speed)", stop=True)
        new = [row.tolist() for row in table if not any(np.allclose(row, p) for p in PAPER_ACTIONS)]
        gone = [p.tolist() for p in PAPER_ACTIONS if not any(np.allclose(row, p) for row in table)]
        r.ok("changed from the paper's table: added " + (str(new) if new else "nothing")
             + (f", removed {gone}" if gone else ""))
        if not np.any((np.abs(table[:, 1]) < 1e-12)):
            r.note("no action flies straight (yaw rate 0): the drone will always be turning")
        rates = table[:, 1]
        if any(not np.any(np.isclose(rates, -w)) for w in rates):
            r.note("the turns are not symmetric (some left turn has no matching right turn)")
        turning = np.abs(rates) > 1e-12
        if turning.any():
            radius = float(np.min(table[turning, 0] / np.abs(rates[turning])))
            r.note(f"tightest turning radius v/|yaw rate| = {radius:.2f} m (paper: 4 m)")
        if np.any(table[:, 0] > 4.0):
            r.note("speeds above 4 m/s cover a lot of ground in 0.4 s: obstacles get close fast")
        if n > 11:
            r.note(f"{n} actions: a large head learns slowly within a short budget")

        _actions_reach_training(r, path, table)
        r.summary = {"n_actions": n, "added": new, "removed": gone}

    return _run(Report("2 (actions)", path), path, body)


def _actions_reach_training(r, path, table: np.ndarray) -> None:
    """The table reaches the environment, the training flights and the Q-net's head."""
    n = len(table)
    from ..world import DroneEnv
    env = DroneEnv("basic", seed=0, actions=table, observe=False)
    if env.action_space.n != n:
        r.fail(f"the environment sees {env.action_space.n} actions, not {n}", stop=True)
    _, info0 = env.reset(seed=0, options={"pose": _free_pose(env)})
    _, _, term, _, info = _call(r, path, f"DroneEnv(actions=ACTIONS).step({n - 1})",
                                env.step, n - 1)
    turned = float(info["pose"][2] - info0["pose"][2])
    want = table[n - 1, 1] * env.dt
    if not term and abs(turned - want) > 1e-6:
        r.fail(f"after action {n - 1} the drone turned {turned:.3f} rad; expected "
               f"{want:.3f}", stop=True)
    r.ok(f"the environment flies the new action {n - 1} ({table[n - 1].tolist()}: "
         f"turned {turned:+.2f} rad in 0.4 s)")
    from ..rl.flights import Flights
    fl = Flights("basic", 2, seed=0, actions=table, config=_small_pool())
    fl.reset()
    _call(r, path, "Flights(actions=ACTIONS).step", fl.step, np.array([n - 1, 0]))
    r.ok(f"the training flights accept action {n - 1}")
    from ..nets.qnet import QNet
    from ..rl.train import TrainConfig
    cfg = TrainConfig(hidden=16).qnet_config(fl.n_actions, fl.frame_shape)
    net = QNet(cfg, rng=0)
    q, _ = net(np.zeros((1, 1, cfg.in_channels) + tuple(fl.frame_shape), np.float32))
    if q.shape[-1] != n:
        r.fail(f"the Q-network has {q.shape[-1]} outputs, not {n}", stop=True)
    r.ok(f"the Q-network's head has {n} outputs, one per action")


def _small_pool():
    from ..rl.flights import FlightsConfig
    return FlightsConfig(n_worlds=2)          # 2 worlds, not 32: a check must be quick


def _free_pose(env):
    """A start pose with room to fly any action for one step."""
    from ..world import sample_start_pose
    env.reset(seed=0)
    return sample_start_pose(env.scene, np.random.default_rng(0), env.actions, env.dt,
                             env.safe_distance)


# =====================================================================================
# Exercise 3: the field of view
# =====================================================================================
def check_fov(path) -> Report:
    def body(m, r):
        fov = get_value(m, "HFOV_DEG", r, path)
        if isinstance(fov, bool) or not isinstance(fov, (int, float, np.integer, np.floating)):
            r.fail(f"HFOV_DEG must be a number of degrees; got {fov!r}", stop=True)
        fov = float(fov)
        if not 0.0 < fov < 180.0:
            r.fail(f"HFOV_DEG must lie between 0 and 180 degrees; got {fov:g}", stop=True)
        from ..world import Camera
        cam = _call(r, path, f"Camera(hfov_deg={fov:g})", Camera, 32, 104, fov)
        r.ok(f"a 32x104 camera with a {fov:g} degree view: fx = {cam.fx:.1f} px "
             f"(90 degrees: 52.0 px)")
        if abs(fov - PAPER_HFOV) < 1e-9:
            r.fail("HFOV_DEG is still 90 degrees",
                   hint="narrow it, e.g. HFOV_DEG = 60 (then 45)", stop=True)
        if fov > PAPER_HFOV:
            r.note("wider than 90 degrees: the exercise asks for a narrower view, but a wider "
                   "one is a fine extra experiment (memory should matter less)")
        if fov < 20:
            r.note(f"{fov:g} degrees is a keyhole: the drone sees about one obstacle at a time")
        from ..rl.flights import Flights
        fl = Flights("basic", 2, seed=0, camera=cam, config=_small_pool())
        frames = fl.reset()
        if frames.shape != (2, 32, 104):
            r.fail(f"frames came out {frames.shape}, expected (2, 32, 104)", stop=True)
        r.ok(f"the training flights render with your camera (each column spans "
             f"{fov / 104:.2f} degrees instead of {PAPER_HFOV / 104:.2f})")
        r.summary = {"hfov_deg": fov}

    return _run(Report("3 (field of view)", path), path, body)


# =====================================================================================
# Exercise 4: memory
# =====================================================================================
def check_memory(path) -> Report:
    def body(m, r):
        L = get_value(m, "SEQ_LEN", r, path)
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
        from ..rl.replay import EpisodeReplay
        shape = (4, 6)
        rep = EpisodeReplay(200, 1, shape, seed=0)
        frame = np.zeros((1,) + shape, np.float32)
        for ep in range(2):
            rep.start_episodes(np.array([0]), frame)
            for t in range(max(L, 3) + 2):
                rep.add_step(np.array([t % 5]), np.ones(1, np.float32), np.array([False]),
                             np.array([False]), frame)
        batch = _call(r, path, f"replay.sample(batch 8, seq_len {L})", rep.sample, 8, L)
        if batch.actions.shape != (L, 8):
            r.fail(f"the replay gave windows of shape {batch.actions.shape}, expected {(L, 8)}",
                   stop=True)
        r.ok(f"the replay samples windows of {L} step{'s' if L > 1 else ''}")
        r.summary = {"seq_len": L}

    return _run(Report("4 (memory)", path), path, body)


# =====================================================================================
# Exercise 5: ablations (dueling, double-Q)
# =====================================================================================
def _targets_reference(qo, qt, rew, term, gamma):
    best = np.argmax(qo, axis=-1)
    double = np.take_along_axis(qt, best[..., None], -1)[..., 0]
    boot = gamma * (1.0 - term)
    return {"double": rew + boot * double, "single": rew + boot * qt.max(-1),
            "online": rew + boot * qo.max(-1)}


def check_ablation(path) -> Report:
    def body(m, r):
        dueling = get_value(m, "DUELING", r, path)
        if not isinstance(dueling, (bool, np.bool_)):
            r.fail(f"DUELING must be True or False; got {dueling!r}", stop=True)
        fn = get_callable(m, "td_target", r, path)
        rng = np.random.default_rng(0)
        L, B, A = 4, 6, 5
        qo = rng.standard_normal((L, B, A))
        qt = rng.standard_normal((L, B, A))
        rew = rng.uniform(-1, 3, (L, B))
        term = (rng.random((L, B)) < 0.3).astype(np.float64)
        term[0, 0], term[0, 1] = 1.0, 0.0
        qo[0, 1] = [0, 3, 0, 0, 0]          # online and target disagree on the best action
        qt[0, 1] = [0, 0, 2, 0, 0]
        y = _call(r, path, "td_target(...) on a batch of shape (L=4, B=6, A=5)", fn,
                  qo.copy(), qt.copy(), rew.copy(), term.copy(), 0.99)
        y = np.asarray(y, dtype=np.float64) if y is not None else None
        if y is None or y.shape != (L, B):
            r.fail(f"td_target must return one target per step, shape {(L, B)}; got "
                   f"{None if y is None else y.shape}",
                   hint="reduce over the action axis (axis=-1), e.g. with .max(axis=-1)", stop=True)
        if not np.all(np.isfinite(y)):
            r.fail("td_target returned non-finite values", stop=True)
        hit = term == 1
        if not np.allclose(y[hit], rew[hit]):
            r.fail("on a collision step (terminal = 1) the target must be the reward alone: "
                   "there is no next state to bootstrap from",
                   hint="multiply the bootstrap term by (1 - terminals)", stop=True)
        r.ok("terminal steps: y = r")
        refs = _targets_reference(qo, qt, rew, term, 0.99)
        kind = next((k for k, v in refs.items() if np.allclose(y, v, atol=1e-6)), None)
        if kind is None:
            r.fail("td_target matches neither the double-Q target nor the classic DQN target",
                   hint="classic DQN: "
                        "rewards + gamma * (1 - terminals) * q_target_next.max(axis=-1)",
                   stop=True)
        words = {"double": "double Q-learning (the online net picks a', the target net values it)",
                 "single": "no double-Q: the target net picks and values a' (classic DQN)",
                 "online": "the online net picks and values a': this removes the target "
                           "network too"}
        r.ok(f"td_target is {words[kind]}")
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
        from ..nets.qnet import QNetConfig
        variant = "d3rqn" if dueling else "ddrqn"
        cfg = QNetConfig.for_variant(variant, width=16)
        r.ok(f"trains as variant {variant} (dueling={cfg.dueling}, recurrent={cfg.recurrent})")
        r.summary = {"dueling": bool(dueling), "target": kind, "variant": variant}

    return _run(Report("5 (ablations)", path), path, body)


# =====================================================================================
# Exercise 6: a new autograd op
# =====================================================================================
def check_op(path) -> Report:
    from ..autograd import Tensor

    def body(m, r):
        fn = get_callable(m, "leaky_relu", r, path)
        x = np.array([[-2.0, -0.5, -0.1, 0.3], [0.7, 1.5, -1.2, 2.2]])
        for slope in (0.01, 0.2):
            out = _call(r, path, f"leaky_relu(Tensor(x), slope={slope})", fn, Tensor(x), slope)
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
        x32 = Tensor(x.astype(np.float32))
        out32 = _call(r, path, "leaky_relu on float32", fn, x32, 0.1)
        if out32.dtype != np.float32:
            r.fail(f"float32 in must give float32 out (training runs in float32); got "
                   f"{out32.dtype}",
                   hint="multiply by the slope without making a float64 array, e.g. "
                        "x.data * np.asarray(slope, x.dtype)")
        else:
            r.ok("keeps float32 as float32")
        default = _call(r, path, "leaky_relu(x) with the default slope", fn, Tensor(x))
        if not np.allclose(default.data, np.where(x > 0, x, 0.01 * x)):
            r.note("the default slope is not 0.01")

        _op_backward(r, path, fn, x)

    return _run(Report("6 (autograd op)", path), path, body)


def _op_backward(r, path, fn, x: np.ndarray) -> None:
    """The op's backward: its own vjp, right on a grid, through gradcheck, no graph
    inside no_grad()."""
    from ..autograd import GradcheckError, Tensor, gradcheck, no_grad
    leaf = Tensor(x.copy(), requires_grad=True)
    y = _call(r, path, "leaky_relu(leaf with requires_grad)", fn, leaf, 0.2)
    if not y.requires_grad:
        r.fail("the output does not require grad although the input does: the graph is cut",
               hint="build the output with Tensor.from_op(y, (x,), vjp, name)", stop=True)
    parents = getattr(y, "_parents", ())
    if len(parents) != 1 or parents[0] is not leaf:
        r.fail("leaky_relu is built from other Tensor ops, so autograd wrote the backward "
               "for you",
               hint="compute y with NumPy on x.data and return Tensor.from_op(y, (x,), vjp, "
                    "'leaky_relu') with your own vjp(g)", stop=True)
    _call(r, path, "backward() through leaky_relu", y.backward, np.ones_like(x))
    want = np.where(x > 0, 1.0, 0.2)
    if leaf.grad is None or not np.allclose(leaf.grad, want):
        got = None if leaf.grad is None else np.round(leaf.grad, 4).tolist()
        r.fail(f"dy/dx is wrong: got {got}, expected {want.tolist()}",
               hint="vjp(g) must return (g * (1 where x > 0, slope elsewhere),) - a tuple",
               stop=True)
    r.ok("backward: dy/dx = 1 for x > 0, slope otherwise")
    rng = np.random.default_rng(0)
    xs = rng.standard_normal((3, 5))
    xs = np.where(np.abs(xs) < 0.05, 0.3, xs)           # stay off the kink at 0
    try:
        gradcheck(lambda t: fn(t, 0.1) * t, [xs])
        gradcheck(lambda t: fn(t, 0.3), [xs])
    except GradcheckError as e:
        r.fail(f"gradcheck failed: {e}",
               hint="the backward must multiply the incoming gradient g elementwise",
               stop=True)
    except Exception as e:  # noqa: BLE001
        r.fail(f"gradcheck raised {describe(e, path)}", stop=True)
    r.ok("passes gradcheck (backward agrees with central differences, float64)")
    with no_grad():
        z = _call(r, path, "leaky_relu inside no_grad()", fn, Tensor(x, requires_grad=True))
    if z.requires_grad:
        r.fail("inside no_grad() the output must not record a graph", stop=True)
    r.ok("records no graph inside no_grad()")


# =====================================================================================
# Exercise 7: the photometric error of the depth loss
# =====================================================================================
def check_photometric(path) -> Report:
    from ..autograd import GradcheckError, Tensor, gradcheck

    def body(m, r):
        fn = get_callable(m, "photometric_error", r, path)
        rng = np.random.default_rng(0)
        t = rng.uniform(0.2, 0.8, (2, 3, 8, 10))
        p = np.clip(t + rng.normal(0, 0.1, t.shape), 0, 1)
        out = _call(r, path, "photometric_error(pred, target) on (2, 3, 8, 10) images", fn,
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
        same = _call(r, path, "photometric_error(x, x)", fn, Tensor(t), Tensor(t)).data
        if np.max(np.abs(same)) > 1e-6:
            r.fail(f"identical images must give zero error; got up to {np.max(np.abs(same)):.3g}",
                   stop=True)
        far = np.clip(t + rng.normal(0, 0.3, t.shape), 0, 1)
        e_far = fn(Tensor(far), Tensor(t)).data
        if not e_far.mean() > e.mean():
            r.fail("a more different image must give a larger error on average", stop=True)
        r.ok("zero for identical images, larger for more different ones")
        alone = fn(Tensor(p[:1]), Tensor(t[:1])).data
        if not np.allclose(alone, e[:1], atol=1e-9):
            r.fail("the error of image 0 changes when image 1 is in the batch: do not average "
                   "over the batch (axis 0) or over pixels", stop=True)
        r.ok("each image's error depends on that image only")
        pg = rng.uniform(0.3, 0.7, (1, 3, 4, 5))
        tg = rng.uniform(0.3, 0.7, (1, 3, 4, 5))
        try:
            gradcheck(lambda a: fn(a, Tensor(tg)), [pg], atol=1e-5, rtol=1e-4)
        except GradcheckError as ex:
            r.fail(f"gradients into the warped image are wrong: {ex}", stop=True)
        except Exception as ex:  # noqa: BLE001
            r.fail(f"gradcheck through your error raised {describe(ex, path)}",
                   hint="use autograd ops only, so the depth network gets gradients", stop=True)
        r.ok("gradients flow back to the warped image (gradcheck)")

        _photometric_kind(r, p, t, e)

        # it reaches the view-synthesis loss
        from ..depth.losses import view_synthesis_loss
        from ..world import Camera
        cam = Camera(8, 16)
        tgt = rng.uniform(0.2, 0.8, (1, 3, 8, 16)).astype(np.float32)
        srcs = [rng.uniform(0.2, 0.8, (1, 3, 8, 16)).astype(np.float32) for _ in range(2)]
        disp = Tensor(np.full((1, 1, 8, 16), 0.5, np.float32), requires_grad=True)
        poses = Tensor(np.array([[[0.05, 0.0, 0.3, 0.0, 0.01, 0.0],
                                  [-0.05, 0.0, -0.3, 0.0, -0.01, 0.0]]], np.float32))
        loss, _ = _call(r, path, "the view-synthesis loss with your error",
                        view_synthesis_loss, tgt, srcs, [disp], poses, cam.K,
                        photometric_error=fn)
        _call(r, path, "backward through the view-synthesis loss", loss.backward)
        if not math.isfinite(float(loss.data)) or disp.grad is None or not np.any(disp.grad):
            r.fail("the view-synthesis loss with your error is not finite, or gives no gradient "
                   "to the disparity", stop=True)
        r.ok(f"reaches the depth training loss (loss {float(loss.data):.4f}, gradient to the "
             f"disparity)")

    return _run(Report("7 (depth loss)", path), path, body)


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
    if fit < 1e-6:
        alpha = a / (a + b) if abs(a + b) > 1e-12 else float("nan")
        r.ok(f"SSIM + L1 with alpha = {alpha:.3f} (monodepth2: 0.85)")
        if abs(a + b - 1) > 1e-3:
            r.note(f"the two weights add up to {a + b:.3f}, not 1: that rescales the "
                   f"photometric term against the smoothness term")
        if a < -1e-9 or b < -1e-9:
            r.fail("a negative weight rewards mismatching images", stop=True)
        r.summary = {"alpha": float(alpha)}
    else:
        r.note("your error is neither L1 nor an SSIM + L1 blend: fine if intended "
               "(the checker cannot name it)")


# =====================================================================================
# Exercise 8: errors in the depth seen in training
# =====================================================================================
# The DispNet's error e = ln(predicted / GT depth) as measured on 1280 frames of test
# flights (docs/beyond.md, "Two ways to make a GT-trained net robust to those errors"),
# split as ``depth.evaluate.log_error_parts`` splits a student's.
DISPNET_LOG_ERROR = {"total": 0.146, "per frame": 0.044, "per column": 0.103,
                     "per row": 0.038, "rest": 0.086}
RESULTS_SECTION = '"Two ways to make a GT-trained net robust to those errors"'
TOO_STRONG = 0.5          # std of the log-depth error above which the checker warns


def _gt_frames(flights: int = 8, steps: int = 3, seed: int = 0) -> np.ndarray:
    """GT depth maps (metres, float32 (flights * (steps + 1), 32, 104)) of a few training
    flights: their first views, then after each of ``steps`` random actions."""
    from ..rl.flights import Flights
    fl = Flights("basic", flights, seed=seed, config=_small_pool())
    fl.reset()
    out = [fl.last_depth.copy()]
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        fl.step(rng.integers(fl.n_actions, size=flights))
        out.append(fl.last_depth.copy())
    return np.concatenate(out)


def _as_depths(report: Report, value, like: np.ndarray, what: str) -> np.ndarray:
    """``value`` as an array of positive finite float depths of ``like``'s shape; else
    record a failure naming what was expected and what came, and Stop."""
    if value is None:
        report.fail(f"{what} returned None; expected an array of shape {like.shape}",
                    hint="did you forget the `return`? The template ends with `return depth`",
                    stop=True)
    arr = np.asarray(value)
    if arr.shape != like.shape:
        report.fail(f"{what} must return an array of the input's shape {like.shape} (frames, "
                    f"rows, columns); got shape {arr.shape}",
                    hint="return one depth per pixel of every frame; to draw one number per "
                         "frame, draw shape (n, 1, 1) and let NumPy broadcast, e.g. "
                         "depth * np.exp(rng.normal(0.0, 0.05, (len(depth), 1, 1)))", stop=True)
    if arr.dtype.kind != "f":
        report.fail(f"{what} must return floating-point depths (metres) like its input "
                    f"({like.dtype}); got dtype {arr.dtype}",
                    hint="do not round or cast the depths to integers or booleans", stop=True)
    bad = ~np.isfinite(arr)
    if bad.any():
        k = tuple(int(i) for i in np.argwhere(bad)[0])
        report.fail(f"{what} returned {int(bad.sum())} non-finite depth(s) (nan or inf), e.g. "
                    f"{arr[k]} at (frame, row, column) {k}, where the input is "
                    f"{float(like[k]):.3g} m; every depth must be a finite number",
                    hint="look for a division by zero (a frame's std is 0 when its depth is "
                         "constant) or a log of 0 or of a negative number", stop=True)
    low = arr <= 0
    if low.any():
        k = tuple(int(i) for i in np.argwhere(low)[0])
        report.fail(f"{what} returned {int(low.sum())} depth(s) <= 0, e.g. {float(arr[k]):.3g} m "
                    f"at (frame, row, column) {k}, where the input is {float(like[k]):.3g} m; "
                    f"every depth must be > 0",
                    hint="an added error (depth + e) can cross zero near the drone: multiply "
                         "instead, depth * np.exp(e) (an error in log depth), which is "
                         "positive for any e", stop=True)
    return arr


def _global_random_state():
    import random
    kind, keys, pos, has_gauss, gauss = np.random.get_state()
    return (keys.tobytes(), pos, has_gauss, gauss), random.getstate()


def check_depth_errors(path) -> Report:
    def body(m, r):
        fn = get_callable(m, "corrupt", r, path)
        try:
            params = list(inspect.signature(fn).parameters.values())
        except (TypeError, ValueError):
            params = None
        if params is not None:
            positional = [p for p in params
                          if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]
            if len(positional) < 2 and not any(p.kind == p.VAR_POSITIONAL for p in params):
                r.fail(f"corrupt must take (depth, rng); yours takes "
                       f"({', '.join(p.name for p in params)})",
                       hint="keep the template's signature: def corrupt(depth, rng)", stop=True)

        # real GT frames of a few training flights
        depth = _gt_frames()
        n, H, W = depth.shape
        x = depth.copy()
        before = _global_random_state()
        what = f"corrupt(depth of shape {depth.shape}, rng)"
        out = _call(r, path, what, fn, x, np.random.default_rng(0))
        used_global = _global_random_state() != before
        y = _as_depths(r, out, depth, what)
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

        # the same seed must give the same corruption: draw only from rng
        y2 = np.asarray(_call(r, path, what + " a second time, same seed", fn, depth.copy(),
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

        _depth_edge_cases(r, path, fn, depth, in_place)

        _depth_error_size(r, path, fn, what, depth, y)

        _depth_reaches_training(r, path, fn)

    return _run(Report("8 (depth errors)", path), path, body)


def _depth_edge_cases(r, path, fn, depth: np.ndarray, in_place: bool) -> None:
    """One frame, everything near, everything far."""
    _, H, W = depth.shape
    cases = [("a single frame, shape (1, 32, 104)", depth[:1].copy()),
             ("a frame where everything is 0.4 m away (near)",
              np.full((1, H, W), 0.4, np.float32)),
             ("a frame where everything is 30 m away (far)",
              np.full((1, H, W), 30.0, np.float32))]
    for name, d in cases:
        xd = d.copy()
        call = f"corrupt on {name}"
        _as_depths(r, _call(r, path, call, fn, xd, np.random.default_rng(1)), d, call)
        if not in_place and not np.array_equal(xd, d):
            r.fail(f"{call} changed its input `depth` in place",
                   hint="return a new array; leave `depth` as it is", stop=True)
    r.ok("also works on a single frame, and on frames all near (0.4 m) or all far (30 m)")


def _depth_error_size(r, path, fn, what: str, depth: np.ndarray, y: np.ndarray) -> None:
    """How big the error is, and of what shape, next to the DispNet's."""
    n = len(depth)
    parts = log_error_parts(depth, y)
    r.summary = {"log_error": parts}
    if parts["total"] < 1e-9 and np.allclose(y, depth, rtol=1e-6, atol=0):
        r.note("corrupt leaves the depth as it is: the paper's setting (train on clean GT "
               "depth), the same as --baseline. Write a corruption, then compare the "
               "two runs")
    else:
        keys = ["total", "per frame", "per column", "per row", "rest"]
        head = f"{'':10}" + "".join(f"{k:>11}" for k in keys) + f"{'mean':>8}"
        mine = f"{'yours':10}" + "".join(f"{parts[k]:11.3f}" for k in keys) + \
            f"{parts['mean']:+8.3f}"
        theirs = f"{'DispNet':10}" + "".join(f"{DISPNET_LOG_ERROR[k]:11.3f}" for k in keys)
        r.note(f"std of your error in ln(depth), ln(corrupt(depth) / depth), on these {n} "
               f"frames (both clipped to 0.5-10 m, the range the Q-net reads), split per "
               f"frame / column / row / rest, next to the DispNet's (docs/beyond.md, "
               f"{RESULTS_SECTION}):\n{head}\n{mine}\n{theirs}")
        if parts["total"] > TOO_STRONG:
            r.note(f"a std of {parts['total']:.2f} in ln(depth) (a typical depth off by a "
                   f"factor {math.exp(parts['total']):.2f}) is probably too strong: the "
                   f"DispNet's is {DISPNET_LOG_ERROR['total']}, and a smooth noise of std "
                   f"about 0.38 in training already cost flights on GT depth "
                   f"(docs/beyond.md, {RESULTS_SECTION})")
        y3 = np.asarray(_call(r, path, what + " with another seed", fn, depth.copy(),
                              np.random.default_rng(1)))
        if y3.shape == y.shape and np.array_equal(y3, y):
            r.note("the same corruption for every seed: a fixed distortion, which a "
                   "network can learn to undo, rather than a random error")


def _depth_reaches_training(r, path, fn) -> None:
    """The corruption reaches the training flights' frames."""
    from ..rl.flights import Flights, depth_only
    fl = Flights("basic", 4, seed=0, depth_fn=fn, config=_small_pool())
    frames = _call(r, path, "the training flights' reset, with your corrupt", fl.reset)
    _call(r, path, "the training flights' step, with your corrupt", fl.step,
          np.zeros(4, np.int64))
    gt = depth_only(fl.batch, fl.poses, fl.camera)
    if not (np.all(np.isfinite(frames)) and frames.min() >= 0 and frames.max() <= 1):
        r.fail("the training flights' frames with your corruption are not in [0, 1]",
               stop=True)
    changed = not np.allclose(fl.last_depth, gt, rtol=1e-6, atol=0)
    r.ok("reaches the training flights: the Q-net trains on " +
         ("your corrupted depth" if changed else "GT depth (unchanged)") +
         "; the test flights stay on the depth as it is")

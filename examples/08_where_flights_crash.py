# %% [markdown]
# # 08: Where do the flights that fail crash, and into what?
#
# A success rate says how often a pilot fails, not why. This example flies a pilot over
# the usual test flights (the same worlds and start poses as ``evaluate``) and, for every
# collision, notes three facts:
#
#     what was hit      a round obstacle (pillar), a polygon (box, building) or a wall
#                       (world.distance.KINDS: the kind nearest to the drone where its
#                       clearance first fell below 0.5 m along the step's arc)
#     where it was      the bearing of the point hit, seen from the pose the last action
#                       was chosen at: inside the camera's view (|bearing| <= 45 degrees)
#                       or already outside it
#     the last action   turning toward the point hit, away from it, or straight
#
# A pilot that flies into what it sees straight ahead needs better eyes; one that turns
# into a pillar it has just passed (outside the view) needs memory, or a habit of not
# turning toward what it passed. The pilot is a Q-net .npz, several joined by '+' (an
# ensemble), or a baseline (straight, random, reactive, oracle).
#
#     python examples/08_where_flights_crash.py [--smoke] [--policy M.npz] \
#         [--scenarios basic channel intersections corners] [--flights 1000] \
#         [--seed 12345] [--depth gt|pred]
#
# With ``--depth pred`` each world is seen through its shipped DispNet
# (``minid3rqn/models/depth_<scenario>.npz``). Nothing is trained.

# %%
"""Where do the flights that fail crash, and into what?"""
import argparse
import sys
from functools import partial
from pathlib import Path

import numpy as np

from minid3rqn.io import MODELS
from minid3rqn.rl.evaluate import evaluate_policy
from minid3rqn.rl.models import actions_and_camera, load_depth_estimator, load_policy
from minid3rqn.world import DroneEnv
from minid3rqn.world.distance import KINDS, nearest_distance_batch, nearest_distance_by_kind
from minid3rqn.world.stepper import action_arcs

HALF_VIEW = 45.0        # degrees: half the camera's horizontal field of view


# %%
class CrashLog(DroneEnv):
    """The env that appends, for each collision, (kind, bearing in degrees, yaw rate of
    the last action) to ``log``. Worlds, poses and collisions are ``DroneEnv``'s own."""

    def __init__(self, *args, log=None, **kwargs):
        super().__init__(*args, **kwargs)
        self.log = log

    def step(self, actions):
        before = self.poses.copy()                 # where the last action was chosen
        res = super().step(actions)
        hit = np.flatnonzero(res[2])               # terminated: a collision
        if hit.size:
            # the same arc as DroneEnv.step, to find where the clearance first fell short
            chosen = np.asarray(actions)[hit]
            path = action_arcs(before[hit], self.actions, chosen, self.dt)
            batch = self.batch_of(hit)
            clear = nearest_distance_batch(batch, path[:, :, :2])
            first = (clear < self.safe_distance).argmax(axis=1)
            kind, bearing = what_was_hit(batch, before[hit], path[np.arange(hit.size), first])
            self.log.append(np.stack([kind, bearing, self.actions[chosen, 1]], axis=1))
        return res


# %%
def what_was_hit(batch, chosen_at, ended_at, eps=1e-3):
    """Kind index and bearing (degrees, left positive) of the obstacle point nearest to
    ``ended_at`` (n, 3) (where the clearance fell short), seen from ``chosen_at`` (n, 3).
    The point is found by stepping back along the distance's gradient: q = p - d grad d."""
    p = ended_at[:, None, :2]                                          # (n, 1, 2)
    probes = p + np.array([[0, 0], [eps, 0], [-eps, 0], [0, eps], [0, -eps]])
    d = nearest_distance_by_kind(batch, probes)                        # (n, 5, 3)
    kind = d[:, 0].argmin(-1)
    dk = np.take_along_axis(d, kind[:, None, None], axis=2)[..., 0]    # (n, 5)
    grad = np.stack([dk[:, 1] - dk[:, 2], dk[:, 3] - dk[:, 4]], -1) / (2 * eps)
    grad /= np.maximum(np.linalg.norm(grad, axis=1, keepdims=True), 1e-12)
    q = ended_at[:, :2] - dk[:, :1] * grad
    rel = q - chosen_at[:, :2]
    bearing = np.degrees(np.arctan2(rel[:, 1], rel[:, 0]) - chosen_at[:, 2])
    return kind, (bearing + 180.0) % 360.0 - 180.0


# %%
def summarise(crashes: np.ndarray) -> str:
    """One line: crashes by kind, the share out of view, and the share turning toward."""
    if len(crashes) == 0:
        return "no crashes"
    kind, bearing, rate = crashes.T
    counts = ", ".join(f"{name} {int((kind == k).sum())}" for k, name in enumerate(KINDS))
    out_of_view = np.abs(bearing) > HALF_VIEW
    toward = np.sign(rate) == np.sign(bearing)
    return (f"{len(crashes)} crashes: {counts}; hit point out of view at the last "
            f"decision {out_of_view.mean():.0%}; last action turned toward it "
            f"{(toward & (rate != 0)).mean():.0%}, straight {(rate == 0).mean():.0%}, "
            f"away {((~toward) & (rate != 0)).mean():.0%}")


# %%
def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--policy", default=str(MODELS / "d3rqn_basic.npz"),
                    help="a Q-net .npz, several joined by '+', or a baseline")
    ap.add_argument("--scenarios", nargs="+", help="the worlds to fly",
                    default=["basic", "channel", "intersections", "corners"])
    ap.add_argument("--flights", type=int, default=1000, help="test flights per scenario")
    ap.add_argument("--seed", type=int, default=12345, help="evaluation seed")
    ap.add_argument("--depth", choices=["gt", "pred"], default="gt",
                    help="GT depth, or each world's shipped DispNet")
    ap.add_argument("--smoke", action="store_true", help="a few flights in one world")
    args = ap.parse_args([] if argv is None and "ipykernel" in sys.modules else argv)
    if args.smoke:
        args.scenarios, args.flights = ["intersections"], 40

    policy = load_policy(args.policy, 0)
    _, camera = actions_and_camera(policy)
    print(f"{args.flights} flights per world on {'GT' if args.depth == 'gt' else 'predicted'} "
          f"depth, evaluation seed {args.seed}")
    for scenario in args.scenarios:
        est = (load_depth_estimator(MODELS / f"depth_{scenario}.npz")
               if args.depth == "pred" else None)
        log = []
        res = evaluate_policy(policy, scenario, args.flights, args.seed, depth=args.depth,
                              depth_estimator=est, progress=False,
                              env_factory=partial(CrashLog, log=log, camera=camera))
        crashes = np.concatenate(log) if log else np.zeros((0, 3))
        assert len(crashes) == res.flights - res.successes   # every failure was a collision
        print(f"{res.line()}\n    {summarise(crashes)}", flush=True)


# %%
if __name__ == "__main__":
    main()

# %% [markdown]
# # 05: Success rates with 95% intervals: Straight, Random, Reactive and a Q-net
#
# Every policy flies the same fresh test worlds (seeds disjoint from training), all
# flights of a chunk stepped together. The paper's protocol is 2000 flights of 50 steps:
#
#     python -m minid3rqn evaluate straight random reactive oracle \
#         minid3rqn/models/d3rqn_basic.npz --flights 2000
#
#     python examples/05_evaluate.py [--smoke] [--flights N] [--model PATH]
#
# Each line gives two intervals. The first (Wilson's) counts the flights as independent
# trials. The flights share worlds, though (200 flights fly 32 here), and a world with a
# hard spot fails several at once; the second, "by world", allows for that, and "deff"
# says how many times the first interval's variance the true one is (docs/d3rqn.md,
# section 9). Read the second when you ask how well a policy flies this kind of world.

# %%
"""Success rates with 95% intervals: Straight, Random, Reactive and a Q-net."""
import argparse
import sys
from pathlib import Path

from minid3rqn.rl.models import SHIPPED_QNET, load_policy
from minid3rqn.rl.evaluate import evaluate_policy


# %%
def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--smoke", action="store_true", help="8 flights of 20 steps (tests)")
    p.add_argument("--flights", type=int, default=200, help="test flights per policy")
    p.add_argument("--model", default=str(SHIPPED_QNET), help="a Q-net .npz to fly too")
    p.add_argument("--scenario", default="basic", help="the test worlds")
    args = p.parse_args([] if "ipykernel" in sys.modules else None)
    n = 8 if args.smoke else args.flights
    specs = ["straight", "random", "reactive"]
    if Path(args.model).exists():
        specs.append(args.model)
    print(f"{n} flights of 50 steps in fresh '{args.scenario}' worlds (GT depth)")
    for spec in specs:
        res = evaluate_policy(load_policy(spec), args.scenario, n_flights=n,
                              max_steps=20 if args.smoke else 50, progress=False)
        print("  " + res.line())


# %%
if __name__ == "__main__":
    main()

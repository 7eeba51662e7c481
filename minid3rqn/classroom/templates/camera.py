"""Exercise 3: the field of view. This file is the one place to change.

The drone's camera sees HFOV_DEG degrees horizontally (ours: 90, on 32x104 depth maps).
A narrower view shows less of the world at each step, so an obstacle that was visible
a moment ago may be out of view now: remembering it is worth more. The paper argues
that this partial observability is why the recurrent D3RQN beats the feed-forward
D3QN.

Your task: narrow the view (try 60, then 45 degrees), train D3RQN and D3QN on it, and
see whether the gap between them grows as the view narrows.

    python -m minid3rqn check fov
    python -m minid3rqn exercise fov --variant d3rqn
    python -m minid3rqn exercise fov --variant d3qn
    python -m minid3rqn exercise fov --variant d3rqn --baseline   (90 degrees)
    python -m minid3rqn exercise fov --variant d3qn --baseline

The image size stays 32x104: only the focal length changes (fx = 52 / tan(HFOV / 2)).
"""
HFOV_DEG = 90.0

"""Exercise 8: errors in the depth seen in training. This file is the one place to change.

The Q-net is trained on ground-truth (GT) depth maps but, in the paper's pipeline, flies
on the depth network's (DispNet's) predicted depth, which is wrong in places. In this
project a D3RQN trained on GT depth flies 0.949 of the test flights on GT depth and
0.835 on predicted depth (docs/beyond.md, "What the analyses found"). The DispNet's
error in ln(depth) has a std of 0.146, which splits into a part per frame (std 0.044),
per column (0.103), per row (0.038) and a finer rest (0.086) (the same section). The
errors that cost flights are at 2-4 m, in the shape of the depth map rather than its
overall scale, and all over the view. (At the classroom's budget the paper's setting
flies about as well on predicted depth as on GT depth: docs/exercises/08_depth_errors.md.)

Your task: write `corrupt`, a random corruption of the GT depth that the Q-net sees
while it TRAINS (the test flights are never corrupted), so that the trained net flies
better on predicted depth, ideally without flying worse on GT depth. The run reports
both. Some ideas, one at a time or combined (e is an error in ln(depth), so
depth * np.exp(e) stays positive):

  * per-pixel noise:        e = rng.normal(0.0, 0.1, depth.shape)
  * a per-frame scale error: e = rng.normal(0.0, 0.05, (n, 1, 1))        (broadcasts)
  * smooth per-column errors of the measured size (std about 0.1): draw a few values
    per frame, e.g. rng.normal(0.0, 0.1, (n, 1, 8)), and interpolate them across the
    104 columns (np.interp, or np.repeat then a moving average along axis 2)
  * errors only at 2-4 m:   np.where((depth >= 2.0) & (depth < 4.0), noisy, depth)
  * blurred edges: average each pixel with its left and right neighbours
    (depth[:, :, :-2], depth[:, :, 1:-1], depth[:, :, 2:]), so that the edges of
    obstacles smear

    python -m minid3rqn check depth-errors
    python -m minid3rqn exercise depth-errors              (trained on your corruption)
    python -m minid3rqn exercise depth-errors --baseline   (trained on clean GT depth)

Rules the checker enforces:
  * change the depth: returning it unchanged is the paper's setting, which
    `exercise depth-errors --baseline` already trains;
  * return an array of the input's shape (n, 32, 104), of positive, finite depths;
  * do not modify `depth` in place (no `depth *= ...`, no `depth[...] = ...`): return
    a new array;
  * draw every random number from `rng` (rng.normal, rng.uniform, rng.integers ...),
    never from np.random.* or Python's random: the library seeds `rng`, so a seed fixes
    the run.
The checker also prints the size of your error next to the DispNet's, split the same way.
"""
import numpy as np


def corrupt(depth, rng):
    """The depth maps the Q-net will see in training, made from GT depth maps.

    Called on every batch of depth maps the training flights observe, before they are
    encoded into the Q-net's [0, 1] frames (depth / 10 m, clipped at 10 m).

    Args:
        depth: GT depth in metres, float32 array (n, H, W): n frames of the training
            flights (one per flight that just moved or restarted), H = 32 rows,
            W = 104 columns. Do not modify it.
        rng: a numpy Generator (np.random.Generator), seeded by the library; the only
            source of random numbers to use.

    Returns:
        An array of the same shape (n, H, W): the corrupted depths, positive and finite.
    """
    return depth        # no corruption yet: the paper's setting (clean GT depth). Yours here.

"""Reference solution, exercise 8 (depth errors): an error shaped like the DispNet's.

The DispNet's error e = ln(predicted / GT depth), measured in this project, has a std of
0.146, split into a part per frame (std 0.044), per column (0.103), per row (0.038) and a
finer rest (0.086) (docs/beyond.md, "What the analyses found"). This corruption draws an
error with those four parts, afresh for every frame, and returns depth * exp(e)
(positive for any e):

    e(v, u) = a + b(u) + c(v) + r(v, u)
    a     one number per frame,                         std 0.044
    b(u)  smooth across the columns (8 knots),          std 0.103
    c(v)  smooth down the rows (4 knots),               std 0.038
    r     independent per pixel,                        std 0.086

What is measured is only the size of each part. The rest is a guess, to discuss: that
the errors are Gaussian in ln(depth), independent of the depth itself (the costly ones
are at 2-4 m: the same section), that the per-column part varies smoothly over about 15
columns (13 degrees), and that the rest is pixel noise (a DispNet's finer errors probably
come in patches). The former ``train-agent --depth-noise S`` (docs/beyond.md, "What did
not help, and the options removed") was a cousin of this: three smooth parts of sizes
S/2, S, S and no pixel noise.

A smooth part is drawn at a few evenly spaced knots and linearly interpolated. A point
between two independent knots has less variance than a knot (on average along the way,
2/3 of it), so the knots are drawn larger by the factor that makes the interpolated
values have the wanted std on average.

The checker's split of this error comes out near the DispNet's, not equal to it: part
of a smooth per-column error is a shift of the whole frame (its mean over the columns),
which the split counts per frame; both depths are clipped at 10 m, which hides the
errors of far pixels; and 32 frames are a small sample.
"""
import numpy as np

STD_FRAME = 0.044      # the DispNet's measured split of its error in ln(depth)
STD_COLUMN = 0.103
STD_ROW = 0.038
STD_REST = 0.086
COLUMN_KNOTS = 8       # a guess: the measurement gives sizes, not smoothness
ROW_KNOTS = 4


def _smooth(rng, n, length, knots, std):
    """(n, length) random curves: ``knots`` N(0, 1) values evenly spaced, linearly
    interpolated, scaled so that the curves' values have std ``std`` on average."""
    x = np.linspace(0.0, knots - 1, length)
    i0 = np.minimum(np.floor(x).astype(np.int64), knots - 2)
    f = x - i0
    k = rng.normal(0.0, 1.0, (n, knots))
    curve = k[:, i0] * (1.0 - f) + k[:, i0 + 1] * f
    variance = np.mean((1.0 - f) ** 2 + f ** 2)      # of an interpolated value, knots ~ N(0, 1)
    return curve * (std / np.sqrt(variance))


def corrupt(depth, rng):
    n, H, W = depth.shape
    e = (rng.normal(0.0, STD_FRAME, (n, 1, 1))
         + _smooth(rng, n, W, COLUMN_KNOTS, STD_COLUMN)[:, None, :]
         + _smooth(rng, n, H, ROW_KNOTS, STD_ROW)[:, :, None]
         + rng.normal(0.0, STD_REST, (n, H, W)))
    return (depth * np.exp(e)).astype(np.float32)

"""Reference solution, exercise 2 (actions): the paper's five plus a sharper turn each way.

+-0.75 rad/s at 2 m/s gives a turning radius of 2.7 m (the paper's sharpest: 4 m).
"""
ACTIONS = [
    [2.0, 0.0],
    [2.0, 0.25],
    [2.0, -0.25],
    [2.0, 0.5],
    [2.0, -0.5],
    [2.0, 0.75],
    [2.0, -0.75],
]

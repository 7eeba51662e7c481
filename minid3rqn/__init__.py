"""minid3rqn: obstacle avoidance from monocular vision with D3RQN, from scratch in NumPy.

Folders follow the data flow: world -> depth -> rl, all learning on autograd via nets.
"""
__version__ = "0.1.0"

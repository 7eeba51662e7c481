"""The 2.5D world: scenes, a pinhole ray-casting camera, the drone environment.

Flow: ``make_scene`` builds a world (pymunk shapes + NumPy arrays); ``render`` /
``render_batch`` ray-cast RGB and ground-truth depth through a ``Camera``; ``step_drones``
steps every drone (the arc flown, collision, reward), and ``DroneEnv`` (N flights, or
one) is the environment around it, the only one; ``topdown`` draws a map.
"""
from .camera import Camera
from .distance import (ClearanceField, clearance_field, nearest_distance, nearest_distance_batch,
                       sample_start_pose)
from .env import DroneEnv
from .geometry import (backproject, inverse_warp_numpy, pose_to_camera_transform, project,
                       relative_transform)
from .kinematics import (ACTION_INTERVAL, ACTIONS, SAFE_DISTANCE, integrate_arc, paper_reward)
from .renderer import render, render_batch, render_depth_batch
from .scenarios import SCENARIOS, make_scene
from .scene import Scene, SceneBatch
from .stepper import step_drones
from .topview import topdown
from ..viz import depth_to_rgb  # re-exported for convenience

__all__ = [
    "Camera", "Scene", "SceneBatch", "SCENARIOS", "make_scene", "render", "render_batch",
    "nearest_distance", "nearest_distance_batch",
    "ClearanceField", "clearance_field", "sample_start_pose", "pose_to_camera_transform",
    "relative_transform", "backproject", "project", "inverse_warp_numpy", "ACTIONS",
    "ACTION_INTERVAL", "SAFE_DISTANCE", "integrate_arc", "paper_reward", "step_drones",
    "DroneEnv", "topdown", "depth_to_rgb",
]

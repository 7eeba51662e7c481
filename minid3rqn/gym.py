"""The world for any Gymnasium library: ``world.DroneEnv`` as a ``gymnasium.Env`` (one
drone) and a ``gymnasium.vector.VectorEnv`` (N drones, stepped as one batch).

    pip install -e ".[gym]"
    import gymnasium, minid3rqn.gym      # importing it registers "minid3rqn/Drone-v0"
    env = gymnasium.make("minid3rqn/Drone-v0", scenario="basic", observation="depth")
    envs = gymnasium.make_vec("minid3rqn/Drone-v0", num_envs=16,
                              vectorization_mode="vector_entry_point")
    env = qnet_input(env, stack=5)       # what our Q-nets read: encoded, 5 frames stacked

Observations: "depth" and "pred" (``depth_model``: a DispNet file or ``DepthEstimator``;
default the scenario's shipped one) in metres, Box(0, 100, (H, W), float32), beyond
100 m read as 100 m; "rgb" Box(0, 255, (H, W, 3), uint8). Actions: Discrete(n_actions).
``info["is_success"]``: ``max_steps`` actions flown without a collision. The other
keywords are ``DroneEnv``'s. The vector form restarts a finished flight within the step
(``AutoresetMode.SAME_STEP``: its last observation in ``info["final_obs"]``).
"""
from __future__ import annotations

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from .world.env import DroneEnv

ENV_ID = "minid3rqn/Drone-v0"
DEPTH_LIMIT = 100.0                  # metres: the top of the depth observation space


def _core(n_envs, scenario="basic", observation="depth", depth_model=None, **kwargs):
    """The ``DroneEnv`` behind an adapter, with its observation space (one flight's)."""
    if observation is None:
        raise ValueError("DroneEnv (gymnasium): observation must be 'depth', 'pred' or "
                         "'rgb'; got None")
    if observation == "pred" and not hasattr(depth_model, "predict"):   # a file, or none
        from .rl.models import load_depth_estimator, shipped_depth_model
        depth_model = load_depth_estimator(depth_model or shipped_depth_model(scenario))
    env = DroneEnv(scenario, n_envs, observation=observation, depth_model=depth_model,
                   **kwargs)
    shape = env.frame_shape
    space = spaces.Box(0, 255, shape + (3,), np.uint8) if observation == "rgb" else \
        spaces.Box(0.0, DEPTH_LIMIT, shape, np.float32)
    return env, space


def _clip(env, obs):
    return obs if env.observation == "rgb" else np.minimum(obs, DEPTH_LIMIT)


class DroneGymEnv(gymnasium.Env):
    """One drone (``world.DroneEnv`` with N = 1) as a ``gymnasium.Env``; see the module
    docstring. Stepping a finished episode raises: ``reset`` first."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 2.5}      # 0.4 s per action

    def __init__(self, render_mode: str | None = None, **kwargs):
        self.env, self.observation_space = _core(1, render_mode=render_mode, **kwargs)
        self.action_space = spaces.Discrete(self.env.n_actions)
        self.render_mode = render_mode

    def _info(self, info) -> dict:
        return {k: v[0].item() for k, v in info.items() if k != "final_obs"}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        obs, info = self.env.reset(seed=seed, options=options)
        return _clip(self.env, obs[0]), self._info(info)

    def step(self, action):
        if not self.action_space.contains(action):
            raise ValueError(f"DroneGymEnv.step: action must be an int in "
                             f"[0, {self.action_space.n}); got {action!r}")
        if not self.env.active[0]:
            raise RuntimeError("DroneGymEnv.step: the episode has ended (or never started); "
                               "call reset() first")
        obs, reward, term, trunc, info = self.env.step(np.array([int(action)]))
        return (_clip(self.env, obs[0]), float(reward[0]), bool(term[0]), bool(trunc[0]),
                self._info(info))

    def render(self):
        return self.env.render()


class DroneVectorEnv(VectorEnv):
    """``num_envs`` drones stepped as one batch (``world.DroneEnv``) as a Gymnasium
    ``VectorEnv``; a finished flight restarts within the step (module docstring)."""

    metadata = {"render_modes": ["rgb_array"], "autoreset_mode": AutoresetMode.SAME_STEP}

    def __init__(self, num_envs: int = 1, render_mode: str | None = None, **kwargs):
        self.env, self.single_observation_space = _core(num_envs, render_mode=render_mode,
                                                        autoreset=True, **kwargs)
        self.num_envs, self.render_mode = self.env.n_envs, render_mode
        self.single_action_space = spaces.Discrete(self.env.n_actions)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)

    def _info(self, info) -> dict:
        out = {k: v for k, v in info.items() if k != "final_obs"}
        out.update({f"_{k}": np.ones(self.num_envs, bool) for k in list(out)})
        return out

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        obs, info = self.env.reset(seed=seed, options=options)
        return _clip(self.env, obs), self._info(info)

    def step(self, actions):
        obs, reward, term, trunc, info = self.env.step(np.asarray(actions))
        out = self._info(info)
        done = term | trunc
        if done.any():
            final = np.empty(self.num_envs, object)
            for i in np.flatnonzero(done):
                final[i] = _clip(self.env, info["final_obs"][i])
            out.update(final_obs=final, _final_obs=done)
        return _clip(self.env, obs), reward.astype(np.float64), term, trunc, out

    def render(self):
        return self.env.render()


def qnet_input(env, stack: int = 5):
    """``env`` (depth in metres) seen as our Q-nets read it (``rl.observe``): each frame
    encoded to [0, 1], then the last ``stack`` frames stacked, (stack, H, W)."""
    from gymnasium.wrappers import FrameStackObservation, TransformObservation
    from .rl.observe import encode_depth
    box = spaces.Box(0.0, 1.0, env.observation_space.shape, np.float32)
    return FrameStackObservation(TransformObservation(env, encode_depth, box), stack)


def register() -> None:
    """Register ``ENV_ID`` with Gymnasium (the package's "gymnasium.envs" entry point)."""
    if ENV_ID not in gymnasium.registry:
        gymnasium.register(ENV_ID, entry_point=DroneGymEnv, vector_entry_point=DroneVectorEnv)


register()

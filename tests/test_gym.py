"""The world as Gymnasium sees it (``minid3rqn.gym``), and the core without Gymnasium."""
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.gym
ROOT = Path(__file__).resolve().parent.parent


def test_the_core_imports_and_flies_without_gymnasium():
    """With gymnasium blocked, the package imports and an env flies."""
    code = ("import sys; sys.modules['gymnasium'] = None\n"
            "import numpy as np, minid3rqn.cli, minid3rqn.rl, minid3rqn.classroom\n"
            "from minid3rqn.world import DroneEnv\n"
            "env = DroneEnv('basic', 2, seed=0, n_worlds=2); env.reset()\n"
            "env.step(np.zeros(2, np.int64))\n"
            "try:\n    import minid3rqn.gym\nexcept ImportError:\n    print('no gym')\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "no gym"


gymnasium = pytest.importorskip("gymnasium")
from gymnasium.utils.env_checker import check_env  # noqa: E402

import minid3rqn.gym as mgym  # noqa: E402
from minid3rqn.world import DroneEnv  # noqa: E402


class _Flat:
    """A stand-in DispNet: 5 m everywhere."""

    def predict(self, rgb):
        return np.full(rgb.shape[:3], 5.0, np.float32)


@pytest.mark.parametrize("observation", ["depth", "pred", "rgb"])
def test_check_env_passes_without_warnings(observation):
    kw = {"depth_model": _Flat()} if observation == "pred" else {}
    env = gymnasium.make(mgym.ENV_ID, observation=observation, n_worlds=2,
                         render_mode="rgb_array", **kw)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs) and isinstance(info["is_success"], bool)
    assert env.action_space == gymnasium.spaces.Discrete(5)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.shape[0] == 192


def test_registered_by_the_entry_point_and_by_import():
    from importlib.metadata import entry_points
    names = {e.name: e.value for e in entry_points(group="gymnasium.envs")}
    assert names.get("minid3rqn") == "minid3rqn.gym:register"
    assert mgym.ENV_ID in gymnasium.registry


def test_episode_seeds_success_and_fresh_entropy():
    env = gymnasium.make(mgym.ENV_ID, scenario="corners", max_steps=3, n_worlds=2)
    first, _ = env.reset(seed=5)
    assert np.array_equal(env.reset(seed=5)[0], first)
    done = False
    while not done:
        obs, reward, terminated, truncated, info = env.step(0)
        done = terminated or truncated
    assert info["is_success"] == truncated and isinstance(reward, float)
    with pytest.raises(RuntimeError, match="reset"):
        env.unwrapped.step(0)
    with pytest.raises(TypeError):
        env.unwrapped.reset(5)                               # keyword-only
    a, b = (gymnasium.make(mgym.ENV_ID, n_worlds=4).unwrapped.env.world_seeds for _ in "ab")
    assert not np.array_equal(a, b)                          # no seed: fresh entropy


def test_bad_arguments_name_the_argument():
    with pytest.raises(ValueError, match="scenario must be one of"):
        gymnasium.make(mgym.ENV_ID, scenario="moon")
    with pytest.raises(ValueError, match="observation must be"):
        gymnasium.make(mgym.ENV_ID, observation=None)
    with pytest.raises(TypeError, match="colour"):
        gymnasium.make(mgym.ENV_ID, colour="red")
    env = gymnasium.make(mgym.ENV_ID, n_worlds=2)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action must be an int in \[0, 5\)"):
        env.unwrapped.step(7)


def test_vector_form_steps_the_batch_as_the_core_does():
    """make_vec gives one batched env: the same flights as ``DroneEnv`` with the same
    seed, finished flights restarted within the step (their last view in final_obs)."""
    envs = gymnasium.make_vec(mgym.ENV_ID, num_envs=4, vectorization_mode="vector_entry_point",
                              n_worlds=2, max_steps=3)
    core = DroneEnv("basic", 4, seed=1, n_worlds=2, max_steps=3, autoreset=True)
    obs, info = envs.reset(seed=1)
    np.testing.assert_array_equal(obs, core.reset()[0])
    assert envs.observation_space.contains(obs) and info["_scene_seed"].all()
    ended = 0
    for _ in range(3):                                       # every flight ends by step 3
        actions = envs.action_space.sample()
        obs, reward, terminated, truncated, info = envs.step(actions)
        want, want_r, *_, want_info = core.step(actions)
        np.testing.assert_array_equal(obs, want)
        np.testing.assert_array_equal(reward, want_r)
        done = terminated | truncated
        if done.any():
            np.testing.assert_array_equal(info["_final_obs"], done)
            for i in np.flatnonzero(done):
                np.testing.assert_array_equal(info["final_obs"][i], want_info["final_obs"][i])
            ended += done.sum()
    assert ended >= 4


def test_qnet_input_is_the_encoded_stack():
    from minid3rqn.rl.observe import encode_depth
    env = mgym.qnet_input(gymnasium.make(mgym.ENV_ID, n_worlds=2), stack=5)
    obs, _ = env.reset(seed=0)
    raw = env.unwrapped.env.obs[0]
    assert obs.shape == (5, 32, 104) and env.observation_space.contains(obs)
    np.testing.assert_array_equal(obs[-1], encode_depth(raw))
    np.testing.assert_array_equal(obs[0], obs[-1])           # the first frame fills it

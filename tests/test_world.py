"""Tests of the 2.5D world: camera, scenes, renderer, geometry, environment, policies.

Run: OMP_NUM_THREADS=1 python -m pytest tests/test_world.py -q
"""
import numpy as np
import pymunk
import pytest

from minid3rqn.world import (ACTIONS, SCENARIOS, Camera, DroneEnv, SceneBatch, depth_to_rgb,
                             inverse_warp_numpy, make_scene, nearest_distance,
                             nearest_distance_batch, paper_reward, pose_to_camera_transform,
                             relative_transform, render, render_batch, sample_start_pose,
                             topdown)
from minid3rqn.world.distance import nearest_distance_by_kind
from minid3rqn.world.geometry import backproject, bilinear_sample_numpy
from minid3rqn.world.kinematics import integrate_arc, substep_poses
from minid3rqn.world.renderer import cast_columns

pytestmark = pytest.mark.world


@pytest.fixture(scope="module")
def scenes():
    return {name: make_scene(name, 3) for name in SCENARIOS}


def pymunk_nearest_distance(scene, xy) -> np.ndarray:
    """Reference: ``scene.space.point_query_nearest`` one point at a time, (..., 2) -> (...)."""
    xy = np.asarray(xy, dtype=np.float64)
    flat = xy.reshape(-1, 2)
    reach = float(np.hypot(*(scene.bounds[2:] - scene.bounds[:2]))) + 1e3
    out = np.empty(len(flat))
    for k, (x, y) in enumerate(flat):
        info = scene.space.point_query_nearest((float(x), float(y)), reach, pymunk.ShapeFilter())
        out[k] = np.inf if info is None else info.distance
    return out.reshape(xy.shape[:-1])


def start_poses(scene, n, seed=0):
    rng = np.random.default_rng(seed)
    return np.stack([sample_start_pose(scene, rng) for _ in range(n)])


# ----------------------------------------------------------------------------- camera

def test_camera_intrinsics():
    cam = Camera()
    assert cam.K.dtype == np.float64 and cam.K.shape == (3, 3)
    assert cam.fx == pytest.approx(52.0)          # (104 / 2) / tan(45 deg)
    assert (cam.cx, cam.cy) == (51.5, 15.5)
    # The outer edges of the first and last columns span the horizontal field of view.
    edge = (cam.width - 0.5 - cam.cx) / cam.fx
    assert np.degrees(2 * np.arctan(edge)) == pytest.approx(90.0)
    assert Camera(64, 208).fx == pytest.approx(2 * cam.fx)


@pytest.mark.parametrize("kwargs, error", [
    (dict(hfov_deg=0), ValueError), (dict(hfov_deg=180), ValueError),
    (dict(hfov_deg=-10), ValueError), (dict(hfov_deg="wide"), TypeError),
    (dict(height=0), ValueError), (dict(width=0), ValueError), (dict(width=10.5), TypeError)])
def test_camera_rejects_bad_configs(kwargs, error):
    with pytest.raises(error, match="Camera: (hfov_deg|height|width)"):
        Camera(**kwargs)


def test_camera_horizon_row():
    """horizon_row moves the principal point (the horizon) up: more floor is seen, and
    nearer; the middle row is the default camera."""
    cam, raised = Camera(), Camera(horizon_row=4)
    assert raised.cy == 4.0 and raised.K[1, 2] == 4.0 and raised.K[0, 2] == cam.cx
    # flying 1 m high, the last row meets the floor 1 m / y_n ahead
    assert 1 / cam.row_rays()[-1] == pytest.approx(52 / 15.5)
    assert 1 / raised.row_rays()[-1] == pytest.approx(52 / 27)
    assert Camera(horizon_row=15.5) == cam and hash(Camera(horizon_row=15.5)) == hash(cam)


@pytest.mark.parametrize("row, error", [(-1, ValueError), (31.5, ValueError),
                                        ("top", TypeError), (True, TypeError)])
def test_camera_rejects_bad_horizon_rows(row, error):
    with pytest.raises(error, match="Camera: horizon_row"):
        Camera(horizon_row=row)


# ----------------------------------------------------------------------------- scenes

def test_make_scene_errors():
    with pytest.raises(ValueError, match="basic.*channel.*intersections.*corners"):
        make_scene("forest", 0)
    with pytest.raises(TypeError, match="seed"):
        make_scene("basic", 1.5)


@pytest.mark.parametrize("name", ["channel", "intersections", "corners"])
def test_transfer_worlds_have_pillars_that_leave_a_way_through(name):
    """The transfer corridors and streets hold pillars (so flying down the middle fails),
    and beside each there is room to pass: some point 1 m from its surface keeps >= 1 m
    from everything."""
    ring = np.stack([np.cos(np.linspace(0, 2 * np.pi, 72)), np.sin(np.linspace(0, 2 * np.pi, 72))], 1)
    for seed in range(5):
        scene = make_scene(name, seed)
        assert len(scene.circle_radii) >= 2
        for c, r in zip(scene.circle_centres, scene.circle_radii):
            clearance = nearest_distance(scene, c + (r + 1.0) * ring)
            assert clearance.max() >= 1.0, (name, seed, c, r)


def test_textures_carry_contrast():
    """Every random appearance has an accent at least 0.15 darker or lighter than its
    base (view synthesis, SSIM and edge-aware smoothness need visible texture)."""
    from minid3rqn.world.textures import C0, C1, random_appearance
    rng = np.random.default_rng(0)
    rows = np.stack([random_appearance(rng) for _ in range(300)])
    brightness = lambda c: c.max(axis=-1)            # HSV value
    assert np.all(np.abs(brightness(rows[:, C0]) - brightness(rows[:, C1])) >= 0.15)


@pytest.mark.parametrize("name", SCENARIOS)
def test_scene_determinism(name):
    a, b, c = make_scene(name, 11), make_scene(name, 11), make_scene(name, 12)
    for field in ("circle_centres", "wall_a", "poly_verts", "appearances"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert not (a.wall_a.shape == c.wall_a.shape and np.array_equal(a.wall_a, c.wall_a)
                and np.array_equal(a.circle_centres, c.circle_centres)
                and np.array_equal(a.poly_verts, c.poly_verts))


@pytest.mark.parametrize("name", SCENARIOS)
def test_nearest_distance_matches_pymunk(scenes, name):
    scene = scenes[name]
    xy = np.random.default_rng(1).uniform(scene.bounds[:2], scene.bounds[2:], (300, 2))
    d = nearest_distance(scene, xy)
    np.testing.assert_allclose(d, pymunk_nearest_distance(scene, xy), atol=1e-9)
    if len(scene.poly_verts):                               # inside a polygon: negative
        centre = scene.poly_verts[0].mean(0)
        assert nearest_distance(scene, centre) < 0
        assert pymunk_nearest_distance(scene, centre) == pytest.approx(
            float(nearest_distance(scene, centre)))
    batch = SceneBatch([scenes["basic"], scene])
    both = nearest_distance_batch(batch, np.stack([xy[:50], xy[50:100]]))
    np.testing.assert_allclose(both[1], d[50:100], atol=1e-12)
    np.testing.assert_allclose(both[0], nearest_distance(scenes["basic"], xy[:50]), atol=1e-12)
    # one distance per kind of obstacle; their minimum is the nearest distance, and each
    # kind's is pymunk's over the shapes of that kind alone
    kinds = nearest_distance_by_kind(batch, np.stack([xy[:50], xy[50:100]]))
    assert kinds.shape == (2, 50, 3)
    np.testing.assert_allclose(kinds.min(-1), both, atol=1e-12)
    if len(scene.circle_radii):
        round_only = np.hypot(*(xy[50:100, None] - scene.circle_centres).transpose(2, 0, 1))
        np.testing.assert_allclose(kinds[1, :, 0], (round_only - scene.circle_radii).min(1),
                                   atol=1e-12)
    with pytest.raises(ValueError, match="nearest_distance_by_kind: xy must be"):
        nearest_distance_by_kind(batch, xy[:50])


# ----------------------------------------------------------------------------- renderer

@pytest.mark.parametrize("name", SCENARIOS)
def test_depth_equals_pymunk_ray_hits(scenes, name):
    """Column depth = pymunk segment_query hit distance along the same ray, as pinhole
    depth (the ray r = f + x_n g has forward component 1, so depth = alpha * length)."""
    scene, cam = scenes[name], Camera()
    poses = start_poses(scene, 6)
    xn = cam.column_rays()
    _, depth = render_batch(scene, poses, cam)
    hits = cast_columns(scene.batch(), poses, xn)["t"]
    reach = 200.0
    cols = np.random.default_rng(2).integers(0, cam.width, (len(poses), 12))
    for n, pose in enumerate(poses):
        f = np.array([np.cos(pose[2]), np.sin(pose[2])])
        g = np.array([np.sin(pose[2]), -np.cos(pose[2])])
        for u in cols[n]:
            end = pose[:2] + reach * (f + xn[u] * g)
            q = scene.space.segment_query_first(tuple(pose[:2]), tuple(end), 0.0,
                                                pymunk.ShapeFilter())
            assert q is not None
            assert hits[n, u] == pytest.approx(q.alpha * reach, abs=1e-7)
            # The image's middle rows see the wall (the planes there are far away).
            assert depth[n, cam.height // 2, u] == pytest.approx(q.alpha * reach, rel=1e-6)


@pytest.mark.parametrize("cam", [Camera(64, 208), Camera(64, 208, horizon_row=8.5)],
                         ids=["middle", "raised-horizon"])
def test_depth_of_floor_and_ceiling(scenes, cam):
    scene = scenes["basic"]
    pose = start_poses(scene, 1)[0]
    _, depth = render(scene, pose, cam)
    t = cast_columns(scene.batch(), pose[None], cam.column_rays())["t"][0]
    yn = cam.row_rays()
    plane = np.where(yn > 0, scene.altitude / yn, (scene.ceiling - scene.altitude) / -yn)
    np.testing.assert_allclose(depth, np.minimum(t[None, :], plane[:, None]), rtol=1e-6)
    assert np.all(np.isfinite(depth)) and depth.min() > 0


@pytest.mark.parametrize("cam", [Camera(), Camera(horizon_row=4)],
                         ids=["middle", "raised-horizon"])
def test_backprojected_pixels_lie_on_surfaces(scenes, cam):
    """Every pixel back-projected with its depth lands on the floor, the ceiling or an
    obstacle surface: the depth is exactly consistent with K."""
    scene = scenes["intersections"]
    pose = start_poses(scene, 1, seed=4)[0]
    _, depth = render(scene, pose, cam)
    pts = backproject(depth, cam.K).reshape(-1, 4 - 1)
    T = pose_to_camera_transform(pose, scene.altitude)
    world = pts @ T[:3, :3].T + T[:3, 3]
    on_plane = (np.abs(world[:, 2]) < 1e-4) | (np.abs(world[:, 2] - scene.ceiling) < 1e-4)
    on_wall = np.abs(nearest_distance(scene, world[:, :2])) < 1e-4
    assert np.all(on_plane | on_wall)


def test_render_outputs_and_batch_equals_single(scenes):
    cam = Camera()
    worlds = [scenes[name] for name in SCENARIOS]
    poses = np.stack([start_poses(s, 1, seed=5)[0] for s in worlds])
    rgb, depth = render_batch(worlds, poses, cam)
    assert rgb.shape == (4, 32, 104, 3) and rgb.dtype == np.uint8
    assert depth.shape == (4, 32, 104) and depth.dtype == np.float32
    for n, scene in enumerate(worlds):
        r1, d1 = render(scene, poses[n], cam)
        np.testing.assert_array_equal(r1, rgb[n])
        np.testing.assert_array_equal(d1, depth[n])
        assert r1.std() > 10                   # textured, not flat
    # Many poses in one world.
    r2, d2 = render_batch(worlds[0], np.repeat(poses[:1], 3, 0), cam)
    np.testing.assert_array_equal(r2[2], rgb[0])


def test_render_rejects_bad_input(scenes):
    with pytest.raises(ValueError, match="pose"):
        render(scenes["basic"], (1.0, 2.0))
    with pytest.raises(TypeError, match="camera"):
        render(scenes["basic"], (1.0, 2.0, 0.0), camera=(32, 104))
    with pytest.raises(ValueError, match="poses"):
        render_batch([scenes["basic"], scenes["channel"]], np.zeros((3, 3)))


# ----------------------------------------------------------------------------- geometry

def test_transforms():
    pose_a, pose_b = np.array([1.0, 2.0, 0.3]), np.array([1.5, 2.2, 0.5])
    T_a = pose_to_camera_transform(pose_a, altitude=1.0)
    # Camera z (forward) is the heading, camera y (down) is world -z, camera x is right.
    np.testing.assert_allclose(T_a[:3, 2], [np.cos(0.3), np.sin(0.3), 0.0])
    np.testing.assert_allclose(T_a[:3, 1], [0.0, 0.0, -1.0])
    np.testing.assert_allclose(T_a[:3, 0], [np.sin(0.3), -np.cos(0.3), 0.0])
    np.testing.assert_allclose(T_a[:3, 3], [1.0, 2.0, 1.0])
    P_w = np.array([4.0, -1.0, 2.5, 1.0])
    P_a = np.linalg.solve(T_a, P_w)
    P_b = np.linalg.solve(pose_to_camera_transform(pose_b), P_w)
    np.testing.assert_allclose(relative_transform(pose_a, pose_b) @ P_a, P_b, atol=1e-12)
    batch = relative_transform(np.stack([pose_a, pose_b]), np.stack([pose_b, pose_a]))
    np.testing.assert_allclose(batch[0] @ batch[1], np.eye(4), atol=1e-12)


def test_warp_identity_and_bilinear():
    rng = np.random.default_rng(0)
    cam = Camera()
    img = rng.random((32, 104, 3))
    depth = rng.uniform(1, 10, (32, 104))
    warped, valid = inverse_warp_numpy(img, depth, cam.K, np.eye(4))
    assert valid[1:-1, 1:-1].all()          # edge pixels may round to just outside
    np.testing.assert_allclose(warped[valid], img[valid], atol=1e-9)
    # Half-pixel shift: bilinear average of neighbours; out of view -> invalid and 0.
    coords = np.stack(np.meshgrid(np.arange(104) + 0.5, np.arange(32), indexing="xy"), -1)
    out, ok = bilinear_sample_numpy(img[None], coords[None].astype(float))
    np.testing.assert_allclose(out[0, :, :-1], 0.5 * (img[:, :-1] + img[:, 1:]), atol=1e-12)
    assert not ok[0, :, -1].any() and ok[0, :, :-1].all()
    with pytest.raises(ValueError, match="padding"):
        inverse_warp_numpy(img, depth, cam.K, np.eye(4), padding="reflect")


def test_warp_matches_autograd_bilinear_sample():
    """The NumPy warp and the autograd sampler share one convention."""
    sample = pytest.importorskip("minid3rqn.autograd.sample")
    rng = np.random.default_rng(1)
    img = rng.random((2, 6, 9, 3))
    coords = rng.uniform(-1.5, 10, (2, 5, 7, 2))
    for padding in ("zeros", "border"):
        ours, ok = bilinear_sample_numpy(img, coords, padding)
        theirs, valid = sample.bilinear_sample(img.transpose(0, 3, 1, 2), coords, padding)
        np.testing.assert_allclose(ours, theirs.data.transpose(0, 2, 3, 1), atol=1e-12)
        np.testing.assert_array_equal(ok, valid[:, 0] > 0)


@pytest.mark.parametrize("name", ["basic", "corners"])
def test_warp_reconstructs_next_frame(scenes, name):
    """With GT depth and GT relative pose, the next frame warped into the current view
    reproduces it on pixels seen in both frames."""
    scene, cam = scenes[name], Camera(64, 208)
    env_actions = ACTIONS
    err_warp, err_none = [], []
    for pose in start_poses(scene, 3, seed=6):
        nxt = integrate_arc(pose, *env_actions[1], 0.4)
        rgb_t, depth_t = render(scene, pose, cam)
        rgb_s, depth_s = render(scene, nxt, cam)
        T = relative_transform(pose, nxt)
        warped, valid = inverse_warp_numpy(rgb_s, depth_t, cam.K, T)
        # Visible in both: the target point's depth in the source agrees with the
        # source's own depth there (not occluded).
        z_s = (backproject(depth_t, cam.K) @ T[:3, :3].T + T[:3, 3])[..., 2]
        d_src, _ = inverse_warp_numpy(depth_s, depth_t, cam.K, T)
        both = valid & (np.abs(d_src - z_s) < 0.05 * z_s)
        assert both.mean() > 0.5
        diff = np.abs(warped - rgb_t.astype(np.float32)).mean(-1)
        err_warp.append(diff[both].mean())
        err_none.append(np.abs(rgb_s.astype(float) - rgb_t).mean())
    assert np.mean(err_warp) < 6.0                      # intensity levels of 255
    assert np.mean(err_warp) < 0.35 * np.mean(err_none)


# ----------------------------------------------------------------------------- kinematics

def test_arcs_compose_and_turn_at_radius():
    pose = np.array([1.0, -2.0, 0.7])
    a = integrate_arc(integrate_arc(pose, 2.0, 0.5, 0.15), 2.0, 0.5, 0.25)
    np.testing.assert_allclose(a, integrate_arc(pose, 2.0, 0.5, 0.4), atol=1e-12)
    # A full circle at 2 m/s and 0.5 rad/s has radius 4 m and returns to the start.
    circle = integrate_arc(pose, 2.0, 0.5, np.linspace(0, 4 * np.pi, 50))
    centre = pose[:2] + 4.0 * np.array([-np.sin(0.7), np.cos(0.7)])
    np.testing.assert_allclose(np.linalg.norm(circle[:, :2] - centre, axis=1), 4.0, atol=1e-12)
    np.testing.assert_allclose(circle[-1, :2], pose[:2], atol=1e-12)
    sub = substep_poses(pose[None], np.array([2.0]), np.array([0.0]), 0.4, 8)
    np.testing.assert_allclose(np.diff(sub[0, :, 0]), 0.1 * np.cos(0.7), atol=1e-12)


def test_paper_reward():
    assert paper_reward(1.7, False) == 1.7 and paper_reward(0.3, True) == -1.0
    np.testing.assert_array_equal(paper_reward(np.array([2.0, 0.4]), np.array([False, True])),
                                  [2.0, -1.0])


# ----------------------------------------------------------------------------- environment

def test_env_determinism_observations_and_options():
    """The same seed flies the same flights; reset(seed=s) starts over as seed s; each
    observation has its shape; options pin the world and the start; no seed: fresh
    entropy."""
    runs = []
    for _ in range(2):
        env = DroneEnv("channel", 2, seed=4, observation="rgb")
        obs, info = env.reset()
        assert obs.shape == (2, 32, 104, 3) and obs.dtype == np.uint8
        rng = np.random.default_rng(0)
        trace = [env.poses.copy()]
        for _ in range(5):
            obs, r, term, trunc, info = env.step(rng.integers(env.n_actions, size=2))
            trace.append(env.poses.copy())
        runs.append((np.array(trace), obs))
    np.testing.assert_array_equal(runs[0][0], runs[1][0])
    np.testing.assert_array_equal(runs[0][1], runs[1][1])
    env = DroneEnv("channel", seed=0)
    obs, info = env.reset(seed=9)
    assert obs.shape == (1, 32, 104) and obs.dtype == np.float32 and obs.min() > 0
    np.testing.assert_array_equal(obs, env.gt_depth())
    p1 = env.poses.copy()
    env.reset()
    env.reset(seed=9)
    np.testing.assert_array_equal(env.poses, p1)
    _, info = env.reset(options={"scene_seed": 5, "pose": (1.0, 2.0, 0.5)})
    assert info["scene_seed"][0] == 5 and env.poses[0].tolist() == [1.0, 2.0, 0.5]
    assert DroneEnv(observation=None).reset()[0] is None
    assert not np.array_equal(DroneEnv(n_worlds=4).world_seeds,     # no seed: fresh
                              DroneEnv(n_worlds=4).world_seeds)     # entropy


def test_env_worlds_train_and_test_are_disjoint():
    """worlds='train' and 'test' draw their pools from disjoint seed ranges; a sequence
    of seeds is the pool itself."""
    train = DroneEnv("basic", 4, seed=0, worlds="train", n_worlds=5, observation=None)
    test = DroneEnv("basic", 4, seed=0, worlds="test", n_worlds=5, observation=None)
    assert train.world_seeds.max() < 1_000_000 <= test.world_seeds.min()
    assert len(set(train.world_seeds.tolist())) == 5
    own = DroneEnv("basic", 8, seed=3, worlds=[11, 12], observation=None)
    _, info = own.reset()
    assert set(info["scene_seed"].tolist()) <= {11, 12}


def test_env_autoreset_and_ended_flights():
    """Without autoreset an ended flight stays put (reward 0, flags False); with it the
    flight restarts at once and info["final_obs"] holds its last view."""
    env = DroneEnv("basic", 3, seed=0, n_worlds=2, max_steps=2)
    env.reset()
    _, _, first, _, _ = env.step(np.zeros(3, np.int64))
    obs, reward, term, trunc, info = env.step(np.zeros(3, np.int64))
    assert not env.active.any() and (first | term | trunc).all()
    assert (info["is_success"] == trunc).all()
    poses = env.poses.copy()
    obs2, reward, term, trunc, info = env.step(np.zeros(3, np.int64))
    np.testing.assert_array_equal(env.poses, poses)
    np.testing.assert_array_equal(obs2, obs)
    assert not (reward.any() or term.any() or trunc.any())
    auto = DroneEnv("basic", 3, seed=0, n_worlds=2, max_steps=2, autoreset=True)
    auto.reset()
    done = np.zeros(3, bool)
    while not done.any():
        obs, _, term, trunc, info = auto.step(np.zeros(3, np.int64))
        done = term | trunc
    assert auto.active.all() and (auto.steps[done] == 0).all()
    np.testing.assert_array_equal(obs[done], auto.gt_depth()[done])   # the new episodes'
    assert not np.array_equal(info["final_obs"][done], obs[done])      # first views
    np.testing.assert_array_equal(info["final_obs"][~done], obs[~done])


def _facing_wall(env, scene_seed=2):
    """Reset ``env`` 3 m from a wall of a channel world, flying straight at it."""
    scene = make_scene("channel", scene_seed)
    a, b = scene.wall_a[0], scene.wall_b[0]
    mid = 0.5 * (a + b)
    normal = np.array([-(b - a)[1], (b - a)[0]]) / np.linalg.norm(b - a)
    if not scene.in_region(mid + 3.0 * normal):
        normal = -normal
    start = mid + 3.0 * normal
    yaw = np.arctan2(-normal[1], -normal[0])
    env.reset(options={"scene_seed": scene_seed, "pose": (start[0], start[1], yaw)})
    return a, b, normal


@pytest.mark.parametrize("speed", [2.0, 25.0])
def test_flying_into_a_wall_is_caught_at_any_speed(speed):
    """Even at 10 m per step (100 sub-steps) the zero-thickness wall is a collision on the
    step whose arc reaches it: every step before ends on the start side, clear of it."""
    env = DroneEnv("channel", seed=1, actions=[[speed, 0.0]], observation=None)
    a, b, normal = _facing_wall(env)
    for _ in range(10):
        before = np.dot(env.poses[0, :2] - a, normal)
        _, reward, term, trunc, info = env.step(np.array([0]))
        side = np.dot(env.poses[0, :2] - a, normal)
        assert side == pytest.approx(before - speed * env.dt)    # the arc flown to its end
        if term[0]:
            break
        assert side >= 0.5                                # clear of the wall, start side
    assert term[0] and not trunc[0] and info["collided"][0] and reward[0] == -1.0
    assert before - speed * env.dt < 0.5                  # the arc came within 0.5 m
    assert not env.active[0]


def test_step_drones_checks_the_whole_arc_and_pays_at_its_end():
    """step_drones: collision anywhere on the arc; the pose and d_nearest at its end; the
    reward gets the yaw rate only if it takes a third argument."""
    from minid3rqn.world import step_drones
    scene = make_scene("channel", 2)
    a, b = scene.wall_a[0], scene.wall_b[0]
    mid = 0.5 * (a + b)
    normal = np.array([-(b - a)[1], (b - a)[0]]) / np.linalg.norm(b - a)
    if not scene.in_region(mid + 3.0 * normal):
        normal = -normal
    start = mid + 0.8 * normal                  # 0.8 m before the wall, facing it: the
    yaw = np.arctan2(-normal[1], -normal[0])    # 2 m arc ends 1.2 m beyond it
    poses = np.array([[start[0], start[1], yaw]] * 2)
    actions = np.array([[5.0, 0.0], [5.0, 0.5]])
    batch = SceneBatch([scene, scene])
    moved = step_drones(poses, actions, np.array([0, 1]), batch)
    end = integrate_arc(poses, actions[:, 0], actions[:, 1], 0.4)
    np.testing.assert_allclose(moved.poses, end, atol=1e-12)
    np.testing.assert_array_equal(moved.d_nearest,
                                  nearest_distance_batch(batch, end[:, None, :2])[:, 0])
    assert moved.collided.all()
    np.testing.assert_array_equal(moved.rewards, [-1.0, -1.0])
    seen = []
    moved = step_drones(poses, actions, np.array([0, 1]), batch,
                        reward_fn=lambda d, c, w: seen.append(w) or np.where(c, -2.0, d))
    np.testing.assert_array_equal(seen[0], [0.0, 0.5])
    np.testing.assert_array_equal(moved.rewards, [-2.0, -2.0])
    moved = step_drones(poses, actions, np.array([1, 0]), batch, reward_fn=lambda d, c: 3.0)
    np.testing.assert_array_equal(moved.rewards, [3.0, 3.0])
    with pytest.raises(ValueError, match="one reward per flight"):
        step_drones(poses, actions, np.array([1, 0]), batch, reward_fn=lambda d, c: [1, 2, 3])


def test_action_table_and_reward_hooks():
    env = DroneEnv("basic", seed=0, actions=[[1.0, 0.0], [1.0, 1.0]],
                   reward_fn=lambda d, collided: 42.0 + collided, max_steps=2,
                   observation=None)
    assert DroneEnv("basic", reward_fn=None).reward_fn is paper_reward
    assert env.n_actions == 2
    env.reset()
    p0 = env.poses[0].copy()
    _, reward, term, trunc, info = env.step(np.array([0]))
    assert np.linalg.norm(env.poses[0, :2] - p0[:2]) == pytest.approx(0.4)
    assert reward[0] in (42.0, 43.0)
    if not term[0]:
        _, _, term, trunc, info = env.step(np.array([1]))
        assert env.poses[0, 2] - p0[2] == pytest.approx(0.4)
        assert trunc[0] != term[0]


@pytest.mark.parametrize("bad", [[5], [-1], [1.0], ["0"], [0, 0], 0])
def test_bad_action_raises(bad):
    env = DroneEnv("basic", seed=0, observation=None)
    env.reset()
    with pytest.raises(ValueError, match=r"DroneEnv.step: actions must (lie in \[0, 5\)|be an "
                                         r"int array of shape \(1,\))"):
        env.step(np.array(bad))


@pytest.mark.parametrize("kwargs, match", [
    (dict(scenario="moon"), "scenario must be one of"),
    (dict(n_envs=0), "n_envs must be an int >= 1"),
    (dict(worlds="valid"), "worlds must be 'train', 'test' or a sequence"),
    (dict(worlds=[1.5]), "worlds must be 'train', 'test' or a sequence"),
    (dict(n_worlds=0), "n_worlds"),
    (dict(observation="gray"), "observation must be one of"),
    (dict(observation="pred"), "depth_model"),
    (dict(depth_model=object()), "depth_model"),
    (dict(actions=[0.0, 0.25]), "actions must have shape"),
    (dict(max_steps=0), "max_steps"),
    (dict(render_mode="human"), "render_mode must be one of"),
])
def test_bad_env_arguments_name_the_argument(kwargs, match):
    with pytest.raises(ValueError, match=match):
        DroneEnv(**kwargs)


def test_bad_env_calls():
    with pytest.raises(TypeError, match="reward_fn"):
        DroneEnv(reward_fn=3)
    with pytest.raises(TypeError, match="depth_fn"):
        DroneEnv(depth_fn=3)
    with pytest.raises(RuntimeError, match="reset"):
        DroneEnv().step(np.array([0]))
    with pytest.raises(ValueError, match="unknown option"):
        DroneEnv().reset(options={"newworld": True})
    with pytest.raises(ValueError, match="options\\['pose'\\]"):
        DroneEnv().reset(options={"pose": (1.0, 2.0)})
    with pytest.raises(TypeError):
        DroneEnv().reset(3)                                  # seed is keyword-only
    env = DroneEnv(n_envs=2, observation=None)
    env.reset()
    with pytest.raises(ValueError, match="actions must lie in"):
        env.step(np.array([0, 7]))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.array([0]))


def test_batched_flights_match_single_flights():
    """N flights stepped together fly, see and are paid as each flown alone from the same
    world and start."""
    n = 3
    vec = DroneEnv("intersections", n, seed=7, observation="rgb")
    vec.reset()
    seeds, poses = vec.scene_seeds.copy(), vec.poses.copy()
    obs, info = vec.reset(options={"scene_seed": seeds, "pose": poses})
    singles = [DroneEnv("intersections", seed=0, observation="rgb") for _ in range(n)]
    for i, env in enumerate(singles):
        o, _ = env.reset(options={"scene_seed": int(seeds[i]), "pose": poses[i]})
        np.testing.assert_array_equal(obs[i], o[0])
    rng = np.random.default_rng(3)
    for _ in range(6):
        actions = rng.integers(0, 5, n)
        obs, reward, term, trunc, info = vec.step(actions)
        for i, env in enumerate(singles):
            if not env.active[0]:
                continue
            o, r, t, tr, inf = env.step(actions[i:i + 1])
            np.testing.assert_allclose(vec.poses[i], env.poses[0], atol=1e-12)
            np.testing.assert_array_equal(obs[i], o[0])
            assert reward[i] == pytest.approx(r[0]) and term[i] == t[0] and trunc[i] == tr[0]
            assert info["d_nearest"][i] == pytest.approx(inf["d_nearest"][0], abs=1e-9)


def test_policies():
    from minid3rqn.rl.policies import OraclePolicy, RandomPolicy, StraightPolicy
    env = DroneEnv("corners", 4, seed=0, observation=None)
    for policy, crashes in ((OraclePolicy(), False), (StraightPolicy(), True)):
        obs, _ = env.reset()
        policy.reset(env)
        crashed = np.zeros(4, bool)
        while env.active.any():
            obs, _, term, _, _ = env.step(policy.act(obs))
            crashed |= term
        assert crashed.all() if crashes else not crashed.any()
    random = RandomPolicy(env.n_actions, seed=0)
    random.reset(env)
    acts = random.act(None)
    assert acts.shape == (4,) and acts.dtype.kind == "i"


def test_render_rgb_array():
    env = DroneEnv("basic", seed=0, render_mode="rgb_array")
    env.reset()
    env.step(np.array([0]))
    img = env.render()
    assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[0] == 192
    assert DroneEnv().render() is None


# ----------------------------------------------------------------------------- pictures

def test_pictures(scenes):
    img = topdown(scenes["basic"], trajectory=[[3, 3], [5, 4], [7, 7]], pose=(7, 7, 0.5),
                  camera=Camera(), size=200)
    assert max(img.size) <= 201 and img.mode == "RGB"
    rgb = depth_to_rgb(np.array([[0.5, 15.0]]))
    assert rgb[0, 0, 0] > rgb[0, 0, 2] and rgb[0, 1, 2] > rgb[0, 1, 0]   # red near, blue far


def test_a_gif_of_a_frame(tmp_path):
    from minid3rqn.viz import write_gif
    rgb, depth = render(make_scene("basic", 0), (5.0, 5.0, 0.3))
    write_gif([rgb, depth_to_rgb(depth)], tmp_path / "a.gif")
    assert (tmp_path / "a.gif").stat().st_size > 0


@pytest.mark.parametrize("shape", [(33, 105), (1, 1), (5, 9)])
def test_odd_image_sizes_have_finite_depth(scenes, shape):
    """With an odd height the middle row looks at the horizon: it must see a wall."""
    scene = scenes["channel"]
    cam = Camera(*shape, hfov_deg=100.0)
    rgb, depth = render(scene, start_poses(scene, 1)[0], cam)
    assert rgb.shape == shape + (3,) and np.all(np.isfinite(depth)) and depth.min() > 0


def test_wall_normals_face_the_camera():
    """In a square room the wall ahead is lit by its inward normal, from either side."""
    from minid3rqn.world.scene import SceneBuilder
    from minid3rqn.world.textures import LIGHT, make_appearance, wall_shade
    grey = make_appearance((0.5, 0.5, 0.5), (0.6, 0.6, 0.6))
    b = SceneBuilder(grey, grey)
    room = np.array([[-5.0, -5.0], [5.0, -5.0], [5.0, 5.0], [-5.0, 5.0]])
    b.add_polyline(room, b.add_appearance(grey), closed=True)
    scene = b.build("room", 0, 1.0, 3.0, room)
    cam = Camera()
    for yaw, inward in ((0.0, (-1.0, 0.0)), (np.pi, (1.0, 0.0)), (np.pi / 2, (0.0, -1.0))):
        hit = cast_columns(scene.batch(), np.array([[0.0, 0.0, yaw]]), cam.column_rays())
        centre = cam.width // 2
        assert hit["t"][0, centre] == pytest.approx(5.0, rel=1e-3)
        assert hit["shade"][0, centre] == pytest.approx(wall_shade(np.dot(inward, LIGHT)))


@pytest.mark.parametrize("height", [32, 33])  # 33: a row on the horizon (y_n = 0)
def test_depth_only_renderer_equals_full_render(height):
    from minid3rqn.world import SceneBatch, render_depth_batch, sample_start_pose
    scenes = [make_scene("basic", seed=i) for i in range(3)]
    rng = np.random.default_rng(0)
    poses = np.array([sample_start_pose(s, rng) for s in scenes])
    cam = Camera(height=height, width=104)
    _, depth = render_batch(SceneBatch(scenes), poses, cam)
    only = render_depth_batch(SceneBatch(scenes), poses, cam)
    assert np.all(np.isfinite(only)) and np.all(only > 0)
    np.testing.assert_array_equal(only, depth)


def test_cast_paths_agree(scenes):
    """The single-pose cast and the flat many-pose cast give the same columns, bit for
    bit, with 2 poses and with 6."""
    xn = Camera().column_rays()
    for name in SCENARIOS:
        scene = scenes[name]
        poses = start_poses(scene, 6, seed=2)
        many = cast_columns(scene.batch(), poses, xn)
        few = cast_columns(scene.batch(), poses[:2], xn)
        for k in range(2):
            one = cast_columns(scene.batch(), poses[k:k + 1], xn)
            for key in ("t", "s", "shade", "cos", "app"):
                np.testing.assert_array_equal(one[key][0], many[key][k], err_msg=key)
                np.testing.assert_array_equal(one[key][0], few[key][k], err_msg=key)


def test_cast_paths_agree_on_a_shared_corner():
    """A column whose ray passes exactly through the corner two walls share meets both at
    the same t: every cast path picks the lower segment index (in the many-pose path this
    is the tie branch of ``_cast_many``), and circles keep losing ties to segments."""
    from minid3rqn.world.scene import SceneBuilder
    from minid3rqn.world.textures import make_appearance
    builder = SceneBuilder(make_appearance((0.5, 0.5, 0.5), (0.2, 0.2, 0.2)),
                           make_appearance((0.6, 0.6, 0.6), (0.3, 0.3, 0.3)))
    app = builder.add_appearance(make_appearance((0.8, 0.2, 0.2), (0.3, 0.1, 0.1)))
    # Two walls meeting at (5, 0), straight ahead of a camera at the origin facing +x,
    # a pillar off to the side and an enclosure around everything.
    builder.add_polyline([(5.0, -1.0), (5.0, 0.0), (6.0, 1.0)], app)
    builder.add_circle((4.0, 1.5), 0.4, app)
    builder.add_polyline([(-10, -10), (10, -10), (10, 10), (-10, 10)], app, closed=True)
    scene = builder.build("corner", 0, 1.0, 3.0, [(-10, -10), (10, -10), (10, 10), (-10, 10)])
    xn = Camera(32, 105).column_rays()                  # odd width: column 52 has x_n = 0
    assert xn[52] == 0.0
    poses = np.tile([0.0, 0.0, 0.0], (6, 1))
    poses[1:, 0] -= np.arange(1, 6) * 0.5               # further back, same ray
    many = cast_columns(scene.batch(), poses, xn)
    few = cast_columns(scene.batch(), poses[:3], xn)
    for k in range(3):
        one = cast_columns(scene.batch(), poses[k:k + 1], xn)
        assert one["t"][0, 52] == 5.0 + 0.5 * k
        for key in ("t", "s", "shade", "cos", "app"):
            np.testing.assert_array_equal(one[key][0], many[key][k], err_msg=key)
            np.testing.assert_array_equal(one[key][0], few[key][k], err_msg=key)
    # The wall (5, -1) -> (5, 0) is segment 0 and wins the tie: s at its end = its length.
    assert np.all(many["s"][:, 52] == 1.0)


def test_render_cache_follows_scene_batch_set(scenes):
    """The floor/ceiling tables cached per batch follow ``SceneBatch.set``."""
    worlds = [scenes["basic"], scenes["channel"]]
    poses = np.stack([start_poses(s, 1, seed=1)[0] for s in worlds])
    batch = SceneBatch(worlds)
    render_batch(batch, poses, Camera())                       # fills the cache
    new = scenes["corners"]
    batch.set(1, new)
    poses[1] = start_poses(new, 1, seed=1)[0]
    rgb, depth = render_batch(batch, poses, Camera())
    rgb_ref, depth_ref = render_batch(SceneBatch([worlds[0], new]), poses, Camera())
    np.testing.assert_array_equal(rgb, rgb_ref)
    np.testing.assert_array_equal(depth, depth_ref)


def test_scene_batch_subset_keeps_its_own_render_cache(scenes):
    """A subset of a batch (the flights still flying) renders its own worlds, and
    rendering it never leaves stale tables in the full batch's cache (or vice versa)."""
    from minid3rqn.world.renderer import render_depth_batch
    worlds = [scenes["basic"], scenes["channel"], scenes["corners"]]
    poses = np.stack([start_poses(s, 1, seed=2)[0] for s in worlds])
    batch = SceneBatch(worlds)
    for idx in ([1], [0, 2], [0, 1, 2], [2]):
        sub = batch.subset(idx)
        assert sub.scenes == [worlds[k] for k in idx] and len(sub) == len(idx)
        ref_rgb, ref_depth = render_batch(SceneBatch([worlds[k] for k in idx]), poses[idx])
        rgb, depth = render_batch(sub, poses[idx])
        np.testing.assert_array_equal(rgb, ref_rgb)
        np.testing.assert_array_equal(depth, ref_depth)
        np.testing.assert_array_equal(render_depth_batch(sub, poses[idx]), ref_depth)
        np.testing.assert_array_equal(render_depth_batch(batch, poses),
                                      render_batch(SceneBatch(worlds), poses)[1])

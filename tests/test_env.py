"""twin.env: the twin as a dm_control.rl.control Environment, by dm_env's conventions.

A small camera (64 x 40 px) and lidar (90 beams) keep these quick; the scene is the
twin's own MjSpec scene.
"""

import dm_env
import numpy as np
import pytest
from dm_env import specs

from stack.cells import ConfigError
from stack.planning.model import build_model
from stack.planning.task import load_task
from twin.config import TwinConfig
from twin.env import GuardTask, Outage, TwinPhysics, make_environment
from vigil.run import REPO

TASK = REPO / "config" / "task-r1.yaml"
GRID = {"numbering": [[12, 10, 8, 6, 4, 2], [11, 9, 7, 5, 3, 1]], "cell_size_m": [1.0, 1.5]}


@pytest.fixture(scope="module")
def model():
    return build_model(load_task(TASK))


def small_config(**person) -> TwinConfig:
    cfg = {
        "grid": GRID,
        "camera": {"width_px": 64, "height_px": 40},
        "lidar": {"beams": 90},
        "robot": {"start_cell": 7},
    }
    if person:
        cfg["person"] = person
    return TwinConfig.from_dict(cfg)


def short_walk():
    # enters at the door side, walks 1 m into cell 1, stops for good at 1.25 s
    return {"waypoints": [{"x_m": 5.5, "y_m": 1.9}, {"x_m": 5.5, "y_m": 0.9, "speed_mps": 0.8}]}


@pytest.fixture
def env(model):
    e = make_environment(small_config(**short_walk()), model, seed=4, tail_s=0.5)
    yield e
    e.close()


def test_specs_follow_dm_env(env):
    a = env.action_spec()
    assert isinstance(a, specs.BoundedArray) and a.shape == (3,)
    assert np.all(a.minimum < 0) and np.all(a.maximum > 0)
    assert a.maximum[0] == pytest.approx(env.twin.config.robot.max_linear_mps)
    spec = env.observation_spec()
    assert {"camera", "scan", "odometry", "camera_stamp", "scan_stamp", "time"} <= set(spec)
    assert spec["camera"].shape == (40, 64, 3) and spec["camera"].dtype == np.uint8
    assert spec["scan"].shape == (90,)
    ts = env.reset()
    assert ts.step_type == dm_env.StepType.FIRST and ts.reward is None
    for name, s in spec.items():
        s.validate(ts.observation[name])  # every observation matches its spec
    a.validate(np.zeros(3))


def test_zero_action_rollout_keeps_the_robot_and_reads_sensors_at_their_rates(env):
    ts = env.reset()
    start = ts.observation["odometry"][:2].copy()
    camera_stamps, scan_stamps, odom_stamps = set(), set(), set()
    rewards = []
    while not ts.last():
        ts = env.step(np.zeros(3))
        assert ts.step_type in (dm_env.StepType.MID, dm_env.StepType.LAST)
        rewards.append(ts.reward)
        camera_stamps.add(round(float(ts.observation["camera_stamp"]), 3))
        scan_stamps.add(round(float(ts.observation["scan_stamp"]), 3))
        odom_stamps.add(round(float(ts.observation["odometry_stamp"]), 3))
    t_end = float(ts.observation["time"])
    assert t_end == pytest.approx(env.twin.person.end_time_s + 0.5, abs=0.021)
    assert ts.discount == 1.0  # the episode ends with the script, not in a terminal state
    assert np.linalg.norm(ts.observation["odometry"][:2] - start) < 0.05
    # camera and lidar at 10 Hz, odometry at 25 Hz, as the ROS bridge publishes
    assert sorted(camera_stamps)[:3] == [0.0, 0.1, 0.2]
    assert sorted(odom_stamps)[:4] == [0.0, 0.04, 0.08, 0.12]
    assert len(scan_stamps) == len(camera_stamps)
    # the robot rests at the rest cell (reward 0) until the person is in restricted cell 1,
    # where an idle robot elsewhere is not rewarded either: every reward is the table's
    assert set(np.round(rewards, 9)) <= {0.0}


def test_moving_costs_the_tables_move_reward_over_a_decision_step(model):
    e = make_environment(small_config(present=False), model, decision_step_s=2.0,
                         time_limit_s=0.2)  # fmt: skip
    try:
        ts = e.reset()
        rewards = []
        while not ts.last():
            ts = e.step(np.array([0.2, 0.0, 0.0]))
            rewards.append(ts.reward)
        assert len(rewards) == 10  # 0.2 s of 0.02 s control periods
        move = model.task.rewards.move  # robot still in rest cell 7: only the move cost
        assert rewards[0] == pytest.approx(move * 0.02 / 2.0)
    finally:
        e.close()


def test_same_seed_same_episode_different_seed_different_noise(model):
    def run(seed):
        e = make_environment(small_config(**short_walk()), model, seed=seed, time_limit_s=0.3)
        try:
            ts, out = e.reset(), []
            while not ts.last():
                ts = e.step(np.array([0.1, 0.0, 0.2]))
                out.append(ts.observation["scan"].copy())
            again = e.reset().observation["odometry"].copy()  # a reset starts it all over
            return np.array(out), again
        finally:
            e.close()

    a, a0 = run(1)
    b, _ = run(1)
    c, _ = run(2)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    np.testing.assert_allclose(a0[:3], [*small_config().grid.center(7), 0.0])


def test_an_outage_freezes_its_sensor_only(model):
    outage = Outage("camera", 0.15, 0.45)
    e = make_environment(small_config(present=False), model, outages=[outage], time_limit_s=0.6)
    try:
        ts = e.reset()
        seen = []
        while not ts.last():
            ts = e.step(np.zeros(3))
            seen.append((float(ts.observation["time"]), float(ts.observation["camera_stamp"]),
                         float(ts.observation["scan_stamp"])))  # fmt: skip
        at = {round(t, 2): (c, s) for t, c, s in seen}
        assert at[0.4][0] == pytest.approx(0.1)  # no frame in [0.15, 0.45)
        assert at[0.4][1] == pytest.approx(0.4)  # the lidar goes on
        assert at[0.5][0] == pytest.approx(0.5)
    finally:
        e.close()


def test_physics_is_the_twins_own_model_and_data(env):
    physics = env.physics
    assert isinstance(physics, TwinPhysics)
    assert physics.model.ptr is env.twin.model
    env.reset()
    env.step(np.array([0.3, 0.0, 0.0]))
    assert physics.data.time == pytest.approx(env.twin.time_s)
    assert physics.timestep() == pytest.approx(env.twin.config.control_period_s)


def test_bad_input_is_named(model):
    with pytest.raises(ConfigError, match="sensor"):
        Outage("sonar", 0.0, 1.0)
    with pytest.raises(ConfigError, match="t1 >= t0"):
        Outage("lidar", 2.0, 1.0)
    with pytest.raises(ConfigError, match="decision_step_s"):
        GuardTask(model, decision_step_s=0.0)


def test_an_episode_of_two_walkers_lasts_until_the_last_one_has_stopped(model):
    first = short_walk()  # stops for good at 1.25 s
    later = {"waypoints": [{"x_m": 1.5, "y_m": 1.9}, {"x_m": 1.5, "y_m": 0.4, "speed_mps": 0.5}]}
    cfg = TwinConfig.from_dict(
        {
            "grid": GRID,
            "camera": {"width_px": 64, "height_px": 40},
            "lidar": {"beams": 90},
            "robot": {"start_cell": 7},
            "people": [first, later],
        }
    )
    env = make_environment(cfg, model, seed=4, tail_s=0.5)
    try:
        assert env.twin.end_time_s == pytest.approx(3.0)  # 1.5 m at 0.5 m/s
        ts = env.reset()
        while not ts.last():
            ts = env.step(np.zeros(3))
        assert env.twin.time_s == pytest.approx(3.5, abs=0.05)  # not 1.25 + 0.5
    finally:
        env.close()


def test_the_twin_renders_headless_without_mujoco_gl_in_the_environment():
    """A study's worker (or any command) that imports the twin with no MUJOCO_GL set
    gets EGL: before, `bench/bench_fidelity.py` run without MUJOCO_GL=egl failed every
    rendered episode with "gladLoadGL error" (GLFW, no display)."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    code = "import twin.env, os; print(os.environ['MUJOCO_GL'], os.environ['PYOPENGL_PLATFORM'])"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=True, cwd=str(REPO))  # fmt: skip
    assert out.stdout.split() == ["egl", "egl"]
    env["MUJOCO_GL"] = "glfw"  # a user's choice stands
    code = "import twin, os; print(os.environ['MUJOCO_GL'])"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=True, cwd=str(REPO))  # fmt: skip
    assert out.stdout.strip() == "glfw"

"""The holonomic base follows body-frame velocity commands within its limits; odometry."""

import math

import numpy as np
import pytest

from twin.config import TwinConfig
from twin.twin import Pose2D, Twin, VelocityCommand


def _twin(**robot) -> Twin:
    data = {"room": {"furniture": False}, "person": {"present": False}, "robot": robot}
    data["odometry"] = {"linear_noise_std_mps": 0.0, "angular_noise_std_radps": 0.0}
    return Twin(TwinConfig.from_dict(data), seed=0)


def test_tracks_a_forward_command():
    twin = _twin()
    start = twin.ground_truth().robot
    twin.run(2.0, VelocityCommand(0.3, 0.0, 0.0))
    gt = twin.ground_truth()
    assert gt.robot_velocity[0] == pytest.approx(0.3, abs=0.01)
    assert gt.robot_velocity[1] == pytest.approx(0.0, abs=0.01)
    # 2 s at 0.3 m/s less the ramp-up at 1 m/s^2 (0.3 s, losing 0.045 m)
    assert gt.robot.x_m - start.x_m == pytest.approx(0.6 - 0.045, abs=0.02)
    assert gt.robot.y_m == pytest.approx(start.y_m, abs=1e-3)


def test_turns_in_place_and_then_moves_in_its_own_frame():
    twin = _twin()
    start = twin.ground_truth().robot
    twin.run(math.pi / 2 / 0.5, VelocityCommand(0.0, 0.0, 0.5))
    twin.run(0.5, VelocityCommand())
    turned = twin.ground_truth().robot
    # a yaw command turns the robot about its centre, not about its start point
    assert math.hypot(turned.x_m - start.x_m, turned.y_m - start.y_m) < 2e-3
    assert turned.yaw_rad == pytest.approx(math.pi / 2, abs=0.03)
    twin.run(2.0, VelocityCommand(0.3, 0.0, 0.0))  # forward now means north
    gt = twin.ground_truth()
    heading = math.atan2(gt.robot.y_m - turned.y_m, gt.robot.x_m - turned.x_m)
    assert heading == pytest.approx(turned.yaw_rad, abs=0.02)
    twin.run(2.0, VelocityCommand(0.0, 0.3, 0.0))  # left of north is west
    assert twin.ground_truth().robot.x_m < gt.robot.x_m - 0.4


def test_velocity_and_acceleration_limits():
    twin = _twin(max_linear_mps=0.5, max_linear_accel_mps2=1.0, max_angular_radps=1.0)
    twin.step(VelocityCommand(3.0, 0.0, 0.0))
    # one control period at 1 m/s^2 reaches at most 0.02 m/s (plus the actuator lag)
    assert twin.ground_truth().robot_velocity[0] <= 0.02 + 1e-6
    twin.run(2.0, VelocityCommand(3.0, 4.0, 5.0))
    v = twin.ground_truth().robot_velocity
    assert math.hypot(v[0], v[1]) == pytest.approx(0.5, abs=0.01)
    assert v[2] == pytest.approx(1.0, abs=0.02)
    twin.run(1.0, None)  # no command stops the base
    assert np.allclose(twin.ground_truth().robot_velocity, 0.0, atol=1e-3)


def test_noise_free_odometry_reads_the_ground_truth():
    twin = _twin()
    for cmd in (VelocityCommand(0.3, 0.1, 0.5), VelocityCommand(-0.2, 0.2, -0.4)):
        twin.run(2.0, cmd)
    odom, gt = twin.odometry(), twin.ground_truth()
    assert odom.pose.x_m == pytest.approx(gt.robot.x_m, abs=2e-3)
    assert odom.pose.y_m == pytest.approx(gt.robot.y_m, abs=2e-3)
    assert odom.pose.yaw_rad == pytest.approx(gt.robot.yaw_rad, abs=1e-3)
    assert odom.vx_mps == pytest.approx(gt.robot_velocity[0], abs=0.01)


def test_noisy_odometry_drifts_with_the_configured_noise():
    cfg = TwinConfig.from_dict(
        {
            "person": {"present": False},
            "odometry": {"linear_noise_std_mps": 0.05, "angular_noise_std_radps": 0.05},
        }
    )
    twin = Twin(cfg, seed=3)
    twin.set_robot_pose(Pose2D(1.0, 1.0, 0.0))
    vs = []
    for _ in range(100):
        twin.step(VelocityCommand(0.2, 0.0, 0.0))
        vs.append(twin.odometry().vx_mps - twin.ground_truth().robot_velocity[0])
    assert np.std(vs[20:]) == pytest.approx(0.05, rel=0.35)
    odom, gt = twin.odometry(), twin.ground_truth()
    drift = math.hypot(odom.pose.x_m - gt.robot.x_m, odom.pose.y_m - gt.robot.y_m)
    assert 0.0 < drift < 0.2


def test_a_differential_base_never_moves_sideways():
    twin = _twin(drive="diff", start_yaw_rad=0.7)
    start = twin.ground_truth().robot
    twin.run(2.0, VelocityCommand(0.0, 0.3, 0.0))  # a lateral command is dropped
    gt = twin.ground_truth().robot
    assert math.hypot(gt.x_m - start.x_m, gt.y_m - start.y_m) < 2e-3
    # an arc: forward and turning at once; the motion stays along the heading
    prev = gt
    for _ in range(60):
        twin.step(VelocityCommand(0.3, 0.2, 0.6))
        now = twin.ground_truth().robot
        dx, dy = now.x_m - prev.x_m, now.y_m - prev.y_m
        mid = prev.yaw_rad + math.remainder(now.yaw_rad - prev.yaw_rad, math.tau) / 2
        lateral = -math.sin(mid) * dx + math.cos(mid) * dy
        assert abs(lateral) < 2e-4, lateral
        prev = now
    assert math.hypot(prev.x_m - gt.x_m, prev.y_m - gt.y_m) > 0.3
    # the holonomic base does slide sideways under the same lateral command
    holo = _twin(start_yaw_rad=0.7)
    holo.run(2.0, VelocityCommand(0.0, 0.3, 0.0))
    moved = holo.ground_truth().robot
    assert math.hypot(moved.x_m - start.x_m, moved.y_m - start.y_m) > 0.4

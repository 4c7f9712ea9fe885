"""The twin as a ``dm_env`` environment, through ``dm_control.rl.control``.

:func:`make_environment` wraps one :class:`twin.twin.Twin` (its own MjSpec scene, kept
as it is: the model and data are shared with dm_control, not rebuilt) in a
:class:`dm_control.rl.control.Environment`:

- **physics**: :class:`TwinPhysics`, a :class:`dm_control.mujoco.Physics` over the
  twin's ``MjModel``/``MjData``; one physics "step" is one :meth:`Twin.step` (one
  ``control_period_s``, the twin's own rate limits, person placement and odometry);
- **action**: the robot's body-frame velocity command ``[vx, vy, wz]`` (m/s, m/s,
  rad/s), bounded by the robot's limits;
- **observations**: the ceiling camera's image, the lidar scan and the wheel odometry,
  each at its own rate as the ROS bridge publishes them (``twin.bridge_node``: odometry
  25 Hz, lidar and camera 10 Hz, nothing from a sensor during its outage), with the
  simulated time each was taken (a stamp that did not change means no new reading);
- **reward**: the task model's reward table (``stack.planning.model``, table 4.1) at
  the true state (robot cell, person cell and direction) and the action's class (Do
  nothing when the command is zero, else a move), spread over a decision step's length
  so that one decision step of ``decision_step_s`` earns the table's value;
- **episode**: the people's scripts (``twin.people``) from the start until the last
  has stopped for good, plus ``tail_s``.

Same twin config and seed, same episode: :meth:`GuardTask.initialize_episode` reseeds
the twin's noise generator at every reset.
"""

from __future__ import annotations

import logging
import math
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
from dm_control import mujoco as dm_mujoco
from dm_control.mujoco import engine, index
from dm_control.mujoco.wrapper import MjData
from dm_control.rl import control
from dm_env import specs

from stack.cells import ConfigError
from stack.perception.observation import direction_of_velocity
from stack.planning.model import ACTIONS, FactoredModel
from twin.config import TwinConfig
from twin.twin import Twin, VelocityCommand

SENSORS = ("odometry", "scan", "camera")
STILL_BELOW_MPS = 0.05  # a true person speed below this is "Not moving" (vigil.report)
DO_NOTHING = ACTIONS.index("Do nothing")
A_MOVE = next(i for i, a in enumerate(ACTIONS) if a != "Do nothing")  # all moves cost alike


@dataclass(frozen=True)
class Outage:
    """No readings from ``sensor`` ("camera" or "lidar") for ``t0_s <= t < t1_s``."""

    sensor: str
    t0_s: float
    t1_s: float

    def __post_init__(self) -> None:
        if self.sensor not in ("camera", "lidar"):
            raise ConfigError("outage.sensor", self.sensor, "must be camera or lidar")
        if not (math.isfinite(self.t0_s) and math.isfinite(self.t1_s)) or self.t1_s < self.t0_s:
            raise ConfigError("outage", (self.t0_s, self.t1_s), "finite times with t1 >= t0")


class TwinPhysics(dm_mujoco.Physics):
    """dm_control's Physics over a :class:`Twin`'s own model and data (shared).

    Use :meth:`of_twin`; :meth:`set_control` takes the velocity command and
    :meth:`step` advances one control period per step through :meth:`Twin.step`.
    """

    twin: Twin
    command: VelocityCommand
    _command_bits = b""  # the last action's bytes (its command is kept while they hold)
    _named_structs = None

    @classmethod
    def of_twin(cls, twin: Twin) -> TwinPhysics:
        """Wrap ``twin`` (its MjData is shared: the twin and this physics are one)."""
        physics = cls(MjData(twin.data))
        physics.twin = twin
        physics.command = VelocityCommand()
        return physics

    def _reload_from_data(self, data: MjData) -> None:
        """dm_control's, but the named indexers (``physics.named``) are made on first
        use: the twin's code never asks, and making them was a tenth of an in-process
        episode's set-up."""
        if not isinstance(data, MjData):
            raise TypeError(f"Expected wrapper.MjData. Got: {type(data)}.")
        self._data = data
        self._warnings = self.data.warning.number
        self._warnings_before = np.empty_like(self._warnings)
        self._new_warnings = np.empty(dtype=bool, shape=(len(self._warnings),))
        with self._contexts_lock:
            if self._contexts:
                self._free_rendering_contexts()
        try:
            self.after_reset()
        except control.PhysicsError as e:
            logging.warning(e)
        self._named_structs = None

    @property
    def named(self) -> engine.NamedIndexStructs:
        if self._named_structs is None:
            axis_indexers = index.make_axis_indexers(self.model)
            self._named_structs = engine.NamedIndexStructs(
                model=index.struct_indexer(self.model, "mjmodel", axis_indexers),
                data=index.struct_indexer(self.data, "mjdata", axis_indexers),
            )
        return self._named_structs

    def timestep(self) -> float:
        """One step is the twin's control period [s] (physics substeps inside)."""
        return self.twin.config.control_period_s

    def set_control(self, control_: np.ndarray) -> None:
        action = np.asarray(control_, float).reshape(3)
        bits = action.tobytes()  # exact, signed zeros too: the same action, the same command
        if bits != self._command_bits:
            vx, vy, wz = (float(v) for v in action)
            self.command = VelocityCommand(vx, vy, wz)
            self._command_bits = bits

    def step(self, nstep: int = 1) -> None:
        # dm_control's check_invalid_state, inline (a context manager every 20 ms period)
        np.copyto(self._warnings_before, self._warnings)
        for _ in range(nstep):
            self.twin.step(self.command)
        np.greater(self._warnings, self._warnings_before, out=self._new_warnings)
        if self._new_warnings.any():
            names = np.compress(self._new_warnings, list(mujoco.mjtWarning.__members__))
            message = f"Physics state is invalid. Warning(s) raised: {', '.join(names)}"
            if self._warnings_cause_exception:
                raise control.PhysicsError(message)
            logging.warning(message)

    def reset(self, keyframe_id=None) -> None:  # noqa: ARG002 - the twin has one start
        self.twin.reset()
        self.command = VelocityCommand()
        self._command_bits = b""


class SensorSchedule:
    """When each sensor reads, as the ROS bridge publishes (periods from its rates).

    Args:
        periods_s: sensor -> period [s].
        outages: intervals without readings.
    """

    def __init__(self, periods_s: dict[str, float], outages: Sequence[Outage] = ()):
        self.periods_s = dict(periods_s)
        self.outages = tuple(outages)
        self.next_s = dict.fromkeys(self.periods_s, 0.0)

    def reset(self) -> None:
        self.next_s = dict.fromkeys(self.periods_s, 0.0)

    def due(self, name: str, t: float) -> bool:
        """Whether ``name`` is due at ``t`` (then its next time moves on)."""
        if t + 1e-9 < self.next_s[name]:
            return False
        while self.next_s[name] <= t + 1e-9:
            self.next_s[name] += self.periods_s[name]
        return True

    def due_now(self, names: Sequence[str], t: float) -> tuple[str, ...]:
        """Those of ``names`` due at ``t`` (:meth:`due` of each, in order)."""
        if t + 1e-9 < min(self.next_s.values()):
            return ()  # most control periods: no sensor reads
        return tuple(name for name in names if self.due(name, t))

    def out(self, sensor: str, t: float) -> bool:
        return any(o.sensor == sensor and o.t0_s <= t < o.t1_s for o in self.outages)

    def next_time_s(self) -> float:
        return min(self.next_s.values())


class GuardTask(control.Task):
    """The guarding task on the twin: sensors in, a velocity command out.

    Args:
        model: the task model (its grid, restricted cells and reward table).
        seed: the twin's noise seed, drawn again at every reset.
        outages: sensor outages (faults).
        decision_step_s: the model's step length [s]: the reward table's value is
            earned over this long (``vigil.system`` gives the planner ``min_step_s`` 2.5).
        tail_s: the episode runs this long after the person's script has ended.
        odom_rate_hz: odometry rate (the deployment's ``odom_rate_hz``).
        render: render the camera image at its instants; False: only its stamp moves
            (a model of the camera pipeline draws the detections from the truth,
            :mod:`stack.perception.model`).
        reward: compute the reward table's value at every step; False: 0.0 (the
            in-process loop scores runs from the trace, and the reward's ground truth
            at 50 Hz was a tenth of its time).
    """

    def __init__(
        self,
        model: FactoredModel,
        seed: int = 0,
        outages: Sequence[Outage] = (),
        decision_step_s: float = 2.5,
        tail_s: float = 5.0,
        odom_rate_hz: float = 25.0,
        render: bool = True,
        reward: bool = True,
    ):
        super().__init__()
        self.render = bool(render)
        self.reward = bool(reward)
        if not decision_step_s > 0 or not tail_s >= 0 or not odom_rate_hz > 0:
            raise ConfigError(
                "decision_step_s/tail_s/odom_rate_hz",
                (decision_step_s, tail_s, odom_rate_hz),
                "must be > 0, >= 0, > 0",
            )
        self.model = model
        self.seed = int(seed)
        self.outages = tuple(outages)
        self.decision_step_s = float(decision_step_s)
        self.tail_s = float(tail_s)
        self.odom_period_s = 1.0 / odom_rate_hz
        self._R = model.reward_table().reshape(model.n_states, len(ACTIONS))
        self.schedule: SensorSchedule | None = None
        self.due_now: tuple[str, ...] = ()  # sensors due at the last step (outages included)
        self._obs: dict[str, np.ndarray] = {}
        self._end_s = math.inf

    # -- dm_control hooks ---------------------------------------------------------------
    def initialize_episode(self, physics: TwinPhysics) -> None:
        twin = physics.twin
        twin.rng = np.random.default_rng(self.seed)  # same seed, same episode
        cfg = twin.config
        periods = {
            "odometry": self.odom_period_s,
            "scan": 1.0 / cfg.lidar.rate_hz,
            "camera": 1.0 / cfg.camera.rate_hz,
        }
        self.schedule = SensorSchedule(periods, self.outages)
        self._obs = self._buffers(cfg)
        self._end_s = twin.end_time_s + self.tail_s  # the scripts are fixed for the episode
        self._read_sensors(twin)

    @staticmethod
    def _buffers(cfg: TwinConfig) -> OrderedDict:
        c, lc = cfg.camera, cfg.lidar
        return OrderedDict(
            time=np.zeros((), np.float64),
            odometry=np.zeros(6, np.float64),
            odometry_stamp=np.full((), -1.0),
            scan=np.full(lc.beams, np.inf, np.float32),
            scan_stamp=np.full((), -1.0),
            camera=np.zeros((c.height_px, c.width_px, 3), np.uint8),
            camera_stamp=np.full((), -1.0),
        )

    def before_step(self, action: np.ndarray, physics: TwinPhysics) -> None:
        physics.set_control(action)

    def after_step(self, physics: TwinPhysics) -> None:
        self._read_sensors(physics.twin)

    def get_observation(self, physics: TwinPhysics) -> OrderedDict:
        # the time and the stamps are new arrays when they change (as copies), the
        # sensors' buffers are shared (overwritten at their next reading)
        return OrderedDict(self._obs)

    def get_reward(self, physics: TwinPhysics) -> float:
        if not self.reward:
            return 0.0
        return self.reward_of(physics.twin, physics.command) * (
            physics.timestep() / self.decision_step_s
        )

    def get_termination(self, physics: TwinPhysics) -> float | None:
        # the last walker's end (0 without people) and the tail
        return 1.0 if physics.twin.time_s >= self._end_s - 1e-9 else None

    def action_spec(self, physics: TwinPhysics) -> specs.BoundedArray:
        rc = physics.twin.config.robot
        hi = np.array([rc.max_linear_mps, rc.max_linear_mps, rc.max_angular_radps])
        return specs.BoundedArray((3,), np.float64, -hi, hi, name="velocity_vx_vy_wz")

    def observation_spec(self, physics: TwinPhysics) -> OrderedDict:
        obs = self._obs or self._buffers(physics.twin.config)
        return OrderedDict((k, specs.Array(v.shape, v.dtype, name=k)) for k, v in obs.items())

    # -- the reward -------------------------------------------------------------------------
    def reward_of(self, twin: Twin, command: VelocityCommand) -> float:
        """The reward table's value at the true state under ``command``'s action class."""
        gt = twin.ground_truth()
        person: list[tuple[int | None, str]] = [(None, "Not moving")]
        if gt.person is not None and gt.person.cell is not None:
            vx, vy = gt.person.velocity_mps
            person = [(gt.person.cell, direction_of_velocity(vx, vy, STILL_BELOW_MPS).label)]
        person += [(None, "Not moving")] * (self.model.people - 1)
        s = self.model.state_index(gt.robot_cell, person)
        moving = math.hypot(command.vx_mps, command.vy_mps) > 1e-6 or abs(command.wz_radps) > 1e-6
        return float(self._R[s, A_MOVE if moving else DO_NOTHING])

    # -- sensors ----------------------------------------------------------------------------
    def _read_sensors(self, twin: Twin) -> None:
        sched = self.schedule
        assert sched is not None, "initialize_episode first"
        t = twin.time_s
        o = self._obs
        o["time"] = np.array(t)
        self.due_now = sched.due_now(SENSORS, t)
        if "odometry" in self.due_now:
            od = twin.odometry()
            o["odometry"][:] = (od.pose.x_m, od.pose.y_m, od.pose.yaw_rad, od.vx_mps, od.vy_mps,
                                od.wz_radps)  # fmt: skip
            o["odometry_stamp"] = np.array(t)
        if "scan" in self.due_now and not sched.out("lidar", t):
            o["scan"][:] = twin.scan().ranges_m
            o["scan_stamp"] = np.array(t)
        if "camera" in self.due_now and not sched.out("camera", t):
            if self.render:
                o["camera"][:] = twin.render_camera()
            o["camera_stamp"] = np.array(t)


def make_environment(
    config: TwinConfig,
    model: FactoredModel,
    seed: int = 0,
    outages: Sequence[Outage] = (),
    decision_step_s: float = 2.5,
    tail_s: float = 5.0,
    odom_rate_hz: float = 25.0,
    time_limit_s: float = float("inf"),
    render: bool = True,
    reward: bool = True,
) -> GuardEnvironment:
    """The twin as a ``dm_env.Environment`` (one step = one twin control period).

    Args:
        config: the twin's scene (with the person's script).
        model: the task model (rewards, grid).
        seed: the twin's noise seed.
        outages, decision_step_s, tail_s, odom_rate_hz, render, reward: see
            :class:`GuardTask`.
        time_limit_s: an upper bound on the episode (the script's end comes first).

    Raises:
        ConfigError: a bad value (named).
    """
    twin = Twin(config, seed=seed)
    physics = TwinPhysics.of_twin(twin)
    task = GuardTask(model, seed, outages, decision_step_s, tail_s, odom_rate_hz, render, reward)
    return GuardEnvironment(physics, task, time_limit=time_limit_s, n_sub_steps=1)


class GuardEnvironment(control.Environment):
    """dm_control's Environment that also frees the twin's renderer on :meth:`close`."""

    @property
    def twin(self) -> Twin:
        return self.physics.twin

    def close(self) -> None:
        self.physics.twin.close()
        super().close()

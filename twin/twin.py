"""The digital twin's pure Python API (no rclpy).

``Twin(config, seed)`` builds the scene, then ``step(command)`` advances physics by one
control period under a body-frame velocity command, and the sensors are read on demand:
``render_camera()``, ``scan()``, ``odometry()``; ``ground_truth()`` tells what really
happened. Same config and seed, same run: MuJoCo is deterministic on one machine, the
person's script is a pure function of time, and all noise comes from one
``np.random.Generator`` drawn in a fixed order.

Several people (issue 16): every walker of ``config.walkers`` has its own script and
its own mocap bodies (``twin.scene.person_prefix``); the lidar and the camera see them
all, and ``ground_truth().people`` reports each in the config's order. ``person`` and
``ground_truth().person`` remain the first walker, so one-person code is unchanged.

The module runs past 500 lines because it is the twin's one public API: the scene's
build, the step, every sensor read and the ground truth share the MuJoCo model and the
one random generator, and splitting them would pass both around.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from stack.geometry import Pose2D
from stack.memo import Memo
from stack.nav.occupancy import OccupancyMap, save_map_yaml
from twin.camera_thread import AsyncCamera, LensBlur
from twin.config import TwinConfig
from twin.occupancy import occupancy_from_model
from twin.person import PersonPose, PersonScript, default_waypoints, vector_norm
from twin.scene import (
    CAMERA_NAME,
    LIDAR_SITE,
    PERSON_SEGMENTS,
    ROBOT_BODY,
    ROBOT_PREFIX,
    SceneLayout,
    build_spec,
    person_prefix,
)
from twin.sensors import (
    OPTICAL_FROM_MUJOCO_CAMERA,
    CameraInfo,
    CameraPose,
    LaserScan,
    Lidar,
    camera_info_of,
)


@dataclass(frozen=True)
class VelocityCommand:
    """A body-frame velocity command, as geometry_msgs/Twist (x forward, y left).

    Attributes:
        vx_mps, vy_mps: linear velocity [m/s].
        wz_radps: yaw rate [rad/s].
    """

    vx_mps: float = 0.0
    vy_mps: float = 0.0
    wz_radps: float = 0.0


@dataclass(frozen=True)
class Odometry:
    """Wheel odometry, as nav_msgs/Odometry.

    The odom frame coincides with the map frame at time 0 (the robot starts at its true
    pose), so a perfect odometry would read the ground truth; noise makes it drift.

    Attributes:
        time_s: simulation time [s].
        pose: integrated pose in the odom frame.
        vx_mps, vy_mps, wz_radps: measured body-frame velocity.
    """

    time_s: float
    pose: Pose2D
    vx_mps: float
    vy_mps: float
    wz_radps: float


@dataclass(frozen=True)
class PersonTruth:
    """The person's true state.

    Attributes:
        pose: pelvis on the floor and heading.
        velocity_mps: (vx, vy) in the map frame.
        cell: the cell holding the pelvis, None outside the region.
        in_room: False once the person has left through the door.
    """

    pose: Pose2D
    velocity_mps: tuple[float, float]
    cell: int | None
    in_room: bool


@dataclass(frozen=True)
class GroundTruth:
    """What really is, for evaluation.

    Attributes:
        time_s: simulation time [s].
        robot: the robot's pose (read from its body, not the joints).
        robot_velocity: body-frame (vx, vy, wz) [m/s, m/s, rad/s].
        robot_cell: the cell under the robot's centre, None outside the region.
        person: the (first) person's state, None when the scene has no person.
        people: every walker's state, in ``config.walkers`` order (``people[0]`` is
            ``person``).
    """

    time_s: float
    robot: Pose2D
    robot_velocity: tuple[float, float, float]
    robot_cell: int | None
    person: PersonTruth | None
    people: tuple[PersonTruth, ...] = ()


def truth_record(gt: GroundTruth) -> dict:
    """The ground truth as the run's trace records it (``/twin/truth`` JSON): the robot,
    the first person (the one-person fields every report reads) and, with several
    walkers, ``people``: each walker's position, cell and velocity."""
    r, p = gt.robot, gt.person
    out = {
        "t": round(gt.time_s, 6),
        "robot": [round(r.x_m, 4), round(r.y_m, 4), round(r.yaw_rad, 4)],
        "robot_cell": gt.robot_cell,
        "person": None if p is None else [round(p.pose.x_m, 4), round(p.pose.y_m, 4)],
        "person_cell": None if p is None else p.cell,
        "person_velocity": None if p is None else [round(float(v), 4) for v in p.velocity_mps],
    }
    if len(gt.people) > 1:
        out["people"] = [
            {
                "position": [round(q.pose.x_m, 4), round(q.pose.y_m, 4)],
                "cell": q.cell,
                "velocity": [round(float(v), 4) for v in q.velocity_mps],
            }
            for q in gt.people
        ]
    return out


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def _clip(v: float, lo: float, hi: float) -> float:
    """``np.clip`` of one finite value (bounds lo < hi)."""
    return lo if v < lo else hi if v > hi else v


def _segment_quat(u: np.ndarray) -> np.ndarray:
    """Unit quaternion turning +z onto the unit vector u."""
    w = 1.0 + u[2]
    if w < 1e-9:
        return np.array([0.0, 1.0, 0.0, 0.0])
    q = np.array([w, -u[1], u[0], 0.0])
    return q / vector_norm(q)


class _Scene:
    """A compiled scene and what follows from its static geometry alone."""

    def __init__(self, config: TwinConfig):
        self.spec, self.layout = build_spec(config)
        self.model = self.spec.compile()
        self.occupancy: OccupancyMap | None = None  # made on first use


def _scene_key(config: TwinConfig) -> str:
    """What builds the scene: the config without the walkers' waypoints (they only
    script where the walkers go; their bodies, clothes and number stay in)."""
    return repr(
        dataclasses.replace(
            config,
            person=dataclasses.replace(config.person, waypoints=()),
            people=tuple(dataclasses.replace(p, waypoints=()) for p in config.people),
        )
    )


# the scenes a process has compiled: a study's episodes differ in the walks only, so
# each compiles the same scene (about a tenth of an episode's set-up); a twin copies it
_SCENES = Memo(4)
# a walker beyond the first without waypoints takes the default tour this much later
DEFAULT_TOUR_STAGGER_S = 4.0
# a base slower than this (m/s, rad/s) with no command and no contact is at rest: its
# velocity servo would take it to zero over another second, moving it by less than a
# rounding step of its pose (1e-15 x 0.03 s), so the physics steps are skipped
REST_SPEED_MPS = 1e-15


class Twin:
    """The headless digital twin: the LRM room, the MBot, the ceiling camera, people.

    Args:
        config: the configuration; None for the defaults.
        seed: seed of the noise generator (or a Generator to draw from).

    Raises:
        ConfigError: the configuration cannot be built into a scene.
    """

    def __init__(self, config: TwinConfig | None = None, seed: int | np.random.Generator = 0):
        self.config = config if config is not None else TwinConfig()
        self.rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        scene = _SCENES.get(_scene_key(self.config), lambda: _Scene(self.config))
        self._scene = scene
        self.spec, self.layout = scene.spec, scene.layout  # shared: never change them
        self.model = copy.copy(scene.model)  # this twin's own (it sets the actuators' gains)
        self._data = mujoco.MjData(self.model)
        self._people_stale = False  # the walkers moved on since they were last placed
        m = self.model
        self._robot_body = m.body(ROBOT_BODY).id
        # views of the robot body's pose in the data (its arrays never move)
        self._robot_xpos = self._data.xpos[self._robot_body]
        self._robot_xmat = self._data.xmat[self._robot_body]
        self._lidar_site = m.site(LIDAR_SITE).id
        self._camera = m.camera(CAMERA_NAME).id
        jx, jy, jyaw = (m.joint(ROBOT_PREFIX + n) for n in ("x", "y", "yaw"))
        self._qadr = (jx.qposadr[0], jy.qposadr[0], jyaw.qposadr[0])
        self._dadr = (jx.dofadr[0], jy.dofadr[0], jyaw.dofadr[0])
        self._act = tuple(m.actuator(ROBOT_PREFIX + n).id for n in ("vx", "vy", "wz"))
        self._act_idx = np.array(self._act)  # for zeroing all three at once
        rc = self.config.robot
        for a, kv in zip(
            self._act,
            (rc.linear_gain_ns_per_m, rc.linear_gain_ns_per_m, rc.angular_gain_nms_per_rad),
            strict=True,
        ):
            # a velocity actuator is force = kv * (ctrl - qvel)
            m.actuator_gainprm[a, 0] = kv
            m.actuator_biasprm[a, 2] = -kv
        self._n_substeps = round(self.config.control_period_s / self.config.timestep_s)
        self.lidar = Lidar(self.config.lidar, self._robot_body)
        self.camera_info: CameraInfo = camera_info_of(self.config.camera)
        self._renderer: mujoco.Renderer | None = None
        self.people: list[PersonScript] = []
        self._mocaps: list[dict[str, int]] = []
        for i, walker in enumerate(self.config.walkers):
            wps = walker.waypoints or self._default_waypoints(self.layout)
            start = 0.0 if walker.waypoints else DEFAULT_TOUR_STAGGER_S * i
            script = PersonScript(dataclasses.replace(walker, waypoints=wps), start_time_s=start)
            self.people.append(script)
            prefix = person_prefix(i)
            self._mocaps.append({s: m.body(prefix + s).mocapid[0] for s in PERSON_SEGMENTS})
        # the first walker, as one-person code knows it
        self.person: PersonScript | None = self.people[0] if self.people else None
        self.reset()

    def _default_waypoints(self, layout: SceneLayout):
        return default_waypoints(self.config.grid, layout.door_center_m, layout.room[3])

    # -- lifecycle ----------------------------------------------------------
    def reset(self) -> None:
        """Put the robot at its start cell, the person at the script's start, time at 0."""
        self._truth: GroundTruth | None = None  # the state's, until it changes
        mujoco.mj_resetData(self.model, self._data)
        x, y = self.config.grid.center(self.config.robot.start_cell)
        yaw = self.config.robot.start_yaw_rad
        for adr, v in zip(self._qadr, (x, y, yaw), strict=True):
            self._data.qpos[adr] = v
        # the rate-limited command actually applied (body frame)
        self._cmd: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self._odom: tuple[float, float, float] = (float(x), float(y), float(yaw))
        self._odom_vel: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self._place_person(force=True)  # mj_resetData moved the mocap bodies back
        self._people_stale = False
        mujoco.mj_forward(self.model, self._data)

    def set_robot_pose(self, pose: Pose2D) -> None:
        """Teleport the robot (at rest) to ``pose``; odometry restarts from there.

        Args:
            pose: the new pose in the map frame.
        """
        self._truth = None
        for adr, v in zip(self._qadr, (pose.x_m, pose.y_m, pose.yaw_rad), strict=True):
            self._data.qpos[adr] = v
        self._data.qvel[list(self._dadr)] = 0.0
        self._cmd = (0.0, 0.0, 0.0)
        self._odom = (float(pose.x_m), float(pose.y_m), float(pose.yaw_rad))
        self._odom_vel = (0.0, 0.0, 0.0)
        mujoco.mj_forward(self.model, self._data)

    def close(self) -> None:
        """Free the renderer's GL context."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __enter__(self) -> Twin:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def time_s(self) -> float:
        return float(self._data.time)

    # -- stepping -----------------------------------------------------------
    def step(self, command: VelocityCommand | None = None) -> None:
        """Advance one control period (``config.control_period_s``) under ``command``.

        The command is clipped to the velocity limits and rate-limited by the
        acceleration limits, then held for the period. Because the slides move along
        world x and y, the body-frame command is turned into the world frame at every
        physics step with the current yaw.

        Args:
            command: body-frame velocity; None stops the base.
        """
        self._truth = None
        command = command or VelocityCommand()
        rc = self.config.robot
        dt = self.config.control_period_s
        diff = rc.drive == "diff"
        # on Python floats, the operations of the numpy version in its order (the same
        # numbers; a tenth of the time for three values)
        wx, wy, wz = command.vx_mps, 0.0 if diff else command.vy_mps, command.wz_radps
        # np.hypot(0, 0) is 0: skipped at rest (most periods), as the one below
        lin = np.hypot(wx, wy) if wx or wy else 0.0
        if lin > rc.max_linear_mps:
            k = rc.max_linear_mps / lin
            wx, wy = wx * k, wy * k
        wz = _clip(wz, -rc.max_angular_radps, rc.max_angular_radps)
        c0, c1, c2 = self._cmd
        dx, dy, dz = wx - c0, wy - c1, wz - c2
        dlin = np.hypot(dx, dy) if dx or dy else 0.0
        if dlin > rc.max_linear_accel_mps2 * dt:
            k = rc.max_linear_accel_mps2 * dt / dlin
            dx, dy = dx * k, dy * k
        dz = _clip(dz, -rc.max_angular_accel_radps2 * dt, rc.max_angular_accel_radps2 * dt)
        self._cmd = (float(c0 + dx), float(c1 + dy), float(c2 + dz))
        moving = any(self._cmd)

        before = self._robot_pose()
        data = self._data
        if not moving and data.ncon == 0 and np.abs(data.qvel).max() < REST_SPEED_MPS:
            # at rest (most of an episode): nothing pushes the base and it touches nothing,
            # so the physics steps would change only the time (the base's last crawl,
            # below REST_SPEED_MPS, moves it less than a rounding step of its pose)
            data.ctrl[self._act_idx] = 0.0
            data.qvel[:] = 0.0
            ts, t = self.model.opt.timestep, data.time
            for _ in range(self._n_substeps):
                t += ts  # as mj_step adds it, step by step
            data.time = t
        elif not diff and not moving:
            # coming to rest: the world-frame command is zero at every yaw, so the
            # substeps run in one call (the same steps, without Python between)
            data.ctrl[self._act_idx] = 0.0
            mujoco.mj_step(self.model, data, self._n_substeps)
        else:
            self._substeps(diff)
        # the walkers are kinematic and touch nothing, so the physics never needs them:
        # they are placed when something looks (:attr:`data`, the lidar, the camera),
        # at that instant's pose (a scan at 10 Hz, not every 20 ms period)
        self._people_stale = bool(self.people)
        mujoco.mj_kinematics(self.model, self._data)
        self._integrate_odometry(before, self._robot_pose(), dt)

    def _substeps(self, diff: bool) -> None:
        """The control period's physics steps, the command turned into the world frame
        with the yaw of each (the slides move along world x and y)."""
        data = self._data
        for _ in range(self._n_substeps):
            yaw = data.qpos[self._qadr[2]]
            c, s = math.cos(yaw), math.sin(yaw)
            ctrl = data.ctrl
            ctrl[self._act[0]] = c * self._cmd[0] - s * self._cmd[1]
            ctrl[self._act[1]] = s * self._cmd[0] + c * self._cmd[1]
            ctrl[self._act[2]] = self._cmd[2]
            if diff:  # no slip sideways: keep only the slides' velocity along the heading
                qv, ix, iy = data.qvel, self._dadr[0], self._dadr[1]
                along = c * qv[ix] + s * qv[iy]
                qv[ix], qv[iy] = c * along, s * along
            mujoco.mj_step(self.model, data)

    def run(self, duration_s: float, command: VelocityCommand | None = None) -> None:
        """Step for ``duration_s`` (rounded to control periods) under a fixed command."""
        for _ in range(max(0, round(duration_s / self.config.control_period_s))):
            self.step(command)

    def _robot_pose_array(self) -> np.ndarray:
        return np.array(self._robot_pose())

    def _robot_pose(self) -> tuple[float, float, float]:
        # read the pose from the body (FEASIBILITY/issue 3: never from the slide values)
        pos, mat = self._robot_xpos, self._robot_xmat
        return float(pos[0]), float(pos[1]), math.atan2(mat[3], mat[0])

    def _integrate_odometry(
        self, before: tuple[float, float, float], after: tuple[float, float, float], dt: float
    ) -> None:
        dyaw = _wrap(after[2] - before[2])
        mid = before[2] + dyaw / 2
        c, s = math.cos(mid), math.sin(mid)
        dx, dy = after[0] - before[0], after[1] - before[1]
        # the true body-frame velocity over the period, then the wheel-encoder noise
        oc = self.config.odometry
        n0, n1, n2 = self.rng.normal(0.0, 1.0, 3).tolist()
        v0 = (c * dx + s * dy) / dt + n0 * oc.linear_noise_std_mps
        v1 = (-s * dx + c * dy) / dt + n1 * oc.linear_noise_std_mps
        v2 = dyaw / dt + n2 * oc.angular_noise_std_radps
        x, y, yaw = self._odom
        oyaw = yaw + v2 * dt / 2
        oc_, os_ = math.cos(oyaw), math.sin(oyaw)
        self._odom = (
            x + (oc_ * v0 - os_ * v1) * dt,
            y + (os_ * v0 + oc_ * v1) * dt,
            _wrap(yaw + v2 * dt),
        )
        self._odom_vel = (v0, v1, v2)

    @property
    def end_time_s(self) -> float:
        """When the last walker stops for good [s] (0 without people)."""
        return max((p.end_time_s for p in self.people), default=0.0)

    @property
    def data(self) -> mujoco.MjData:
        """The simulation's state, the walkers placed at the current time (they move
        only when something looks: :meth:`_sync_people`)."""
        self._truth = None  # whoever has the data may change the state
        self._sync_people()
        return self._data

    def _sync_people(self) -> None:
        if self._people_stale:
            self._people_stale = False
            self._place_person()
            mujoco.mj_kinematics(self.model, self._data)

    def _place_person(self, force: bool = False) -> None:
        now = float(self._data.time)
        if force or getattr(self, "_placed", None) is None:
            self._placed: list[int | None] = [None] * len(self.people)
        placed = self._placed
        for i, (script, mocap) in enumerate(zip(self.people, self._mocaps, strict=True)):
            still = script.still_phase(now)  # a pause: the pose is the one already placed
            if still is not None and still == placed[i]:
                continue
            self._place_one(script.pose(now), mocap)
            placed[i] = still

    def _place_one(self, p: PersonPose, mocap: dict[str, int]) -> None:
        mp, mq = self._data.mocap_pos, self._data.mocap_quat
        t = mocap["torso"]
        mp[t] = (p.position_m[0], p.position_m[1], -p.pelvis_drop_m)
        mq[t] = (math.cos(p.heading_rad / 2), 0.0, 0.0, math.sin(p.heading_rad / 2))
        for k, side in enumerate(("l", "r")):
            for name, a, b in (
                ("thigh", p.hips_m[k], p.knees_m[k]),
                ("shin", p.knees_m[k], p.ankles_m[k]),
                ("arm", p.shoulders_m[k], p.hands_m[k]),
            ):
                i = mocap[f"{name}_{side}"]
                seg = a - b  # +z of the segment body points from the far end to the near
                mp[i] = (a + b) / 2
                mq[i] = _segment_quat(seg / vector_norm(seg))
            f = mocap[f"foot_{side}"]
            mp[f] = p.ankles_m[k]
            mq[f] = mq[t]

    # -- sensors ------------------------------------------------------------
    def render_camera(self) -> np.ndarray:
        """Render the ceiling camera's view.

        Returns:
            (height, width, 3) uint8 RGB image.
        """
        if self._renderer is None:
            self._renderer = self._camera_renderer()
        self._renderer.update_scene(self.data, camera=self._camera)
        return self._renderer.render().copy()

    def _camera_renderer(self) -> mujoco.Renderer | LensBlur:
        """The ceiling camera's renderer: MuJoCo's, and the lens's blur if configured."""
        c = self.config.camera
        renderer = mujoco.Renderer(self.model, c.height_px, c.width_px)
        return LensBlur(renderer, c.blur_sigma_px) if c.blur_sigma_px > 0 else renderer

    def async_camera(self) -> AsyncCamera:
        """The ceiling camera on a render thread of its own (the real-time twin's:
        :mod:`twin.camera_thread`); the caller closes it."""
        return AsyncCamera(self._camera_renderer, self._camera)

    def render_segmentation(self) -> np.ndarray:
        """Render which geom each ceiling-camera pixel sees (ground truth for perception).

        Returns:
            (height, width) int32 geom ids, -1 where no geom is seen.
        """
        if self._renderer is None:
            self.render_camera()
        r = self._renderer
        assert r is not None
        r.enable_segmentation_rendering()
        try:
            r.update_scene(self.data, camera=self._camera)
            seg = r.render()
        finally:
            r.disable_segmentation_rendering()
        ids = seg[..., 0].astype(np.int32)
        ids[seg[..., 1] != mujoco.mjtObj.mjOBJ_GEOM] = -1
        return ids

    def person_geom_ids(self, index: int | None = None) -> np.ndarray:
        """Ids of the people's geoms (empty without people).

        Args:
            index: only this walker's (0-based, ``config.walkers`` order); None: all.
        """
        m = self.model
        which = range(len(self.people)) if index is None else [index]
        prefixes = tuple(person_prefix(i) for i in which)
        names = [m.geom(i).name for i in range(m.ngeom)]
        return np.array([i for i, n in enumerate(names) if n.startswith(prefixes)], int)

    def scan(self) -> LaserScan:
        """One lidar scan from the robot's current pose (range noise from the twin's rng)."""
        origin = self._data.site_xpos[self._lidar_site].copy()
        yaw = self._robot_pose_array()[2]
        return self.lidar.scan(self.model, self.data, origin, yaw, self.rng)

    def odometry(self) -> Odometry:
        """The integrated wheel odometry (odom frame = map frame at time 0)."""
        o, v = self._odom, self._odom_vel
        return Odometry(self.time_s, Pose2D(*map(float, o)), float(v[0]), float(v[1]), float(v[2]))

    def ground_truth(self) -> GroundTruth:
        """The true state of the robot and every person (kept until the state changes:
        the truth record and the camera model ask at the same instants)."""
        if self._truth is None:
            self._truth = self._ground_truth()
        return self._truth

    def _ground_truth(self) -> GroundTruth:
        x, y, yaw = self._robot_pose()
        qvel, (ix, iy, iyaw) = self._data.qvel, self._dadr
        vx, vy = float(qvel[ix]), float(qvel[iy])
        c, s = math.cos(yaw), math.sin(yaw)
        vel = (c * vx + s * vy, -s * vx + c * vy, float(qvel[iyaw]))
        grid = self.config.grid
        people = []
        now = self.time_s
        for script in self.people:
            (px, py), heading, velocity = script.motion(now)
            people.append(
                PersonTruth(
                    pose=Pose2D(px, py, heading),
                    velocity_mps=velocity,
                    cell=grid.cell_at(px, py),
                    in_room=self.layout.in_room(px, py),
                )
            )
        return GroundTruth(
            time_s=self.time_s,
            robot=Pose2D(x, y, yaw),
            robot_velocity=vel,
            robot_cell=grid.cell_at(x, y),
            person=people[0] if people else None,
            people=tuple(people),
        )

    def camera_pose(self) -> CameraPose:
        """The ceiling camera's optical frame in the map frame."""
        pos = self._data.cam_xpos[self._camera].copy()
        rot = self._data.cam_xmat[self._camera].reshape(3, 3) @ OPTICAL_FROM_MUJOCO_CAMERA
        return CameraPose(pos, rot)

    def lidar_mount_m(self) -> tuple[float, float, float]:
        """The lidar's position on the robot (base_link -> laser) [m]."""
        x, y, z = self.model.site_pos[self._lidar_site]
        return float(x), float(y), float(z)

    # -- map ----------------------------------------------------------------
    def occupancy_map(self) -> OccupancyMap:
        """The room's occupancy grid, made from the static geometry (config.map)."""
        if self._scene.occupancy is None:  # static geoms only: the same for the scene's twins
            mc = self.config.map
            self._scene.occupancy = occupancy_from_model(
                self.model,
                self._data,
                self.layout.room,
                mc.resolution_m,
                (mc.z_min_m, mc.z_max_m),
            )
        return self._scene.occupancy

    def save_map(self, directory: str | Path, name: str = "lrm") -> tuple[Path, Path]:
        """Write the occupancy map as ``name.pgm`` + ``name.yaml`` (map_server format).

        Args:
            directory: output directory (created if absent).
            name: file stem.

        Returns:
            (pgm_path, yaml_path).
        """
        mc = self.config.map
        yml = save_map_yaml(
            self.occupancy_map(),
            Path(directory) / f"{name}.yaml",
            occupied_thresh=mc.occupied_thresh,
            free_thresh=mc.free_thresh,
        )
        return yml.with_suffix(".pgm"), yml

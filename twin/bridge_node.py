"""ROS 2 bridge: the twin publishes what the robot's drivers and the camera would.

Publishes ``/camera/image_raw`` (sensor_msgs/Image, rgb8), ``/camera/camera_info``,
``/scan`` (sensor_msgs/LaserScan), ``/odom`` (nav_msgs/Odometry), ``/map``
(nav_msgs/OccupancyGrid, transient local), ``/clock`` (simulated time), TF (``/tf``:
``odom -> base_link`` with each odometry message; ``/tf_static``: ``base_link -> laser``
from the lidar's mount) and ground truth under ``/twin/...``; subscribes to ``/cmd_vel``
(geometry_msgs/Twist) and stops the base when the last command arrived more than
``cmd_timeout_s`` of simulated time ago (the base's own timeout,
:class:`stack.hardware.base_watchdog.BaseWatchdog`, as diff_drive_controller's
``cmd_vel_timeout``: a sender killed with SIGKILL sends no last zero); with
``gate_heartbeat_timeout_s`` > 0 (a twin run with the velocity gate,
``twin.velocity_gate``) it also stops when ``/velocity_gate/heartbeat`` has been silent
that long: a dead gate, as a real base driver's watchdog would.

Time, three modes:
    lock-step (``lockstep`` true, the default in CI and ``vigil run``): the bridge is the
        coordinator of :mod:`stack.lockstep`. Each sensor tick it publishes ``/clock``,
        waits until every participant has processed it, publishes ``/lockstep/tick``
        (the participants' timers run), waits for that and everything it caused,
        publishes the sensors, waits
        until every participant has processed them and everything that followed
        (detections, observations, the planner's decision, the next ``/cmd_vel``),
        and only then steps the physics. Results do not depend on the machine's speed.
        The waits are checked after each batch of callbacks the executor runs
        (:class:`stack.ros_main.BatchingExecutor`); with ``render_ahead`` (the
        nodes in one process, :mod:`vigil.container`) a frame due at the tick is
        rendered on the camera's thread (:mod:`twin.camera_thread`) from the scene at
        the ``/clock`` while the nodes take the clock and the tick.
    real time (``realtime`` true, ``lockstep`` false): the simulated time follows a
        monotonic wall clock (:class:`twin.realtime.Pacer`): a bridge that fell behind
        steps the physics until it has caught up; the camera renders on a thread of its
        own (:mod:`twin.camera_thread`) and a frame it could not render in time is
        dropped. Every stamp is the ROS system time of the run's start plus
        the simulated time, so the twin's messages carry the wall clock, as a robot's
        drivers' do, and the nodes (on the system clock, as on the robot) join them.
        How well it kept up (:class:`twin.realtime.RealtimeStats`) is logged every 10 s
        and written to ``realtime_file`` (JSON, replaced each second).
    free-running (both false): ticks as fast as the executor allows.

The module is over 500 lines because the three modes share the sensors, the base and
its watchdog, and each mode's timing is only readable beside the others'.

Ground truth for evaluation also goes out as one record per sensor tick on
``/twin/truth`` (vigil_interfaces/TwinTruth): the robot's pose and cell, the first
person's position, cell and velocity, and every walker's (several people).
"""

from __future__ import annotations

import json
import os
import time

from geometry_msgs.msg import PoseStamped, Twist, TwistStamped
from nav_msgs.msg import OccupancyGrid
from nav_msgs.msg import Odometry as OdometryMsg
from rclpy.clock import Clock as RosClock
from rclpy.clock import ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo as CameraInfoMsg
from sensor_msgs.msg import Image, LaserScan
from std_msgs.msg import Int32, UInt64
from tf2_msgs.msg import TFMessage
from vigil_interfaces.msg import LockstepAck, TwinTruth

import stack.topics as topic
from stack import tf
from stack.exits import EXIT_STALLED  # the lock-step stalled for good
from stack.files import write_atomic
from stack.hardware.base_watchdog import GATE_SILENT, STALE, BaseWatchdog, check_timeout
from stack.hardware.base_watchdog import OK as WATCHDOG_OK
from stack.lockstep import (
    ABORT,
    ACK_TOPIC,
    CLOCK,
    RUN_ID_ENV,
    SENSORS,
    TICK,
    TICK_TOPIC,
    Coordinator,
    Ledger,
)
from stack.ros_main import BatchingExecutor, Releasing, spin_node
from stack.ros_msgs import ack_from_msg, truth_to_msg
from stack.ros_params import declare
from stack.ros_tf import TF_QOS, TF_STATIC_QOS, tf_message
from twin.config import TwinConfig, load_twin_config
from twin.realtime import Pacer
from twin.ros_sensors import (
    camera_info_msg,
    image_msg,
    map_msg,
    odometry_msg,
    parse_outages,
    pose_msg,
    scan_msg,
    stamp_of,
)
from twin.twin import GroundTruth, Twin, VelocityCommand, truth_record


class TwinBridge(Releasing, Node):
    """Steps a :class:`Twin` and converts between it and ROS messages.

    Parameters: ``config`` (twin YAML, "" for defaults), ``task`` (task YAML with the
    grid, "" for none), ``seed``, ``realtime``, ``cmd_timeout_s``,
    ``gate_heartbeat_timeout_s`` (0: no gate watched), ``odom_rate_hz``
    (0: every control period), ``lockstep``, ``participants`` (node names that must
    be up before the first lock-step tick), ``stall_warn_s`` and ``stall_timeout_s``
    (wall-clock seconds: when to log a lock-step wait, and when to stop waiting for a
    participant that lost messages or died), ``stall_abort_s`` (default three times
    ``stall_timeout_s``: no tick for this long, forgiving included, ends the bridge with
    exit code :data:`EXIT_STALLED` and an error naming what it waited for),
    ``sensor_outages`` (JSON list of
    [sensor, t0_s, t1_s] with sensor "camera" or "lidar": nothing is published from it
    in that simulated interval, a fault for tests and scenarios), ``render_ahead``
    (lock-step: render a frame on the camera's thread during the clock and tick phases).
    """

    def __init__(self, twin: Twin | None = None, **kwargs):
        super().__init__("twin_bridge", **kwargs)
        v = declare(
            self,
            config="",
            task="",
            seed=0,
            realtime=False,
            cmd_timeout_s=0.5,
            gate_heartbeat_timeout_s=0.0,
            odom_rate_hz=25.0,
            lockstep=False,
            participants=[""],
            stall_warn_s=5.0,
            stall_timeout_s=30.0,
            sensor_outages="[]",
            realtime_file="",
            render_ahead=False,
        )
        self.lockstep = v.lockstep
        participants = list(v.participants)
        self.stall_warn_s = v.stall_warn_s
        self.stall_timeout_s = v.stall_timeout_s
        # no tick for this long (forgiving included): the run ends with EXIT_STALLED
        self.stall_abort_s = declare(self, stall_abort_s=3 * self.stall_timeout_s).stall_abort_s
        self.outages = parse_outages(v.sensor_outages)
        # checked before the twin is built: a NaN or infinite timeout never stops the base
        check_timeout("cmd_timeout_s", v.cmd_timeout_s)
        if twin is None:
            cfg = load_twin_config(v.config, v.task or None) if v.config else TwinConfig()
            twin = Twin(cfg, seed=v.seed)
        self.twin = twin
        beat_s = v.gate_heartbeat_timeout_s  # 0: no gate to watch
        if beat_s != 0:
            check_timeout("gate_heartbeat_timeout_s", beat_s)
        self.watchdog = BaseWatchdog(v.cmd_timeout_s, beat_s or None)
        self.cmd_timeout_s = self.watchdog.cmd_timeout_s
        cfg = twin.config
        self._stopped_reason = self.watchdog.reason
        odom_hz = v.odom_rate_hz
        self._periods = {
            "odom": cfg.control_period_s if odom_hz <= 0 else 1.0 / odom_hz,
            "scan": 1.0 / cfg.lidar.rate_hz,
            "camera": 1.0 / cfg.camera.rate_hz,
        }
        self._next = dict.fromkeys(self._periods, 0.0)
        self.run_id = os.environ.get(RUN_ID_ENV, "")
        self.ledger = Ledger(tuple(n for n in participants if n), run_id=self.run_id)
        self.coordinator = Coordinator(
            self.ledger, self.stall_warn_s, self.stall_timeout_s, self.stall_abort_s, self._wall_s()
        )

        latched = QoSProfile(
            depth=1,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
            reliability=ReliabilityPolicy.RELIABLE,
        )
        self.pub_image = self.create_publisher(Image, topic.CAMERA_IMAGE, 2)
        self.pub_info = self.create_publisher(CameraInfoMsg, topic.CAMERA_INFO, 2)
        self.pub_scan = self.create_publisher(LaserScan, topic.SCAN, 5)
        self.pub_odom = self.create_publisher(OdometryMsg, topic.ODOM, 10)
        self.pub_map = self.create_publisher(OccupancyGrid, topic.MAP, latched)
        self.pub_clock = self.create_publisher(Clock, topic.CLOCK, 10)
        self.pub_tick = self.create_publisher(Clock, TICK_TOPIC, 10)
        self.pub_truth = self.create_publisher(TwinTruth, topic.TWIN_TRUTH, 10)
        self.pub_robot = self.create_publisher(PoseStamped, topic.TWIN_ROBOT_POSE, 10)
        self.pub_person = self.create_publisher(PoseStamped, topic.TWIN_PERSON_POSE, 10)
        self.pub_person_vel = self.create_publisher(TwistStamped, topic.TWIN_PERSON_VELOCITY, 10)
        self.pub_person_cell = self.create_publisher(Int32, topic.TWIN_PERSON_CELL, 10)
        self.pub_robot_cell = self.create_publisher(Int32, topic.TWIN_ROBOT_CELL, 10)
        self.pub_tf = self.create_publisher(TFMessage, topic.TF, TF_QOS)
        self.pub_tf_static = self.create_publisher(TFMessage, topic.TF_STATIC, TF_STATIC_QOS)
        self.create_subscription(Twist, topic.CMD_VEL, self._on_cmd_vel, 10)
        if beat_s:
            self.create_subscription(
                UInt64,
                topic.GATE_HEARTBEAT,
                lambda _msg: self.watchdog.heartbeat(self.twin.time_s),
                10,
            )
        if self.lockstep:
            self.ledger.subscribe(topic.CMD_VEL)
            self.create_subscription(LockstepAck, ACK_TOPIC, self._on_ack, 200)
        self._publish(self.pub_map, map_msg(twin.occupancy_map(), twin.time_s))
        laser = tf.Transform(twin.lidar_mount_m())
        self._publish(
            self.pub_tf_static,
            tf_message([tf.StampedTransform(tf.BASE_LINK, tf.LASER, twin.time_s, laser)]),
        )
        # real time: the wall-clock schedule; the stamps' offset is set at the first tick
        self.pacer = Pacer(cfg.control_period_s) if v.realtime and not self.lockstep else None
        # real time: the camera renders on its own thread while the physics goes on;
        # lock-step with render_ahead: rendered there while the nodes take the clock and
        # the tick (one process, vigil.container: in separate processes the frame's lead
        # of the render time let the truth reach the recorder before the detection)
        ahead = self.lockstep and v.render_ahead
        self.camera = twin.async_camera() if self.pacer is not None or ahead else None
        self._frame_owed = False  # a frame came due while the renderer was busy
        # real time: the nodes the world waits for before it starts (as an experimenter
        # sends the person in once the system is up), at most stall_timeout_s
        self._awaited = {n for n in participants if n} if self.pacer is not None else set()
        self._await_since: float | None = None
        self.offset_s = 0.0
        self.realtime_file = v.realtime_file
        self._stats_at = (0.0, 0.0)  # wall times of the last stats file and log line
        if self.lockstep:
            callback, period = self._lockstep_timer, 0.001
        elif self.pacer is not None:  # twice per period: a tick is at most half late
            callback, period = self._realtime_tick, cfg.control_period_s / 2
        else:
            callback, period = self._tick, 0.001
        # a steady timer: a wall clock set back must not hold the physics (or the timeout)
        steady = RosClock(clock_type=ClockType.STEADY_TIME)
        self.timer = self.create_timer(period, callback, clock=steady)

    @staticmethod
    def _wall_s() -> float:
        return time.monotonic()

    def _publish(self, pub, msg) -> None:
        pub.publish(msg)
        self.ledger.sent(pub.topic_name)

    def _on_cmd_vel(self, msg: Twist) -> None:
        self.watchdog.command((msg.linear.x, msg.linear.y, msg.angular.z), self.twin.time_s)
        if self.lockstep:
            self.ledger.received(topic.CMD_VEL)

    def _on_ack(self, msg: LockstepAck) -> None:
        try:
            fields = ack_from_msg(msg)
        except ValueError as err:
            self.get_logger().warning(f"lock-step ack ignored: {err}", throttle_duration_sec=5.0)
            return
        self.coordinator.ack(fields, self._wall_s())
        self._log_coordinator()

    def _log_coordinator(self) -> None:
        logger = self.get_logger()
        # one call site per severity: rclpy refuses a call site that changes severity
        for level, line in self.coordinator.log:
            if level == "throttled":
                logger.warning(line, throttle_duration_sec=5.0)
            elif level == "error":
                logger.error(line)
            elif level == "warning":
                logger.warning(line)
            else:
                logger.info(line)
        self.coordinator.log.clear()

    # -- lock-step ----------------------------------------------------------------------
    def _own_matched(self) -> dict[str, int]:
        pubs = (
            self.pub_clock,
            self.pub_tick,
            self.pub_odom,
            self.pub_scan,
            self.pub_image,
            self.pub_truth,
            self.pub_tf,
            self.pub_tf_static,
            self.pub_robot,
        )
        return {p.topic_name: p.get_subscription_count() for p in pubs}

    def _lockstep_timer(self) -> None:
        """Under :class:`stack.ros_main.BatchingExecutor` (:func:`spin_node`) the ledger
        is checked after every batch of callbacks and this timer, slowed down, only sees
        to the start and to stalls; under another executor it checks every 1 ms."""
        hooks = ex.before_wait if isinstance(ex := self.executor, BatchingExecutor) else None
        if hooks is not None and self._lockstep_batch not in hooks:
            hooks.append(self._lockstep_batch)
            self.timer.timer_period_ns = 20_000_000  # 20 ms: the start and stalls only
        self._lockstep_poll()

    def _lockstep_batch(self) -> None:
        for _ in range(4):  # act until told to wait (at once, with participants)
            if not self._lockstep_poll():
                return

    def _lockstep_poll(self) -> bool:
        """Do what the :class:`stack.lockstep.Coordinator` says is next (False: wait)."""
        first = self.coordinator.phase == "start"
        action = self.coordinator.poll(self._wall_s(), self._own_matched, self.twin.time_s)
        self._log_coordinator()
        if action == CLOCK:  # step the physics to the next sensor time, publish the clock
            if not first:
                t_next = min(self._next.values())
                while self.twin.time_s + 1e-9 < t_next:
                    self._step_physics()
            t = self.twin.time_s
            if self.camera is not None and self._next["camera"] <= t + 1e-9:
                if not self._out("camera", t):  # the frame _publish_sensors() will send
                    self.camera.capture(self.twin.data, t)
            self._publish(self.pub_clock, Clock(clock=stamp_of(t)))
        elif action == TICK:  # everyone has the new time: now the timers
            self._publish(self.pub_tick, Clock(clock=stamp_of(self.twin.time_s)))
        elif action == SENSORS:
            self._publish_sensors()
        elif action == ABORT:
            raise SystemExit(EXIT_STALLED)
        return bool(action)

    # -- stepping -------------------------------------------------------------------------
    def _step_physics(self) -> None:
        tw = self.twin
        vx, vy, wz = self.watchdog.output(tw.time_s)
        reason = self.watchdog.reason
        if reason != self._stopped_reason:
            # a stop worth a line: a moving command timed out (an idle gate's zeros at
            # 2 Hz, as old as the timeout, would log one twice a second)
            if reason == STALE and any(self.watchdog.last_command):
                self.get_logger().info(
                    f"no {topic.CMD_VEL} for {self.cmd_timeout_s:g} s: base stopped"
                )
            elif reason == GATE_SILENT:
                self.get_logger().warning(
                    f"no {topic.GATE_HEARTBEAT} for {self.watchdog.heartbeat_timeout_s:g} s "
                    "(the velocity gate died?): base stopped"
                )
            self._stopped_reason = reason
        tw.step(VelocityCommand(vx, vy, wz) if reason == WATCHDOG_OK else None)

    def _tick(self) -> None:
        """Free-running: one control period, then what is due."""
        self._step_physics()
        self._publish(self.pub_clock, Clock(clock=stamp_of(self.twin.time_s)))
        self._publish_sensors()

    def _realtime_tick(self) -> None:
        """Real time: the control periods the wall clock owes, then what is due once."""
        pacer = self.pacer
        assert pacer is not None
        wall = self._wall_s()
        if self._awaited and not self._stack_up(wall):
            return
        if pacer.stats.ticks == 0 and self.offset_s == 0.0:
            # the stamps: the system clock at the start plus the simulated time
            now_s = self.get_clock().now().nanoseconds * 1e-9
            self.offset_s = now_s - self.twin.time_s
        owed = pacer.due(wall)
        for _ in range(owed):
            self._step_physics()
            pacer.stepped(self._wall_s())
        self._publish_frame()  # first: a renderer it frees can take a frame due now
        if owed:
            self._publish(self.pub_clock, Clock(clock=stamp_of(self.twin.time_s + self.offset_s)))
            self._publish_sensors()
        self._report_realtime(wall)

    def _stack_up(self, wall: float) -> bool:
        """Real time, before the first tick: are the awaited nodes in the ROS graph (or
        has the wait lasted ``stall_timeout_s``)? Says which once it stops waiting."""
        if self._await_since is None:
            self._await_since = wall
        self._awaited -= set(self.get_node_names())
        log = self.get_logger()
        if not self._awaited:
            log.info("real time: every node is up, the world starts")
            return True
        if wall - self._await_since >= self.stall_timeout_s:
            log.warning(
                f"real time: starting without {sorted(self._awaited)} "
                f"(not up after {self.stall_timeout_s:g} s)"
            )
            self._awaited = set()
            return True
        return False

    def _publish_frame(self) -> None:
        """Real time: a frame the render thread finished, stamped when it was captured."""
        if self.camera is None or (frame := self.camera.collect()) is None:
            return
        t_s, rgb = frame
        self._publish_image(rgb, t_s + self.offset_s)
        if self._frame_owed:  # the frame that came due meanwhile: taken now, a bit late
            self._capture()

    def _publish_image(self, rgb, stamp_s: float) -> None:
        """The camera's image and its camera_info, stamped ``stamp_s``."""
        info = self.twin.camera_info
        self._publish(self.pub_image, image_msg(rgb, stamp_s, info.frame_id))
        self._publish(self.pub_info, camera_info_msg(info, stamp_s))

    def _capture(self) -> None:
        """Real time: hand the scene to the render thread now, or owe it the frame."""
        assert self.camera is not None and self.pacer is not None
        sent = self.camera.capture(self.twin.data, self.twin.time_s)
        self._frame_owed = not sent
        if sent:
            self.pacer.frame(sent=True, due=0)

    def _report_realtime(self, wall: float) -> None:
        """The stats: to ``realtime_file`` each second, a log line each 10 s."""
        assert self.pacer is not None
        stats = self.pacer.stats
        written, logged = self._stats_at
        if self.realtime_file and wall - written >= 1.0:
            self.write_realtime()
            written = wall
        if wall - logged >= 10.0:
            if logged:
                self.get_logger().info(stats.line())
            logged = wall
        self._stats_at = (written, logged)

    def write_realtime(self) -> None:
        """Replace ``realtime_file`` with the stats so far (a crash leaves the last)."""
        if self.pacer is None or not self.realtime_file:
            return
        stats = self.pacer.stats
        if self.camera is not None and (ms := self.camera.render_ms()) is not None:
            stats.render_ms_median, stats.render_ms_max = ms
        try:
            write_atomic(self.realtime_file, json.dumps(stats.to_json(), sort_keys=True) + "\n")
        except OSError as err:
            self.get_logger().error(
                f"realtime_file {self.realtime_file}: {err}", throttle_duration_sec=10.0
            )

    def _due(self, name: str, t: float) -> int:
        """How many periods of sensor ``name`` came by time ``t`` (0: not due)."""
        if t + 1e-9 < self._next[name]:
            return 0
        n = 0
        while self._next[name] <= t + 1e-9:
            self._next[name] += self._periods[name]
            n += 1
        return n

    def _publish_sensors(self) -> None:
        tw = self.twin
        t = tw.time_s
        ts = t + self.offset_s  # the stamps (real time: on the system clock)
        if self._due("odom", t):
            odom = tw.odometry()
            self._publish(self.pub_odom, odometry_msg(odom, self.offset_s))
            base = tf.Transform.from_pose2d(odom.pose)
            st = tf.StampedTransform(tf.ODOM, tf.BASE_LINK, odom.time_s + self.offset_s, base)
            self._publish(self.pub_tf, tf_message([st]))
            self._publish_truth(tw.ground_truth())
        if self._due("scan", t) and not self._out("lidar", t):
            self._publish(self.pub_scan, scan_msg(tw.scan(), self.offset_s))
        frames = self._due("camera", t)
        if frames and not self._out("camera", t):
            if self.pacer is None and self.camera is not None:  # lock-step: see _frame
                self._publish_image(self._frame(t), ts)
            elif self.camera is not None:  # real time: rendered beside the physics
                # a frame owed since the last period is dropped (counted), this one taken
                # now or as soon as the renderer is free (_publish_frame)
                assert self.pacer is not None
                self.pacer.frame(sent=False, due=frames)
                self._capture()
            else:
                self._publish_image(tw.render_camera(), ts)

    def _frame(self, t: float):
        """Lock-step: the frame of ``t``, captured with the scene at this tick's
        ``/clock`` (nothing moves until the next) and rendered on the camera's thread
        meanwhile: the image ``render_camera()`` makes of the scene, bit for bit."""
        assert self.camera is not None
        if not self.camera.busy:
            self.camera.capture(self.twin.data, t)
        frame = self.camera.collect(wait=True)
        assert frame is not None and frame[0] == t, (frame and frame[0], t)
        return frame[1]

    def _out(self, sensor: str, t: float) -> bool:
        return any(s == sensor and t0 <= t < t1 for s, t0, t1 in self.outages)

    def _publish_truth(self, gt: GroundTruth) -> None:
        t = gt.time_s + self.offset_s
        record = truth_record(gt)
        if self.offset_s:
            record["t"] = round(t, 6)
        self._publish(self.pub_truth, truth_to_msg(record))
        # counted: the localisation stand-in (a participant) reads it
        self._publish(self.pub_robot, pose_msg(gt.robot.x_m, gt.robot.y_m, gt.robot.yaw_rad, t))
        self.pub_robot_cell.publish(Int32(data=gt.robot_cell or -1))
        if gt.person is not None:
            p = gt.person
            self.pub_person.publish(pose_msg(p.pose.x_m, p.pose.y_m, p.pose.yaw_rad, t))
            vel = TwistStamped()
            vel.header.stamp, vel.header.frame_id = stamp_of(t), "map"
            vel.twist.linear.x, vel.twist.linear.y = map(float, p.velocity_mps)
            self.pub_person_vel.publish(vel)
            # -1: outside the region (or the room)
            self.pub_person_cell.publish(Int32(data=p.cell if p.cell is not None else -1))

    def _release(self) -> None:
        """The twin (its renderer), closed once (:class:`stack.ros_main.Releasing`); the
        real-time stats written a last time."""
        if self.camera is not None:
            self.camera.close()
        if self.pacer is not None:
            self.write_realtime()
            self.get_logger().info(self.pacer.stats.line())
        self.twin.close()


def main(args: list[str] | None = None) -> None:
    """Run the bridge until interrupted."""
    spin_node(TwinBridge, args)


if __name__ == "__main__":
    main()

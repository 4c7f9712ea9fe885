"""The whole guarding loop in one process: the twin's ``dm_env`` environment, the
perception cores, the planner's step machine, navigation and the speech gate, on the
lock-step schedule of the ROS run, with no ROS.

:func:`run_inprocess` prepares the run folder exactly as ``vigil run`` does
(:func:`vigil.system.prepare`: the same scene, stack config, calibration, policy and
node parameters) and builds each node's pure core from those parameters:

============================  =================================================
ROS node                      core here
============================  =================================================
twin_bridge                   :func:`twin.env.make_environment` (dm_control)
camera_people                 :class:`stack.perception.camera.CameraPeopleTracker`
legs                          :func:`stack.perception.legs.detect_legs` + ``LegTracker``
observations                  :class:`stack.perception.observer.Observer`
navigation                    :class:`stack.nav.executor.ActionExecutor`
speech                        :class:`stack.nav.warning.WarningReactor` + ``Speaker``
planner                       :func:`stack.planning.runtime.make_planner` +
                              :class:`stack.planning.stepper.DecisionSteps`
recorder                      :class:`vigil.trace_records.TraceRecords`
============================  =================================================

Time runs as in the lock-step ROS run (:mod:`stack.lockstep`): at each sensor instant
the clock "ticks" (every node's periodic work that is due runs: navigation 25 Hz, the
planner's poll 10 Hz, the observations 4 Hz, the camera watchdog 1 Hz), then the
sensors due are delivered, and every message either causes is delivered, in order,
until nothing is in flight; then the physics advances to the next sensor instant under
the last velocity command (dropped after ``cmd_timeout_s``, as the bridge does).
Messages keep their ROS encodings where the encoding changes a value (nanosecond
stamps, float32 scan and map fields, the legs message's rounding), so the cores see
what their nodes would see.

The run folder gets ``steps.jsonl`` and ``trace.jsonl`` in the ROS run's formats and
the speech log, so :func:`vigil.report.write_report` scores it with the same metric code.

The module is over 500 lines because it holds the stand-in for each of the eight
nodes (a few lines each, as thin as the nodes themselves) beside the one message queue
that joins them: the delivery order, which decides whether both runs agree, is only
readable with all of them in one place.
"""

from __future__ import annotations

import json
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

import stack.topics as topic
from stack.cells import ConfigError
from stack.config import open_write, write_text
from stack.geometry import Pose2D
from stack.hardware.base_watchdog import BaseWatchdog
from stack.lockstep import stamp_parts
from stack.nav.config import FollowerConfig, SpeechConfig, read_node_config
from stack.nav.executor import ActionExecutor
from stack.nav.occupancy import from_occupancy_grid
from stack.nav.speech import Speaker, SpeechError
from stack.nav.warning import WarningReactor
from stack.perception.camera import CameraConfig, CameraPeopleTracker
from stack.perception.config import load_config_file
from stack.perception.errors import BadScanError, PerceptionError
from stack.perception.homography import load_calibration
from stack.perception.legs import LegConfig, Scan, StaticMap, detect_legs
from stack.perception.messages import camera_state_from_json, legs_to_dict, tracks_from_dict
from stack.perception.model import DETECTIONS_FILE, ModelCamera, PerceptionModel, PersonFrame
from stack.perception.observation import CombinerConfig
from stack.perception.observer import Observer
from stack.perception.scan_pose import ScanPosePairing
from stack.perception.tracker import LegTracker, TrackerConfig
from stack.planning.agent import ObservationError, Observed
from stack.planning.runtime import PlannerStart, make_planner, online_config, task_model
from stack.planning.stepper import DecisionSteps, StepTiming
from stack.planning.threads import blas_threads
from twin.config import load_twin_config
from twin.env import GuardEnvironment, Outage, make_environment
from twin.twin import truth_record
from vigil.deployment import Deployment, load_deployment
from vigil.scenario import Scenario, load_scenario
from vigil.system import System, prepare
from vigil.trace_records import TraceRecords

REPO = Path(__file__).resolve().parents[1]
DEFAULT_CONFIG = REPO / "config" / "twin.yaml"
DEFAULT_PERCEPTION_MODEL = REPO / "config" / "perception-model.yaml"
CMD_TIMEOUT_S = 0.5  # the bridge's cmd_timeout_s, when the parameters do not say
FRAME_TIMEOUT_S = 2.0  # the camera node's frame_timeout_s
PROGRESS_HZ = 2.0  # navigation's progress_rate_hz
SPEECH_POLL_S = 0.1  # the speech node's poll_rate_hz 10
PERCEPTION_MODES = ("rendered", "model")
MAX_MESSAGES_PER_INSTANT = 20_000  # a simulated instant carries a few dozen
MODEL_STREAM = 0x5EE  # the model camera's random stream, beside the twin's seed


def ros_time(t_s: float) -> float:
    """``t_s`` through a builtin_interfaces/Time as the bridge stamps it
    (:func:`stack.lockstep.stamp_parts`) and a node reads it back."""
    sec, nanosec = stamp_parts(t_s)
    return float(sec) + 1e-9 * float(nanosec)


def f32(x: float) -> float:
    """A float through a float32 message field."""
    return float(np.float32(x))


class _Timer:
    """A periodic callback on lock-step clock ticks (as ``stack.ros_lockstep``)."""

    def __init__(self, period_s: float, callback: Callable[[], None]):
        self.period_s, self.callback = period_s, callback
        self.next_s: float | None = None

    def on_tick(self, t_s: float) -> None:
        if self.next_s is None:
            self.next_s = t_s
        if t_s + 1e-9 >= self.next_s:
            while self.next_s <= t_s + 1e-9:
                self.next_s += self.period_s
            self.callback()


@dataclass
class RunResult:
    """What an in-process run did: its folder, steps, simulated and wall time."""

    run_dir: Path
    steps: int
    sim_s: float
    wall_s: float
    done: bool  # the planner made all its steps (else the episode's time ran out)


class InProcessSystem:
    """The nodes' cores joined by an in-process message queue (see the module doc).

    Args:
        system: a prepared twin run (:func:`vigil.system.prepare`).
        max_sim_s: stop after this much simulated time (the person's script end plus
            the task's tail bounds it too).
        tail_s: the episode's time after the person's script ends.
        video: also store the camera frames (``camera_frames.bin``) for the report's video.
        say: progress lines (about one per simulated decision step).
        perception: ``"rendered"`` (the camera rendered through EGL and read by HOG;
            each frame's truth and detections go to ``detections.jsonl``, the data
            ``vigil fit-perception`` fits) or ``"model"`` (no rendering: the detections
            are drawn from ``perception_model`` and fed to the same tracker).
        perception_model: the fitted model (``"model"`` only).
    """

    def __init__(
        self,
        system: System,
        max_sim_s: float = float("inf"),
        tail_s: float = 5.0,
        video: bool = False,
        say: Callable[[str], None] | None = None,
        perception: str = "rendered",
        perception_model: PerceptionModel | None = None,
    ):
        if perception not in PERCEPTION_MODES:
            raise ConfigError("perception", perception, f"must be one of {PERCEPTION_MODES}")
        if perception == "model" and perception_model is None:
            raise ConfigError("perception_model", None, "needed with perception: model")
        if perception == "model" and video:
            raise ConfigError("video", video, "needs rendered perception (no frames to show)")
        p = system.params
        self.run_dir = system.run_dir
        self.say = say or (lambda _s: None)
        self._queue: deque[tuple[Callable[[Any], None], Any]] = deque()
        self._subs: dict[str, list[Callable[[Any], None]]] = {}
        self.done = False
        self.n_steps = 0

        # -- the planner (as stack.planning.node_planner) --------------------------------
        pp = p["planner"]
        start = PlannerStart(
            int(pp.get("initial_robot_cell", 0)),
            int(pp.get("initial_person_cell", -1)),
            str(pp.get("initial_direction", "")),
        )
        setup = make_planner(pp["task_file"], pp["policy_file"], start, online_config(pp))
        self.agent = setup.agent
        first_person = setup.first_person
        model = task_model(pp["task_file"])  # the twin's task: rewards and grid
        timing = StepTiming(
            start_delay_s=float(pp["start_delay_s"]),
            min_step_s=float(pp["min_step_s"]),
            min_event_step_s=float(pp["min_event_step_s"]),
            nav_timeout_s=float(pp["nav_timeout_s"]),
            obs_timeout_s=float(pp["obs_timeout_s"]),
            max_steps=int(pp["max_steps"]),
        )
        self.steps = DecisionSteps(self.agent, timing, first_person)
        self.steps_file = Path(pp["steps_file"])

        # -- the twin (as twin.bridge_node, through dm_control) --------------------------
        bp = p["twin_bridge"]
        twin_cfg = load_twin_config(bp["config"])
        outages = [Outage(s, t0, t1) for s, t0, t1 in json.loads(bp["sensor_outages"])]
        self.env: GuardEnvironment = make_environment(
            twin_cfg,
            model,
            seed=int(bp["seed"]),
            outages=outages,
            decision_step_s=float(pp["min_step_s"]) or 2.5,
            tail_s=tail_s,
            odom_rate_hz=float(bp["odom_rate_hz"]),
            time_limit_s=max_sim_s,
            render=perception == "rendered",
            reward=False,  # scored from the trace (vigil.report), as a ROS run is
        )
        twin = self.env.twin
        occ = twin.occupancy_map()
        res = f32(occ.resolution_m)  # nav_msgs/MapMetaData.resolution is float32
        origin = tuple(float(v) for v in occ.origin_m)
        data = occ.data.ravel().astype(int)
        h, w = int(occ.shape[0]), int(occ.shape[1])
        self.base = BaseWatchdog(float(bp.get("cmd_timeout_s", CMD_TIMEOUT_S)))
        self._frame_id = twin.camera_info.frame_id
        self._scan_geometry: tuple[float, ...] = ()

        # -- camera_people ----------------------------------------------------------------
        cp = p["camera_people"]
        grid, sections = load_config_file(cp["config_file"])
        homography = load_calibration(cp["calibration_file"]).homography
        self.camera = CameraPeopleTracker(
            CameraConfig.from_dict(sections.get("camera")), grid, homography
        )
        self._last_frame_s = 0.0

        # -- legs -------------------------------------------------------------------------
        lp = p["legs"]
        _, lsec = load_config_file(lp["config_file"])
        self.leg_config = LegConfig.from_dict(lsec.get("legs"))
        self.thresholds = CombinerConfig.from_dict(lsec.get("observations")).speed_thresholds_mps
        self.leg_tracker = LegTracker(TrackerConfig.from_dict(lsec.get("tracker")))
        self.laser_mount = Pose2D(float(lp["laser_x_m"]), 0.0, 0.0)
        self.static_map = StaticMap.from_occupancy(np.asarray(data, np.int16), w, h, res, origin)
        self.legs_pairing: ScanPosePairing[Scan] = ScanPosePairing()

        # -- observations -----------------------------------------------------------------
        op = p["observations"]
        self.observer = Observer(
            op["config_file"], op["calibration_file"], int(op.get("people", 1))
        )
        visibility = self.observer.visibility
        assert visibility is not None  # a twin run always has the camera's calibration
        self.model_camera: ModelCamera | None = None
        self.detections = None
        if perception == "model":
            assert perception_model is not None
            rng = np.random.default_rng([int(bp["seed"]), MODEL_STREAM])
            self.model_camera = ModelCamera(perception_model, visibility, rng)
        else:
            self.detections = open_write(self.run_dir / DETECTIONS_FILE, "w")

        # -- navigation -------------------------------------------------------------------
        np_ = p["navigation"]
        ngrid, fcfg = read_node_config(np_["config_file"], "follower", FollowerConfig)
        rate_hz = float(np_["control_rate_hz"])
        occ_map = from_occupancy_grid(data.tolist(), w, h, res, origin, 0.0)
        self.nav = ActionExecutor(ngrid, fcfg, occ_map, max(1, round(rate_hz / PROGRESS_HZ)))

        # -- speech -----------------------------------------------------------------------
        sp = p["speech"]
        speech_grid, scfg = read_node_config(sp["config_file"], "speech", SpeechConfig)
        if sp.get("voice"):
            scfg = replace(scfg, voice=sp["voice"])
        self.warner = WarningReactor(speech_grid, scfg)  # the speech node's own decisions
        try:
            self.speaker: Speaker | None = Speaker(scfg, sp["out_dir"] or None)
        except SpeechError as exc:
            self.speaker = None
            self.say(f"[inprocess] speech disabled: {exc}")

        # -- recorder ---------------------------------------------------------------------
        self.trace = open_write(self.run_dir / "trace.jsonl", "w")
        self.frames = None
        self._images: dict[float, np.ndarray] = {}
        if video:
            from vigil.frames import FRAMES_FILE, FrameWriter

            self.frames = FrameWriter(self.run_dir / FRAMES_FILE, 90)
        self.records = TraceRecords()  # as the recorder node (vigil.trace_records)

        # -- wiring: the topics each core's node subscribes to, in the system's node order --
        self._sub(topic.CLOCK, self._clock)
        self._sub(
            topic.ODOM, self.legs_on_odom, self.nav_on_pose, self.obs_on_odom, self.rec_on_odom
        )
        self._sub(topic.TWIN_TRUTH, self.rec_on_truth)
        self._sub(topic.SCAN, self.legs_on_scan)
        self._sub(topic.CAMERA_IMAGE, self.camera_on_image, self.rec_on_image)
        self._sub(topic.PERSON, self.obs_on_person, self.rec_on_person)
        self._sub(topic.LEGS, self.obs_on_legs, self.rec_on_legs)
        self._sub(topic.LEG_PEOPLE, self.nav.set_people)
        self._sub(topic.OBSERVATIONS, self.speech_on_observation, self.planner_on_observation)
        self._sub(topic.OBSERVATIONS_REQUEST, lambda _m: self.obs_publish())
        self._sub(topic.NAV_ACTION, self.nav_on_action)
        self._sub(topic.NAV_RESULT, self.planner_on_result)
        self._sub(topic.CMD_VEL, self.bridge_on_cmd)
        self._sub(topic.SPEECH_WARNING, self.rec_on_warning)
        self.timers = [
            _Timer(FRAME_TIMEOUT_S / 2.0, self.camera_watchdog),
            _Timer(float(op["decision_period_s"]), self.obs_publish),
            _Timer(1.0 / rate_hz, lambda: self._emit_nav(self.nav.tick(self.now_s))),
            _Timer(SPEECH_POLL_S, self.speech_on_timer),
            _Timer(0.1, lambda: self._planner_run(self.steps.tick(self.now_s))),
        ]
        write_text(self.steps_file, "")
        self.now_s = 0.0

    # -- the message queue ----------------------------------------------------------------
    def _sub(self, topic: str, *callbacks: Callable[[Any], None]) -> None:
        self._subs.setdefault(topic, []).extend(callbacks)

    def publish(self, topic: str, msg: Any) -> None:
        for cb in self._subs.get(topic, ()):
            self._queue.append((cb, msg))

    def _drain(self) -> None:
        for _ in range(MAX_MESSAGES_PER_INSTANT):
            if not self._queue:
                return
            cb, msg = self._queue.popleft()
            cb(msg)
        # the nodes keep answering each other without time passing: a livelock (an
        # episode that hung a whole study once); fail this episode, not the study
        raise RuntimeError(
            f"more than {MAX_MESSAGES_PER_INSTANT} messages at t = {self.now_s:.3f} s: "
            "the nodes loop without time passing"
        )

    def _clock(self, t_s: float) -> None:
        self.now_s = t_s
        for timer in self.timers:
            timer.on_tick(t_s)

    # -- the run --------------------------------------------------------------------------
    def run(self) -> RunResult:
        """Run until the planner is done or the episode ends; returns what happened."""
        wall0 = time.monotonic()
        ts = self.env.reset()
        try:
            while True:
                self._tick(ts.observation)
                if self.done or ts.last():
                    break
                ts = self._advance()
        finally:
            self.close()
        return RunResult(
            self.run_dir, self.n_steps, self.env.twin.time_s, time.monotonic() - wall0, self.done
        )

    def _advance(self):
        """Step the physics to the next sensor instant under the command the base's
        watchdog lets stand (the bridge's rule: zero once it is ``cmd_timeout_s`` old)."""
        env = self.env
        while True:
            ts = env.step(np.array(self.base.output(env.twin.time_s)))
            if ts.last() or env.task.due_now:
                return ts

    def _tick(self, obs: dict[str, np.ndarray]) -> None:
        t = float(obs["time"])
        now = ros_time(t)
        self.publish(topic.CLOCK, now)
        self._drain()
        due = self.env.task.due_now
        if "odometry" in due:
            od = obs["odometry"]
            self.publish(topic.ODOM, (now, Pose2D(float(od[0]), float(od[1]), float(od[2]))))
            self.publish(topic.TWIN_TRUTH, self._truth_record())
        if float(obs["scan_stamp"]) == t and "scan" in due:
            self.publish(topic.SCAN, self._scan(obs["scan"], now))
        if float(obs["camera_stamp"]) == t and "camera" in due:
            self.publish(topic.CAMERA_IMAGE, (now, obs["camera"]))
        self._drain()

    def _truth_record(self) -> dict:
        return truth_record(self.env.twin.ground_truth())

    def _scan(self, ranges: np.ndarray, now: float) -> Scan:
        if not self._scan_geometry:
            lc = self.env.twin.config.lidar
            s = self.env.twin.lidar
            geometry = (float(s.angles[0]), float(s.increment), lc.range_min_m, lc.range_max_m)
            self._scan_geometry = tuple(f32(v) for v in geometry)  # float32 message fields
        a0, da, r0, r1 = self._scan_geometry
        return Scan(
            ranges_m=np.asarray(ranges, dtype=float),
            angle_min_rad=a0,
            angle_increment_rad=da,
            range_min_m=r0,
            range_max_m=r1,
            stamp_s=now,
        )

    def bridge_on_cmd(self, cmd: tuple[float, float, float]) -> None:
        self.base.command(cmd, self.env.twin.time_s)

    # -- camera_people --------------------------------------------------------------------
    def camera_on_image(self, msg: tuple[float, np.ndarray]) -> None:
        stamp, rgb = msg
        self._last_frame_s = self.now_s
        gt = self.env.twin.ground_truth()
        people = tuple(
            PersonFrame(p.pose.x_m, p.pose.y_m, *p.velocity_mps, p.in_room) for p in gt.people
        )
        if self.model_camera is not None:
            points = self.model_camera.frame(people, gt.robot)
            state = self.camera.update_points(tuple(points), stamp)
        else:
            state = self.camera.process_frame(rgb[:, :, ::-1].copy(), stamp)  # rgb8 -> BGR
            if self.detections is not None:
                record = {
                    "t": round(gt.time_s, 4),
                    "robot": [round(gt.robot.x_m, 4), round(gt.robot.y_m, 4),
                              round(gt.robot.yaw_rad, 4)],
                    "people": [[round(p.x_m, 4), round(p.y_m, 4), round(p.vx_mps, 4),
                                round(p.vy_mps, 4), p.in_room] for p in people],
                    "detections": [[round(x, 4), round(y, 4)] for x, y in state.people_m],
                }  # fmt: skip
                self.detections.write(json.dumps(record) + "\n")
        self.publish(topic.PERSON, json.dumps(self.camera.message(state)))

    def camera_watchdog(self) -> None:
        silent_s = self.now_s - self._last_frame_s
        if silent_s <= FRAME_TIMEOUT_S:
            return
        self.publish(topic.PERSON, json.dumps(self.camera.state.silent_dict(silent_s)))

    # -- legs -----------------------------------------------------------------------------
    def legs_on_odom(self, msg: tuple[float, Pose2D]) -> None:
        for scan in self.legs_pairing.on_pose(*msg):
            self.legs_process(scan)

    def legs_on_scan(self, scan: Scan) -> None:
        for waiting in self.legs_pairing.on_scan(scan.stamp_s, scan):
            self.legs_process(waiting)

    def legs_process(self, scan: Scan) -> None:
        try:
            laser_pose = self.legs_pairing.laser_pose(scan.stamp_s, self.laser_mount)
            det = detect_legs(scan, self.leg_config, laser_pose, self.static_map)
            tracks = self.leg_tracker.update(scan.stamp_s, det.people)
        except BadScanError:
            return
        self.publish(topic.LEGS, legs_to_dict(det, tracks, self.thresholds))
        self.publish(topic.LEG_PEOPLE, [t.position_m for t in tracks if t.confirmed])

    # -- observations ---------------------------------------------------------------------
    def obs_on_person(self, text: str) -> None:
        try:  # as the node: a message that cannot be used is skipped
            self.observer.on_camera(camera_state_from_json(text, self.now_s))
        except (ValueError, PerceptionError) as err:
            self.say(f"[inprocess] person message ignored: {err}")

    def obs_on_legs(self, data: dict) -> None:
        try:
            self.observer.on_tracks(tracks_from_dict(data, self.now_s))
        except (ValueError, TypeError) as err:
            self.say(f"[inprocess] legs message ignored: {err}")

    def obs_on_odom(self, msg: tuple[float, Pose2D]) -> None:
        self.observer.on_pose(msg[1])

    def obs_publish(self) -> None:
        try:
            _, record = self.observer.observe(self.now_s)
        except (ValueError, ArithmeticError) as err:  # as the node: that step is skipped
            self.say(f"[inprocess] observation skipped: {err}")
            return
        self.publish(topic.OBSERVATIONS, json.dumps(record))

    # -- navigation -----------------------------------------------------------------------
    def nav_on_pose(self, msg: tuple[float, Pose2D]) -> None:
        self._emit_nav(self.nav.set_pose(msg[1], self.now_s))

    def nav_on_action(self, goal: tuple[int, str]) -> None:
        goal_id, action = goal
        self._emit_nav(self.nav.action(action, self.now_s, goal_id))

    def _emit_nav(self, outputs) -> None:
        for o in outputs:
            if o.kind == "cmd":
                self.publish(topic.CMD_VEL, (o.cmd.vx_mps, o.cmd.vy_mps, o.cmd.wz_radps))
            elif o.kind == "result":
                self.publish(topic.NAV_RESULT, json.dumps(o.body))

    # -- speech ---------------------------------------------------------------------------
    def speech_on_observation(self, text: str) -> None:
        self.warner.observe(json.loads(text))
        self.speech_check()

    def speech_check(self) -> None:
        if self.speaker is not None:
            self.speaker.poll(self.now_s)
        speaking = self.speaker is not None and self.speaker.speaking
        decision = self.warner.decide(self.now_s, speaking)
        if decision == "say":
            self.publish(topic.SPEECH_WARNING, self.speaker.config.warning if self.speaker else "")
            if self.speaker is not None:
                try:
                    self.speaker.say(None, self.now_s, frame_stamp_s=self.warner.frame_stamp_s)
                except SpeechError as exc:
                    self.say(f"[inprocess] cannot speak: {exc}")
        elif decision == "stop" and self.speaker is not None:
            self.speaker.stop()

    def speech_on_timer(self) -> None:
        if self.speaker is None:
            return
        if self.speaker.speaking:
            self.speech_check()
        self.speaker.poll(self.now_s)

    # -- planner --------------------------------------------------------------------------
    def planner_on_result(self, text: str) -> None:
        self._planner_run(self.steps.on_nav_result(self.now_s, json.loads(text)))

    def planner_on_observation(self, text: str) -> None:
        if self.steps.waiting not in ("obs", "nav", "hold"):
            return
        try:
            commands = self.steps.on_observation(self.now_s, Observed.from_dict(json.loads(text)))
        except (ValueError, ObservationError) as err:
            self.say(f"[inprocess] observation ignored: {err}")
            return
        self._planner_run(commands)

    def _planner_run(self, commands) -> None:
        for c in commands:
            if c.kind == "act":
                self.publish(topic.NAV_ACTION, (c.goal_id, c.action))
            elif c.kind == "request":
                self.publish(topic.OBSERVATIONS_REQUEST, None)
            elif c.kind == "record" and c.record is not None:
                self.n_steps += 1
                with open_write(self.steps_file, "a") as f:
                    f.write(json.dumps(c.record, sort_keys=True) + "\n")
                o = c.record["observation"]
                self.say(
                    f"[inprocess] step {c.record['step']} t={self.now_s:.1f}s: "
                    f"{c.record['action']} -> robot {o['robot']}, person {o['person']}, "
                    f"{o['velocity']}"
                )
            elif c.kind == "done":
                self.done = True

    # -- recorder -------------------------------------------------------------------------
    def rec_on_truth(self, record: dict) -> None:
        gap = self.records.on_truth(record)
        if gap is not None:
            self._trace_write(gap, None)  # the camera is silent (outage)

    def rec_on_odom(self, msg: tuple[float, Pose2D]) -> None:
        self.records.on_odom(msg[1])

    def rec_on_legs(self, data: dict) -> None:
        self.records.on_legs(data)

    def rec_on_warning(self, text: str) -> None:
        self.records.on_warning(text)

    def rec_on_image(self, msg: tuple[float, np.ndarray]) -> None:
        if self.frames is not None:
            self._images[round(msg[0], 6)] = msg[1]
            while len(self._images) > 4:
                del self._images[min(self._images)]

    def rec_on_person(self, text: str) -> None:
        written = self.records.on_person(json.loads(text))
        if written is not None:
            self._trace_write(*written)

    def _trace_write(self, record: dict, stamp: float | None) -> None:
        self.trace.write(json.dumps(record, sort_keys=True) + "\n")
        if self.frames is not None:
            rgb = self._images.pop(stamp, None) if stamp is not None else None
            self.frames.add(record["t"], None if rgb is None else rgb[:, :, ::-1].copy())

    def close(self) -> None:
        if self.speaker is not None:
            self.speaker.stop()
        self.trace.close()
        if self.detections is not None:
            self.detections.close()
        if self.frames is not None:
            self.frames.close()
        self.env.close()


def run_inprocess(
    scenario: Scenario | str | Path,
    out: str | Path,
    config_path: str | Path | None = None,
    seed: int | None = None,
    deployment: Deployment | None = None,
    max_steps: int | None = None,
    max_sim_s: float = float("inf"),
    tail_s: float = 5.0,
    report: bool = True,
    plots: bool = False,
    video: bool = False,
    say: Callable[[str], None] = print,
    perception: str = "rendered",
    perception_model: PerceptionModel | str | Path | None = None,
) -> dict:
    """Run a scenario through the in-process loop and score it; returns the summary.

    Args:
        scenario: the scenario (or its file).
        out: the run folder (created; its steps and trace are overwritten).
        config_path: the deployment file (default ``config/twin.yaml``), unless
            ``deployment`` is given.
        seed: overrides the scenario's seed.
        max_steps: overrides the scenario's decision steps (0: until the episode ends).
        max_sim_s: stop after this much simulated time.
        tail_s: the episode runs this long after the person's script ends.
        report: write the report (``vigil.report.write_report``: metrics, tables).
        plots, video: the report's figures and video.
        perception: ``"rendered"`` or ``"model"`` (:class:`InProcessSystem`).
        perception_model: the model, or its file (default
            ``config/perception-model.yaml``), for ``perception="model"``.

    Returns:
        The report's summary (``summary.json``) with an ``inprocess`` entry (steps,
        simulated and wall seconds), or that entry alone when ``report`` is False.

    Raises:
        ConfigError: a bad scenario or deployment.
    """
    if not isinstance(scenario, Scenario):
        scenario = load_scenario(scenario)
    if seed is not None:
        scenario = replace(scenario, seed=seed)
    if max_steps is not None:
        scenario = replace(scenario, steps=max_steps)
    dep = deployment or load_deployment(config_path or DEFAULT_CONFIG)
    if dep.mode != "twin":
        raise ConfigError("mode", dep.mode, "the in-process loop needs a twin deployment")
    run_dir = Path(out).resolve()
    quiet = lambda _s: None  # noqa: E731 - prepare's calibration line is not progress
    system = prepare(dep, run_dir, scenario, say=quiet)
    system.params["planner"]["max_steps"] = scenario.steps
    if perception == "model" and not isinstance(perception_model, PerceptionModel):
        perception_model = PerceptionModel.load(perception_model or DEFAULT_PERCEPTION_MODEL)
    loop = InProcessSystem(
        system,
        max_sim_s=max_sim_s,
        tail_s=tail_s,
        video=video,
        say=say,
        perception=perception,
        perception_model=perception_model if perception == "model" else None,
    )
    with blas_threads(1):  # as a study's workers and the nodes: small products only lose by more
        result = loop.run()
    info = {
        "scenario": scenario.name,
        "seed": scenario.seed,
        "steps": result.steps,
        "sim_s": round(result.sim_s, 3),
        "wall_s": round(result.wall_s, 2),
        "done": result.done,
        "perception": perception,
    }
    write_text(run_dir / "inprocess.json", json.dumps(info, indent=2, sort_keys=True) + "\n")
    if not report:
        return {"inprocess": info}
    from vigil.report import write_report

    summary = write_report(run_dir, scenario.task, plots=plots, video=video, say=None)
    summary["inprocess"] = info
    return summary

"""The recorder node: writes what a run shows into its folder, as it happens.

For every camera detection record (``/perception/person``, one per frame) it appends
one line to ``trace.jsonl`` (and, while the camera is silent, e.g. in an outage, one
per ``TRUTH_GAP_S`` of ground truth with ``camera`` null, so that the metrics keep
seeing where robot and person are) (the instant's ground truth from ``/twin/truth`` when there
is a twin, the odometry, the camera's detection, the leg tracks, the warnings decided
since the last record) and the camera frame, JPEG-encoded, to ``camera_frames.bin``
(:mod:`vigil.frames`). It writes raw records only and imports nothing of the report:
:func:`vigil.report.write_report` composes the tables, figures and the video from the
folder after the nodes have stopped, outside the lock-step.

Subscribes: ``/camera/image_raw``, ``/perception/person`` (CameraPerson),
``/perception/legs`` (LegTracks), ``/twin/truth`` (TwinTruth), ``/odom``,
``/speech/warning`` (Warning), ``/speech/done`` (SpeechDone); the typed messages are
read back into the records the trace has always held (:mod:`stack.ros_msgs`).

Parameters: ``out_dir``, ``task_file`` and ``config_file`` (accepted, unused: the
report reads the task), ``video`` (false: no frames), ``jpeg_quality``, ``lockstep``.
"""

from __future__ import annotations

import functools
import json
import os
from pathlib import Path

from nav_msgs.msg import Odometry
from rclpy.node import Node
from sensor_msgs.msg import Image
from vigil_interfaces.msg import CameraPerson, LegTracks, SpeechDone, TwinTruth, Warning

import stack.topics as topic
from stack.config import open_write
from stack.perception.errors import BadFrameError
from stack.perception.messages import image_from_msg, pose_from_msg, stamp_to_s
from stack.ros_lockstep import Participant
from stack.ros_main import Releasing, spin_node
from stack.ros_msgs import camera_from_msg, legs_from_msg, speech_done_from_msg, truth_from_msg
from stack.ros_params import declare
from vigil.frames import FRAMES_FILE, FrameWriter
from vigil.trace_records import TraceRecords

TRACE_FILE = "trace.jsonl"


def _skips_bad_messages(callback):
    """A message of the wrong shape is logged and skipped: the recorder never dies of one."""

    @functools.wraps(callback)
    def guarded(self, msg):
        try:
            callback(self, msg)
        except (TypeError, ValueError, KeyError, AttributeError, ArithmeticError) as exc:
            self.get_logger().warning(
                f"{callback.__name__}: message skipped ({exc!r})", throttle_duration_sec=5.0
            )

    return guarded


class RecorderNode(Releasing, Node):
    """Trace and camera frames of a run."""

    def __init__(self, **kwargs):
        super().__init__("recorder", **kwargs)
        # task_file and config_file: unused, kept so that older parameter files still load
        v = declare(
            self,
            out_dir="runs/recording",
            task_file="",
            config_file="",
            video=True,
            jpeg_quality=90,
            lockstep=False,
        )
        out_dir, video, quality = Path(v.out_dir), v.video, v.jpeg_quality
        out_dir.mkdir(parents=True, exist_ok=True)
        self.trace = open_write(out_dir / TRACE_FILE, "a")
        self.frames = FrameWriter(out_dir / FRAMES_FILE, quality) if video else None
        self.images: dict[float, object] = {}
        self.records = TraceRecords()  # what each trace record holds (vigil.trace_records)
        ls = self.lockstep = Participant(self, v.lockstep)
        # in the order the twin's sensors cause them: when several wait at once the
        # executor takes them in this order, so a camera record holds the truth and
        # odometry of its own tick and the legs of its own scan (as when the slower
        # message came later, and as vigil.inprocess's queue delivers them: the
        # twin's messages first, then what the legs node and then the camera node sent)
        ls.subscription(Image, topic.CAMERA_IMAGE, self.on_image, 5)
        ls.subscription(TwinTruth, topic.TWIN_TRUTH, self.on_truth, 10)
        ls.subscription(Odometry, topic.ODOM, self.on_odom, 10)
        ls.subscription(LegTracks, topic.LEGS, self.on_legs, 10)
        ls.subscription(CameraPerson, topic.PERSON, self.on_person, 10)
        ls.subscription(Warning, topic.SPEECH_WARNING, self.on_warning, 10)
        ls.subscription(SpeechDone, topic.SPEECH_DONE, self.on_speech_done, 10)
        self.get_logger().info(f"recording into {out_dir}")

    def on_image(self, msg: Image) -> None:
        stamp = round(stamp_to_s(msg.header.stamp), 6)
        self.images[stamp] = msg
        while len(self.images) > 4:
            del self.images[min(self.images)]

    @_skips_bad_messages
    def on_truth(self, msg: TwinTruth) -> None:
        record = self.records.on_truth(truth_from_msg(msg) or {})
        if record is not None:
            self.write(record, None)  # the camera is silent (outage)

    def on_odom(self, msg: Odometry) -> None:
        try:
            self.records.on_odom(pose_from_msg(msg.pose.pose))
        except ValueError:
            self.records.on_odom(None)

    @_skips_bad_messages
    def on_legs(self, msg: LegTracks) -> None:
        self.records.on_legs(legs_from_msg(msg))

    def on_warning(self, msg: Warning) -> None:
        self.records.on_warning(msg.text)

    @_skips_bad_messages
    def on_speech_done(self, msg: SpeechDone) -> None:
        # an utterance's end comes on wall-clock time (espeak-ng): logged, not traced,
        # so that the trace of a lock-step run is the same on every machine
        data = speech_done_from_msg(msg)
        if data.get("kind") == "failed":
            self.get_logger().warning(f"speech failed: {data.get('error')}")

    @_skips_bad_messages
    def on_person(self, msg: CameraPerson) -> None:
        written = self.records.on_person(camera_from_msg(msg))
        if written is not None:
            self.write(*written)

    def write(self, record: dict, stamp: float | None) -> None:
        """One trace record and, with the video, the frame stamped ``stamp``."""
        self.trace.write(json.dumps(record, sort_keys=True) + "\n")
        self.trace.flush()
        if self.frames is not None:
            frame = None
            image = self.images.pop(stamp, None) if stamp is not None else None
            if image is not None:
                try:
                    frame = image_from_msg(image)  # BGR, as the JPEG encoder wants
                except BadFrameError:
                    frame = None
            self.frames.add(record["t"], frame)
            self.frames.flush()

    def _release(self) -> None:
        """Close the frames and the trace (once, :class:`stack.ros_main.Releasing`),
        each whatever the other did (a full disk may fail one); the first error is
        raised once both are closed."""
        errors: list[OSError] = []
        if self.frames is not None:
            try:
                self.frames.close()
            except OSError as err:
                errors.append(err)
        try:
            self.trace.flush()
            os.fsync(self.trace.fileno())
        except OSError as err:
            errors.append(err)
        finally:
            try:
                self.trace.close()
            except OSError as err:  # the buffer's last bytes found no room either
                errors.append(err)
        if errors:
            raise errors[0]


def main(args=None) -> None:
    spin_node(RecorderNode, args)


if __name__ == "__main__":
    main()

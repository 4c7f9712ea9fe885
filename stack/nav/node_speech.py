"""The speech node: warns a person who is in a restricted cell with the robot (thesis
3.2.2 and 4.4), or walking into it, while they are there, and reports when it has
finished.

When to speak is :class:`stack.nav.warning.WarningReactor` (the in-process loop runs
the same): the robot's and the person's cells (the observations node's fused view)
are the same restricted cell, or the person walks into it from the next cell, or did
within ``grace_s``; a warning playing after that is cut short; nothing is queued.

Subscribes (names are parameters):
    ``/observations`` vigil_interfaces/PersonObservation: the observations node's
        (``robot`` and ``person`` labels: a cell number, or anything else for none; with several
        people also ``people``, one label per person slot: whoever is in the robot's
        cell is warned, :func:`stack.nav.warning.person_to_warn`).
    ``/speech/say`` std_msgs/String: say this text now (empty: the configured warning).

Publishes:
    ``/speech/done`` vigil_interfaces/SpeechDone: {request_id, kind, text, voice, wav,
        duration_s, error} for every finished, replaced, dropped or failed request.
    ``/speech/speaking`` std_msgs/Bool: true when an utterance starts, false when idle.
    ``/speech/warning`` vigil_interfaces/Warning: the warning's text, the warned
        person's cell and, as ``request_id``, the warning's number (1, 2, ...: it is
        published before the speaker gives the utterance its id), the moment it is
        decided (the utterance follows).

Parameters: ``config_file`` (YAML with optional ``grid`` and ``speech`` sections),
``voice`` (overrides the file: "en", "pt"), ``out_dir`` (the run folder: WAV + log there
instead of the sound card), ``poll_rate_hz``, ``lockstep`` (see :mod:`stack.ros_lockstep`).
"""

from __future__ import annotations

from dataclasses import replace

from rclpy.node import Node
from std_msgs.msg import Bool, String
from vigil_interfaces.msg import PersonObservation, SpeechDone, Warning

import stack.topics as topic
from stack.cells import CellGrid
from stack.nav.config import SpeechConfig, read_node_config
from stack.nav.speech import Speaker, SpeechError, SpeechEvent
from stack.nav.warning import WarningReactor
from stack.ros_lockstep import Participant
from stack.ros_main import Releasing, spin_node
from stack.ros_msgs import observation_from_msg, speech_done_to_msg, warning_to_msg
from stack.ros_params import declare, declare_topics


def load_speech_config(path: str) -> tuple[CellGrid, SpeechConfig]:
    """Read the ``grid`` and ``speech`` sections of a YAML file (both optional).

    Raises:
        ConfigError: unreadable file or an invalid value.
    """
    return read_node_config(path, "speech", SpeechConfig)


class SpeechNode(Releasing, Node):
    """Speaks warnings through :class:`stack.nav.speech.Speaker`."""

    def __init__(self, **kwargs):
        super().__init__("speech", **kwargs)
        v = declare(self, config_file="", voice="", out_dir="", poll_rate_hz=10.0, lockstep=False)
        voice, out_dir, rate_hz = v.voice, v.out_dir, v.poll_rate_hz
        topics = declare_topics(
            self,
            observations=topic.OBSERVATIONS,
            say=topic.SPEECH_SAY,
            done=topic.SPEECH_DONE,
            speaking=topic.SPEECH_SPEAKING,
            warning=topic.SPEECH_WARNING,
        )
        self.grid, config = load_speech_config(v.config_file)
        if voice:
            config = replace(config, voice=voice)
        self.config = config
        self.warner = WarningReactor(self.grid, config)
        self.speaker: Speaker | None = None
        self.speaker_error = ""
        try:
            self.speaker = Speaker(config, out_dir or None)
        except SpeechError as exc:  # keep running: every request reports this error
            self.speaker_error = str(exc)
            self.get_logger().error(f"speech disabled: {exc}")
        self._failed_id = 0
        ls = self.lockstep = Participant(self, v.lockstep)
        self.done_pub = ls.publisher(SpeechDone, topics["done"], 10)
        self.speaking_pub = ls.publisher(Bool, topics["speaking"], 10)
        self.warning_pub = ls.publisher(Warning, topics["warning"], 10)
        self._warnings = 0
        ls.subscription(PersonObservation, topics["observations"], self.on_observation, 10)
        ls.subscription(String, topics["say"], self.on_say, 10)
        ls.timer(1.0 / rate_hz, self.on_timer)  # the lock-step clock, like every node
        self.get_logger().info(
            f"speech: voice {config.voice!r}, policy {config.policy}, "
            f"{'WAV into ' + out_dir if out_dir else 'sound card'}"
        )

    def now_s(self) -> float:
        return self.lockstep.now_s()

    def on_observation(self, msg: PersonObservation) -> None:
        try:
            body = observation_from_msg(msg)
            self.warner.observe(body)
        except (ValueError, KeyError) as exc:
            self.get_logger().warning(
                f"ignoring a malformed observation: {exc}", throttle_duration_sec=5.0
            )
            return
        self.check()

    def check(self) -> None:
        if self.speaker is not None:  # finish what is due first: the same on any machine
            for event in self.speaker.poll(self.now_s()):
                self.publish_event(event)
        speaking = self.speaker is not None and self.speaker.speaking
        w = self.warner
        decision = w.decide(self.now_s(), speaking)
        if decision == "say":
            how = "walking into" if w.person_cell != w.robot_cell else "in"
            self.get_logger().info(f"person {how} restricted cell {w.robot_cell}: warning")
            self._warnings += 1
            self.warning_pub.publish(
                warning_to_msg(self.config.warning, self._warnings, w.person_cell, self.now_s())
            )
            self.say(None, w.frame_stamp_s)
        elif decision == "stop" and self.speaker is not None:
            self.get_logger().info("the person has left: warning cut short")
            for event in self.speaker.stop():
                self.publish_event(event)

    def on_say(self, msg: String) -> None:
        self.say(msg.data or None)

    def say(self, text: str | None, frame_stamp_s: float | None = None) -> None:
        if self.speaker is None:
            self._failed_id += 1
            self.publish_event(
                SpeechEvent("failed", -self._failed_id, text or "", error=self.speaker_error)
            )
            return
        try:
            self.speaker.say(text, self.now_s(), frame_stamp_s=frame_stamp_s)
        except SpeechError as exc:
            self.get_logger().warning(f"cannot say {text!r}: {exc}")
            self._failed_id += 1
            self.publish_event(SpeechEvent("failed", -self._failed_id, text or "", error=str(exc)))
            return
        self.on_timer()  # report "started" without waiting for the next tick

    def on_timer(self) -> None:
        if self.speaker is None:
            return
        if self.speaker.speaking:
            self.check()  # cut a warning the person has walked away from
        for event in self.speaker.poll(self.now_s()):
            self.publish_event(event)

    def publish_event(self, event: SpeechEvent) -> None:
        if event.kind == "started":
            self.speaking_pub.publish(Bool(data=True))
            return
        if event.kind == "failed":
            self.get_logger().warning(f"speech failed: {event.error}")
        utt = event.utterance
        body = {
            "request_id": event.request_id,
            "kind": event.kind,
            "text": event.text,
            "voice": utt.voice if utt else None,
            "wav": str(utt.wav_path) if utt and utt.wav_path else None,
            "duration_s": utt.duration_s if utt and utt.duration_s == utt.duration_s else None,
            "error": event.error,
        }
        self.done_pub.publish(speech_done_to_msg(body, self.now_s()))
        if self.speaker is not None and not self.speaker.speaking:
            self.speaking_pub.publish(Bool(data=False))

    def _release(self) -> None:
        """The speaker stopped, once (:class:`stack.ros_main.Releasing`)."""
        if self.speaker is not None:
            self.speaker.stop()


def main(args=None) -> None:
    spin_node(SpeechNode, args)


if __name__ == "__main__":
    main()

"""The speech node: says the warning when the robot reaches a restricted cell with a
person at or near it (thesis 3.2.2 and 4.4), and reports when it has finished.

Subscribes (names are parameters):
    ``/nav/result`` std_msgs/String: the navigation node's JSON results; a succeeded
        result whose ``cell`` is restricted triggers the check.
    ``/perception/person_cell`` std_msgs/String: the person's cell as perception
        publishes it ("7"; anything that is not a positive integer, e.g. "No person",
        means nobody is seen).
    ``/speech/say`` std_msgs/String: say this text now (empty: the configured warning).

Publishes:
    ``/speech/done`` std_msgs/String: JSON {request_id, kind, text, voice, wav,
        duration_s, error} for every finished, replaced, dropped or failed request.
    ``/speech/speaking`` std_msgs/Bool: true when an utterance starts, false when idle.
    ``/speech/warning`` std_msgs/String: the warning's text, the moment it is decided
        (when the navigation result arrives; the utterance itself follows).

Parameters: ``config_file`` (YAML with optional ``grid`` and ``speech`` sections),
``voice`` (overrides the file: "en", "pt"), ``out_dir`` (the run folder: WAV + log there
instead of the sound card), ``poll_rate_hz``, ``lockstep`` (see :mod:`stack.ros_lockstep`).
"""

from __future__ import annotations

import json
from dataclasses import replace

from rclpy.node import Node
from std_msgs.msg import Bool, String

from stack.cells import CellGrid
from stack.nav.config import SpeechConfig, read_node_config
from stack.nav.speech import Speaker, SpeechError, SpeechEvent, should_warn
from stack.ros_lockstep import Participant
from stack.ros_main import spin_node


def load_speech_config(path: str) -> tuple[CellGrid, SpeechConfig]:
    """Read the ``grid`` and ``speech`` sections of a YAML file (both optional).

    Raises:
        ConfigError: unreadable file or an invalid value.
    """
    return read_node_config(path, "speech", SpeechConfig)


class SpeechNode(Node):
    """Speaks warnings through :class:`stack.nav.speech.Speaker`."""

    def __init__(self, **kwargs):
        super().__init__("speech", **kwargs)
        p = self.declare_parameter
        config_file = p("config_file", "").value
        voice = p("voice", "").value
        out_dir = p("out_dir", "").value
        rate_hz = p("poll_rate_hz", 10.0).value
        topics = {
            name: p(f"{name}_topic", default).value
            for name, default in (
                ("result", "/nav/result"),
                ("person_cell", "/perception/person_cell"),
                ("say", "/speech/say"),
                ("done", "/speech/done"),
                ("speaking", "/speech/speaking"),
                ("warning", "/speech/warning"),
            )
        }
        self.grid, config = load_speech_config(config_file)
        if voice:
            config = replace(config, voice=voice)
        self.config = config
        self.person_cell: int | None = None
        self.speaker: Speaker | None = None
        self.speaker_error = ""
        try:
            self.speaker = Speaker(config, out_dir or None)
        except SpeechError as exc:  # keep running: every request reports this error
            self.speaker_error = str(exc)
            self.get_logger().error(f"speech disabled: {exc}")
        self._failed_id = 0
        ls = self.lockstep = Participant(self, p("lockstep", False).value)
        self.done_pub = ls.publisher(String, topics["done"], 10)
        self.speaking_pub = ls.publisher(Bool, topics["speaking"], 10)
        self.warning_pub = ls.publisher(String, topics["warning"], 10)
        ls.subscription(String, topics["result"], self.on_result, 10)
        ls.subscription(String, topics["person_cell"], self.on_person_cell, 10)
        ls.subscription(String, topics["say"], self.on_say, 10)
        self.timer = self.create_timer(1.0 / rate_hz, self.on_timer)
        self.get_logger().info(
            f"speech: voice {config.voice!r}, policy {config.policy}, "
            f"{'WAV into ' + out_dir if out_dir else 'sound card'}"
        )

    def now_s(self) -> float:
        return self.lockstep.now_s()

    def on_person_cell(self, msg: String) -> None:
        text = msg.data.strip()
        self.person_cell = int(text) if text.isdigit() and int(text) > 0 else None

    def on_result(self, msg: String) -> None:
        try:
            body = json.loads(msg.data)
            result, cell = body["result"], body.get("cell")
        except (ValueError, TypeError, KeyError) as exc:
            self.get_logger().warning(f"ignoring a malformed navigation result {msg.data!r}: {exc}")
            return
        if result != "succeeded" or not isinstance(cell, int):
            return
        if should_warn(self.grid, cell, self.person_cell, self.config):
            self.get_logger().info(f"robot in restricted cell {cell}, person in {self.person_cell}")
            self.warning_pub.publish(String(data=self.config.warning))
            self.say(None)

    def on_say(self, msg: String) -> None:
        self.say(msg.data or None)

    def say(self, text: str | None) -> None:
        if self.speaker is None:
            self._failed_id += 1
            self.publish_event(
                SpeechEvent("failed", -self._failed_id, text or "", error=self.speaker_error)
            )
            return
        try:
            self.speaker.say(text, self.now_s())
        except SpeechError as exc:
            self.get_logger().warning(f"cannot say {text!r}: {exc}")
            self._failed_id += 1
            self.publish_event(SpeechEvent("failed", -self._failed_id, text or "", error=str(exc)))
            return
        self.on_timer()  # report "started" without waiting for the next tick

    def on_timer(self) -> None:
        if self.speaker is None:
            return
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
        self.done_pub.publish(String(data=json.dumps(body)))
        if self.speaker is not None and not self.speaker.speaking:
            self.speaking_pub.publish(Bool(data=False))

    def destroy_node(self) -> None:
        if self.speaker is not None:
            self.speaker.stop()
        super().destroy_node()


def main(args=None) -> None:
    spin_node(SpeechNode, args)


if __name__ == "__main__":
    main()

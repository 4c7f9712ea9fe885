"""Spoken warnings through espeak-ng: WAV files, voices, errors, queue and replace."""

import shutil

import pytest

from stack.cells import ConfigError
from stack.nav.config import SpeechConfig
from stack.nav.speech import (
    EmptyTextError,
    EspeakNotFoundError,
    Speaker,
    SpeechError,
    UnknownVoiceError,
    forget_said,
    synthesize,
    wav_duration_s,
)
from stack.nav.warning import WarningGate

pytestmark = pytest.mark.skipif(shutil.which("espeak-ng") is None, reason="needs espeak-ng")


@pytest.mark.parametrize(
    "voice, text",
    [
        ("en", "Please do not stay here. This area is restricted."),
        ("pt", "Por favor, não fique aqui. Esta área é restrita."),
    ],
)
def test_warning_makes_a_wav_of_plausible_length(tmp_path, voice, text):
    cfg = SpeechConfig(voice=voice, words_per_minute=160)
    utt = synthesize(text, tmp_path / "w.wav", cfg)
    assert utt.wav_path.is_file()
    assert utt.duration_s == pytest.approx(wav_duration_s(utt.wav_path))
    spoken_s = len(text.split()) * 60.0 / cfg.words_per_minute  # 3.4 s for 9 words
    assert 0.5 * spoken_s <= utt.duration_s <= 2.0 * spoken_s
    short = synthesize("Stop.", tmp_path / "s.wav", cfg)
    assert short.duration_s < utt.duration_s / 2


def test_a_repeated_warning_reuses_its_audio_until_forgotten(tmp_path, monkeypatch):
    """The same words with the same settings run espeak-ng once per process (the same
    bytes each time); :func:`forget_said` makes the next one synthesise again."""
    import subprocess

    runs = []
    real = subprocess.run

    def counting(args, *a, **kw):
        if "-w" in args:
            runs.append(args)
        return real(args, *a, **kw)

    monkeypatch.setattr(subprocess, "run", counting)
    forget_said()
    cfg = SpeechConfig(voice="en")
    first = synthesize("Please stay out.", tmp_path / "a.wav", cfg)
    again = synthesize("Please stay out.", tmp_path / "b.wav", cfg)
    assert len(runs) == 1
    assert (tmp_path / "a.wav").read_bytes() == (tmp_path / "b.wav").read_bytes()
    assert again.duration_s == first.duration_s
    forget_said()
    synthesize("Please stay out.", tmp_path / "c.wav", cfg)
    assert len(runs) == 2


def test_faster_speech_is_shorter(tmp_path):
    text = "Please do not stay here."
    slow = synthesize(text, tmp_path / "a.wav", SpeechConfig(words_per_minute=120))
    fast = synthesize(text, tmp_path / "b.wav", SpeechConfig(words_per_minute=300))
    assert fast.duration_s < 0.7 * slow.duration_s


def test_clear_errors(tmp_path):
    with pytest.raises(EmptyTextError, match="nothing to say"):
        synthesize("   ", tmp_path / "x.wav")
    with pytest.raises(UnknownVoiceError, match="no voice 'zz-none'"):
        synthesize("hello", tmp_path / "x.wav", voice="zz-none")
    with pytest.raises(EspeakNotFoundError, match="install the Debian package 'espeak-ng'"):
        synthesize("hello", tmp_path / "x.wav", SpeechConfig(espeak_path="/nonexistent/espeak"))
    assert not (tmp_path / "x.wav").exists()


def test_a_restarted_speaker_numbers_after_the_clips_there_and_keeps_them(tmp_path):
    """A speech node restarted mid-run (or a run into a folder holding clips) goes on
    from the highest clip number: before, it numbered from 1 and overwrote
    utterance_0001.wav, and the log's first line then named the wrong clip."""
    first = Speaker(SpeechConfig(policy="queue"), tmp_path)
    first.say("First run.", now_s=0.0)
    first.poll(100.0)
    (tmp_path / "utterance_0007.wav").write_bytes((tmp_path / "utterance_0001.wav").read_bytes())
    (tmp_path / "utterance_notes.wav").write_bytes(b"not a clip of ours")
    kept = {p.name: p.read_bytes() for p in tmp_path.glob("*.wav")}
    again = Speaker(SpeechConfig(policy="queue"), tmp_path)
    rid = again.say("After the restart.", now_s=0.0)
    events = again.poll(100.0)
    assert rid == 8 and [e.kind for e in events] == ["started", "finished"]
    assert events[0].utterance.wav_path.name == "utterance_0008.wav"
    assert {p.name: p.read_bytes() for p in tmp_path.glob("*.wav") if p.name in kept} == kept
    log = (tmp_path / Speaker.LOG_NAME).read_text().splitlines()
    assert [line.split("\t")[3] for line in log[1:]] == ["utterance_0001.wav", "utterance_0008.wav"]


def test_speaker_queues_and_logs_each_utterance(tmp_path):
    sp = Speaker(SpeechConfig(policy="queue"), tmp_path / "run")
    first = sp.say(None, now_s=0.0)
    second = sp.say("Second warning.", now_s=0.1)
    events = sp.poll(0.2)
    assert [(e.kind, e.request_id) for e in events] == [("started", first)]
    assert sp.speaking and sp.queued == 1
    duration = events[0].utterance.duration_s
    events = sp.poll(duration + 0.01)
    assert [(e.kind, e.request_id) for e in events] == [("finished", first), ("started", second)]
    events = sp.poll(100.0)
    assert [(e.kind, e.request_id) for e in events] == [("finished", second)]
    assert not sp.speaking
    wavs = sorted((tmp_path / "run").glob("*.wav"))
    assert len(wavs) == 2
    log = (tmp_path / "run" / Speaker.LOG_NAME).read_text().splitlines()
    assert len(log) == 3 and log[1].endswith("Please do not stay here. This area is restricted.")
    assert log[2].split("\t")[3] == wavs[1].name


def test_a_warning_s_camera_frame_is_logged_and_read_back(tmp_path):
    """The frame-to-warning latency: the speech log holds the stamp of the camera frame
    that caused a warning, the report's reader gives it back, a plain request has none."""
    from vigil.report.records import read_speech_log

    sp = Speaker(SpeechConfig(policy="queue"), tmp_path)
    sp.say(None, now_s=12.5, frame_stamp_s=12.25)
    sp.poll(12.6)
    sp.poll(100.0)
    sp.say("Hello.", now_s=101.0)
    sp.poll(101.0)
    got = read_speech_log(tmp_path / Speaker.LOG_NAME)
    assert [(u.t, u.frame_stamp_s) for u in got] == [(12.5, 12.25), (101.0, None)]
    assert got[1].text == "Hello."


def test_speaker_replace_policy_cuts_the_current_utterance(tmp_path):
    sp = Speaker(SpeechConfig(policy="replace"), tmp_path)
    first = sp.say(None, now_s=0.0)
    second = sp.say("Stop.", now_s=0.5)
    kinds = [(e.kind, e.request_id) for e in sp.poll(0.6)]
    assert kinds == [("started", first), ("replaced", first), ("started", second)]


def test_speaker_bad_requests_raise_and_it_keeps_working(tmp_path):
    sp = Speaker(SpeechConfig(), tmp_path)
    with pytest.raises(EmptyTextError):
        sp.say("", 0.0)
    with pytest.raises(UnknownVoiceError):
        sp.say("hello", 0.0, voice="xx-nope")
    sp.say("hello", 0.0, voice="pt")
    assert [e.kind for e in sp.poll(0.0)] == ["started"]
    with pytest.raises(UnknownVoiceError):
        Speaker(SpeechConfig(voice="xx-nope", warning_text="Hi."), tmp_path)


def test_config_defaults_and_validation():
    assert SpeechConfig().warning.startswith("Please")
    assert SpeechConfig(voice="pt").warning.startswith("Por favor")
    cfg = SpeechConfig.from_dict({"voice": "pt", "policy": "replace", "restricted_cells": [1, 12]})
    assert cfg.restricted_cells == (1, 12)
    with pytest.raises(ConfigError, match="speech.policy: 'shout' is invalid"):
        SpeechConfig.from_dict({"policy": "shout"})
    with pytest.raises(ConfigError, match="speech.warning_text: '' is invalid: must be given"):
        SpeechConfig.from_dict({"voice": "de"})


def test_warning_only_while_the_person_is_in_the_restricted_cell_with_the_robot():
    gate = WarningGate((1, 12), grace_s=2.0, repeat_s=8.0, confirm_s=0.5)
    assert gate.update(0.0, 7, 7, False) is None  # not a restricted cell
    assert gate.update(0.5, 1, 3, False) is None  # the person only near
    assert gate.update(1.0, 1, None, False) is None  # nobody
    assert gate.update(1.1, 1, 1, False) is None  # just seen in the cell: a border flicker?
    assert gate.update(1.2, 1, 3, False) is None  # it was
    assert gate.update(1.25, 1, 1, False) is None
    assert gate.update(1.5, 1, 1, False) is None
    assert gate.update(1.75, 1, 1, False) == "say"  # in the cell for 0.5 s
    assert gate.update(2.0, 1, 1, True) is None  # speaking: nothing queued
    assert gate.update(4.0, 1, 1, False) is None  # said 2.5 s ago: not again yet
    assert gate.update(9.6, 1, 1, False) == "say"  # still there after repeat_s
    assert gate.update(10.0, 1, None, True) is None  # left 0.4 s ago: let it finish
    assert gate.update(11.7, 1, None, True) == "stop"  # stale: cut, never played to nobody
    assert gate.update(12.0, 1, None, False) is None
    assert gate.update(13.0, 12, 12, False) is None
    assert gate.update(13.5, 12, 12, False) == "say"


def test_speech_refuses_a_text_longer_than_the_cap(tmp_path):
    speaker = Speaker(SpeechConfig(max_text_chars=40), tmp_path)
    with pytest.raises(SpeechError, match="max_text_chars"):
        speaker.say("x " * 100, 0.0)


def test_person_to_warn_with_one_and_several_people():
    from stack.nav.warning import person_to_warn

    # one person: the label itself (as before the people slots)
    assert person_to_warn("1", "1") == 1
    assert person_to_warn("1", "No person") is None
    assert person_to_warn("Unknown", "5") == 5
    # two people: the one in the robot's cell is warned even when slot 0 is elsewhere
    slots = [{"person": "4", "velocity": "Not moving"}, {"person": "12", "velocity": "x"}]
    assert person_to_warn("12", "4", slots) == 12
    assert person_to_warn("1", "4", slots) == 4  # nobody with the robot: the first seen
    assert person_to_warn("12", "No person", [{"person": "Unseen"}, "junk", {}]) is None


def test_a_person_walking_into_the_guarded_cell_is_warned_before_entering():
    """approaching(): the person in the next cell moving towards the robot's; the gate
    warns for it (after confirm_s), as it does for a person in the cell."""
    from stack.cells import CellGrid
    from stack.nav.warning import approaching

    g = CellGrid()  # 12 10 8 6 4 2 / 11 9 7 5 3 1
    assert approaching("1", "3", "East 0.2-0.7", g)  # 3 is west of 1
    assert approaching("1", "2", "South higher", g)  # 2 is north of 1
    assert not approaching("1", "3", "West 0.2-0.7", g)  # walking away
    assert not approaching("1", "4", "South higher", g)  # diagonal: not one step
    assert not approaching("1", "5", "East higher", g)  # two cells away
    assert not approaching("1", "3", "Not moving", g)  # standing at the border
    assert not approaching("Out of the map", "3", "East higher", g)
    assert not approaching("1", "No person", "Not moving", g)
    people = [{"person": "7", "velocity": "East higher"}, {"person": "3", "velocity": "East 0-0.2"}]
    assert approaching("1", "7", "East higher", g, people)  # the second person
    gate = WarningGate((1,), grace_s=2.0, repeat_s=8.0, confirm_s=0.5)
    assert gate.update(0.0, 1, 3, False, approaching=True) is None  # not confirmed yet
    assert gate.update(0.6, 1, 3, False, approaching=True) == "say"
    gate = WarningGate((1,), grace_s=2.0, repeat_s=8.0, confirm_s=0.5)
    assert gate.update(0.0, 7, 5, False, approaching=True) is None  # robot not in a restricted cell
    assert gate.update(0.6, 7, 5, False, approaching=True) is None


def test_the_reactor_reads_observation_records_as_the_node_and_the_loop_do():
    from stack.cells import CellGrid
    from stack.nav.config import SpeechConfig
    from stack.nav.warning import WarningReactor

    w = WarningReactor(CellGrid(), SpeechConfig(restricted_cells=(1,), confirm_s=0.5))
    w.observe({"robot": "1", "person": "3", "velocity": "East higher"})
    assert (w.robot_cell, w.person_cell, w.approaching) == (1, 3, True)
    assert w.decide(0.0, False) is None and w.decide(0.6, False) == "say"
    w.observe({"robot": "1", "person": "No person", "velocity": "Not moving"})
    assert w.person_cell is None and not w.approaching
    assert w.decide(4.0, True) == "stop"  # still speaking 3.4 s after: cut short
    people = [{"person": "7", "velocity": "East higher"}, {"person": "1", "velocity": "Not moving"}]
    two = {"robot": "1", "person": "7", "velocity": "East higher", "people": people}
    w.observe(two)
    assert w.person_cell == 1  # whoever is in the robot's cell
    with pytest.raises(KeyError):
        w.observe({"person": "3"})

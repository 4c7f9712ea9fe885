"""Spoken warnings through espeak-ng: WAV files, voices, errors, queue and replace."""

import shutil

import pytest

from stack.cells import CellGrid, ConfigError
from stack.nav.config import SpeechConfig
from stack.nav.speech import (
    EmptyTextError,
    EspeakNotFoundError,
    Speaker,
    UnknownVoiceError,
    should_warn,
    synthesize,
    wav_duration_s,
)

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


def test_should_warn_only_in_a_restricted_cell_with_the_person_near():
    grid = CellGrid()
    cfg = SpeechConfig(restricted_cells=(1, 12), near_cells=1)
    assert should_warn(grid, 1, 1, cfg)
    assert should_warn(grid, 1, 4, cfg)  # diagonal neighbour of 1
    assert not should_warn(grid, 1, 7, cfg)
    assert not should_warn(grid, 7, 7, cfg)
    assert not should_warn(grid, 12, None, cfg)
    assert not should_warn(grid, 12, 99, cfg)

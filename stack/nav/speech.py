"""Spoken warnings with espeak-ng (thesis 4.4: the robot tells the person not to stay).

Two layers:

- :func:`synthesize` turns one text into a WAV file (``espeak-ng -w``), checking the
  executable, the voice and the text first so that each failure has its own error;
- :class:`Speaker` keeps a queue of requests under a clock passed in, with the
  configured policy: a request while speaking is queued, or replaces the current
  utterance. With an output folder (the twin) each utterance is written as a WAV file
  plus a line in ``speech_log.tsv``; without one (the robot) espeak-ng plays it on the
  sound card and the utterance ends when that process exits.

Nothing here raises inside :meth:`Speaker.poll`: failures come back as events, so a node
keeps running.
"""

from __future__ import annotations

import functools
import shutil
import subprocess
import time
import wave
from collections import deque
from dataclasses import dataclass
from pathlib import Path

from stack.files import PrivateOutput, open_write, read_bytes_capped, write_bytes, write_text
from stack.nav.config import SpeechConfig


class SpeechError(RuntimeError):
    """Speaking failed; subclasses say why."""


class EspeakNotFoundError(SpeechError):
    """The espeak-ng executable is not installed or not on PATH."""


class UnknownVoiceError(SpeechError):
    """espeak-ng has no such voice."""


class EmptyTextError(SpeechError, ValueError):
    """There is nothing to say."""


@dataclass(frozen=True)
class Utterance:
    """One synthesised text.

    Attributes:
        text: what was said.
        voice: the espeak-ng voice.
        wav_path: the WAV file (None when played on the sound card).
        duration_s: audio length [s] (nan when played on the sound card, unknown).
        synth_s: wall time the synthesis took [s].
    """

    text: str
    voice: str
    wav_path: Path | None
    duration_s: float
    synth_s: float


def find_espeak(espeak_path: str = "espeak-ng") -> str:
    """Absolute path of the espeak-ng executable.

    Raises:
        EspeakNotFoundError: not found; the message says how to install it.
    """
    found = shutil.which(espeak_path)
    if found is None:
        raise EspeakNotFoundError(
            f"espeak-ng executable {espeak_path!r} not found; install the Debian package "
            "'espeak-ng' (scripts/setup.sh does) or set speech.espeak_path"
        )
    return found


@functools.lru_cache(maxsize=8)
def list_voices(espeak_path: str = "espeak-ng") -> frozenset[str]:
    """Every name espeak-ng accepts for ``-v``: languages (``en``, ``pt``, ``en-gb``),
    voice files (``gmw/en``) and their base names, voice names, and the
    "other languages" aliases (``en`` for ``en-gb``).

    Raises:
        EspeakNotFoundError: espeak-ng is missing.
        SpeechError: espeak-ng could not list its voices.
    """
    exe = find_espeak(espeak_path)
    try:
        out = subprocess.run(
            [exe, "--voices"], capture_output=True, text=True, timeout=10, check=True
        ).stdout
    except (subprocess.SubprocessError, OSError) as exc:
        raise SpeechError(f"{exe} --voices failed: {exc}") from exc
    names: set[str] = set()
    for line in out.splitlines()[1:]:
        parts = line.split()
        if len(parts) < 5:
            continue
        lang, name, file = parts[1], parts[3], parts[4]
        names.update({lang.lower(), name.lower(), file.lower(), file.rsplit("/", 1)[-1].lower()})
        for alias in parts[5:]:
            alias = alias.strip("()")
            if alias and not alias.isdigit():
                names.add(alias.lower())
    return frozenset(names)


def check_voice(voice: str, espeak_path: str = "espeak-ng") -> None:
    """Raise :class:`UnknownVoiceError` unless espeak-ng knows ``voice``.

    A variant suffix (``en+f3``) is allowed; only the part before ``+`` is checked.
    """
    base = voice.split("+", 1)[0].strip().lower()
    if not base or base not in list_voices(espeak_path):
        raise UnknownVoiceError(
            f"espeak-ng has no voice {voice!r}; try 'en' (English) or 'pt' (Portuguese), "
            f"or list them with `{espeak_path} --voices`"
        )


def _check_text(text: str | None) -> str:
    if text is None or not str(text).strip():
        raise EmptyTextError(f"nothing to say: text {text!r} is empty")
    if any(ord(c) < 32 and c not in "\t\n\r" for c in str(text)):
        raise SpeechError(f"text {str(text)[:40]!r} holds control characters")
    return " ".join(str(text).split())


def _espeak_args(exe: str, config: SpeechConfig, voice: str) -> list[str]:
    return [
        exe,
        "-v",
        voice,
        "-s",
        str(config.words_per_minute),
        "-p",
        str(config.pitch),
        "-a",
        str(config.amplitude),
    ]


def wav_duration_s(path: str | Path) -> float:
    """Length of a WAV file [s]."""
    with wave.open(str(path), "rb") as w:
        return w.getnframes() / float(w.getframerate())


def synthesize(
    text: str, wav_path: str | Path, config: SpeechConfig | None = None, voice: str | None = None
) -> Utterance:
    """Synthesise ``text`` into a WAV file.

    Args:
        text: what to say; surrounding and repeated whitespace is collapsed.
        wav_path: the WAV file to write (its folder must exist).
        config: speed, pitch, amplitude, executable and time bound (defaults if None).
        voice: espeak-ng voice; ``config.voice`` when None.

    Returns:
        The utterance, with the audio's duration.

    Raises:
        EmptyTextError: empty or blank text.
        EspeakNotFoundError: espeak-ng is missing.
        UnknownVoiceError: no such voice.
        SpeechError: espeak-ng failed or exceeded ``config.timeout_s``.
    """
    config = config or SpeechConfig()
    voice = voice or config.voice
    text = _check_text(text)
    exe = find_espeak(config.espeak_path)
    check_voice(voice, config.espeak_path)
    wav_path = Path(wav_path)
    t0 = time.perf_counter()
    # espeak-ng says the same words with the same settings into the same bytes: a
    # warning repeated (every episode of a study, every visit) is synthesised once
    key = (tuple(_espeak_args(exe, config, voice)), text)
    said = _SAID.get(key)
    if said is not None:
        with PrivateOutput(wav_path) as out:  # as espeak-ng's: moved into place when whole
            write_bytes(out.path, said[0])
        return Utterance(text, voice, wav_path, said[1], time.perf_counter() - t0)
    # espeak-ng -w opens the name and follows a link there: it writes into a folder of
    # its own, and the finished WAV is moved to wav_path (a link there is refused)
    with PrivateOutput(wav_path) as out:
        try:
            proc = subprocess.run(
                [*_espeak_args(exe, config, voice), "-w", str(out.path), "--", text],
                capture_output=True,
                text=True,
                timeout=config.timeout_s,
            )
        except subprocess.TimeoutExpired as exc:
            raise SpeechError(f"espeak-ng took longer than {config.timeout_s:g} s") from exc
        except OSError as exc:
            raise SpeechError(f"cannot run {exe}: {exc}") from exc
        synth_s = time.perf_counter() - t0
        if proc.returncode != 0:
            err = proc.stderr.strip()
            if "voice does not exist" in err:
                raise UnknownVoiceError(f"espeak-ng has no voice {voice!r}: {err}")
            raise SpeechError(f"espeak-ng exited with {proc.returncode}: {err}")
        try:
            duration = wav_duration_s(out.path)
            audio = read_bytes_capped(out.path)
        except (OSError, ValueError, wave.Error, EOFError) as exc:
            raise SpeechError(f"espeak-ng wrote no readable WAV at {wav_path}: {exc}") from exc
    if len(_SAID) >= SAID_KEPT:
        _SAID.clear()
    _SAID[key] = (audio, duration)
    return Utterance(text, voice, wav_path, duration, synth_s)


SAID_KEPT = 16  # texts whose audio a process keeps (a few warnings)
_SAID: dict[tuple[tuple[str, ...], str], tuple[bytes, float]] = {}


def forget_said() -> None:
    """Forget the audio this process kept: the next :func:`synthesize` of any text
    runs espeak-ng again (a benchmark of the synthesis itself)."""
    _SAID.clear()


@dataclass(frozen=True)
class SpeechEvent:
    """Something that happened to a request.

    Attributes:
        kind: "started", "finished", "replaced" (cut short by a newer request),
            "dropped" (queue full) or "failed".
        request_id: the id :meth:`Speaker.say` returned.
        text: the request's text.
        utterance: set for started/finished/replaced when synthesis succeeded.
        error: the failure's message for "failed" and "dropped".
    """

    kind: str
    request_id: int
    text: str
    utterance: Utterance | None = None
    error: str = ""


# speech_log.tsv: one line an utterance; frame_stamp_s empty unless a camera frame caused it
LOG_HEADER = "time_s\tvoice\tduration_s\twav\tframe_stamp_s\ttext\n"


def _last_clip(out_dir: Path | None) -> int:
    """The highest N of the ``utterance_NNNN.wav`` clips in ``out_dir`` (0 if none)."""
    if out_dir is None:
        return 0
    numbers = [0]
    for wav in out_dir.glob("utterance_*.wav"):
        digits = wav.stem.removeprefix("utterance_")
        if digits.isdigit():
            numbers.append(int(digits))
    return max(numbers)


@dataclass
class _Request:
    id: int
    text: str
    voice: str
    frame_stamp_s: float | None = None  # the camera frame that caused it (a warning)


class Speaker:
    """Speaks requests one at a time under the configured queue-or-replace policy.

    Args:
        config: voice, policy, queue bound and espeak-ng settings.
        out_dir: the run folder; when set, each utterance becomes
            ``utterance_NNNN.wav`` there and a line in ``speech_log.tsv``. When None,
            espeak-ng plays on the sound card.

    Raises:
        EspeakNotFoundError: espeak-ng is missing (checked once, at construction).
        UnknownVoiceError: the configured voice does not exist.
    """

    LOG_NAME = "speech_log.tsv"

    def __init__(self, config: SpeechConfig, out_dir: str | Path | None = None):
        self.config = config
        self.exe = find_espeak(config.espeak_path)
        check_voice(config.voice, config.espeak_path)
        self.out_dir = Path(out_dir) if out_dir is not None else None
        if self.out_dir is not None:
            self.out_dir.mkdir(parents=True, exist_ok=True)
            log = self.out_dir / self.LOG_NAME
            if not log.exists():
                write_text(log, LOG_HEADER)
        self._queue: deque[_Request] = deque()
        self._current: _Request | None = None
        self._current_utt: Utterance | None = None
        self._busy_until = 0.0
        self._proc: subprocess.Popen | None = None
        self._next_id = 1 + _last_clip(self.out_dir)  # a restarted node keeps its clips
        self._pending: list[SpeechEvent] = []

    @property
    def speaking(self) -> bool:
        return self._current is not None

    @property
    def queued(self) -> int:
        return len(self._queue)

    def say(
        self,
        text: str | None,
        now_s: float,
        voice: str | None = None,
        frame_stamp_s: float | None = None,
    ) -> int:
        """Request an utterance; it starts at once or on a later :meth:`poll`.

        Args:
            text: what to say (``config.warning`` when None).
            now_s: the current time [s].
            voice: a voice for this request only.
            frame_stamp_s: the stamp of the camera frame that caused it (a warning's
                observation), logged beside its start: the frame-to-warning latency.

        Returns:
            The request id, used in the events.

        Raises:
            EmptyTextError: blank text.
            UnknownVoiceError: unknown ``voice``.
        """
        text = _check_text(self.config.warning if text is None else text)
        if len(text) > self.config.max_text_chars:
            raise SpeechError(
                f"text of {len(text)} characters is longer than max_text_chars "
                f"({self.config.max_text_chars}): it would hold up a warning"
            )
        voice = voice or self.config.voice
        check_voice(voice, self.config.espeak_path)
        req = _Request(self._next_id, text, voice, frame_stamp_s)
        self._next_id += 1
        if self._current is not None and self.config.policy == "replace":
            self._queue.clear()
            self._stop_current("replaced")
        if len(self._queue) >= self.config.max_queue:
            self._pending.append(SpeechEvent("dropped", req.id, text, error="speech queue is full"))
            return req.id
        self._queue.append(req)
        self._advance(now_s)
        return req.id

    def poll(self, now_s: float) -> list[SpeechEvent]:
        """Advance: finish the current utterance when its time is up, start the next.

        Returns:
            The events since the last poll (or say), oldest first.
        """
        self._advance(now_s)
        events, self._pending = self._pending, []
        return events

    def stop(self) -> list[SpeechEvent]:
        """Cut the current utterance short and drop the queue."""
        self._queue.clear()
        if self._current is not None:
            self._stop_current("replaced")
        events, self._pending = self._pending, []
        return events

    # -- internals -----------------------------------------------------------
    def _stop_current(self, kind: str) -> None:
        assert self._current is not None
        if self._proc is not None and self._proc.poll() is None:
            self._proc.terminate()
            try:
                self._proc.wait(timeout=1.0)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait(timeout=1.0)
        self._pending.append(
            SpeechEvent(kind, self._current.id, self._current.text, self._current_utt)
        )
        self._current, self._current_utt, self._proc = None, None, None

    def _current_done(self, now_s: float) -> bool:
        if self._proc is not None:
            return self._proc.poll() is not None
        return now_s >= self._busy_until

    def _advance(self, now_s: float) -> None:
        if self._current is not None and self._current_done(now_s):
            if self._proc is not None and self._proc.returncode != 0:
                err = self._proc.stderr.read() if self._proc.stderr else ""
                self._pending.append(
                    SpeechEvent(
                        "failed",
                        self._current.id,
                        self._current.text,
                        error=f"espeak-ng exited with {self._proc.returncode}: {err.strip()}",
                    )
                )
                self._current, self._current_utt, self._proc = None, None, None
            else:
                self._stop_current("finished")
        while self._current is None and self._queue:
            self._start(self._queue.popleft(), now_s)

    def _start(self, req: _Request, now_s: float) -> None:
        try:
            if self.out_dir is None:
                utt = self._play(req)
            else:
                utt = self._write(req, now_s)
        except SpeechError as exc:
            self._pending.append(SpeechEvent("failed", req.id, req.text, error=str(exc)))
            return
        self._current, self._current_utt = req, utt
        self._busy_until = now_s + (utt.duration_s if self.config.emulate_playback else 0.0)
        self._pending.append(SpeechEvent("started", req.id, req.text, utt))

    def _write(self, req: _Request, now_s: float) -> Utterance:
        assert self.out_dir is not None
        wav = self.out_dir / f"utterance_{req.id:04d}.wav"
        utt = synthesize(req.text, wav, self.config, req.voice)
        with open_write(self.out_dir / self.LOG_NAME, "a") as log:
            frame = "" if req.frame_stamp_s is None else f"{req.frame_stamp_s:.3f}"
            log.write(
                f"{now_s:.3f}\t{utt.voice}\t{utt.duration_s:.3f}\t{wav.name}\t{frame}\t{utt.text}\n"
            )
        return utt

    def _play(self, req: _Request) -> Utterance:
        t0 = time.perf_counter()
        try:
            self._proc = subprocess.Popen(
                [*_espeak_args(self.exe, self.config, req.voice), "--", req.text],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.PIPE,
                text=True,
            )
        except OSError as exc:
            raise SpeechError(f"cannot run {self.exe}: {exc}") from exc
        return Utterance(req.text, req.voice, None, float("nan"), time.perf_counter() - t0)

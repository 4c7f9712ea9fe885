"""The base side's command timeout and gate watchdog (pure, no rclpy).

What must happen when the process that drives the base dies lives on the receiving
side: a SIGKILL, a segfault or the OOM killer skip any last zero the sender meant to
publish. The base (the twin's bridge, a real base driver) therefore keeps its own rule,
like ros2_controllers' diff_drive_controller ``cmd_vel_timeout`` (0.5 s by default):

- a command stands for at most ``cmd_timeout_s`` after it *arrived* (receipt time on
  the base's own clock: monotonic on hardware, simulated time in the twin); then the
  base gets zero velocity;
- with ``heartbeat_timeout_s`` set, a command stands only while the velocity gate's
  heartbeat (``/velocity_gate/heartbeat``, :data:`stack.topics.GATE_HEARTBEAT`) is
  fresh: a quiet gate (disarmed, or navigation idle) keeps beating, a dead one does
  not, so the base stops on a dead gate even before the command's own timeout.

Callers pass ``now_s`` from one clock that never runs backwards; a clock that does
(a bag rewound) simply makes every command stale.

Reasons (:attr:`BaseWatchdog.reason`): ``"no command"`` (none yet), ``"stale"``,
``"gate silent"``, ``"ok"``.
"""

from __future__ import annotations

import math

from stack.cells import ConfigError

ZERO = (0.0, 0.0, 0.0)
NO_COMMAND = "no command"
STALE = "stale"
GATE_SILENT = "gate silent"
OK = "ok"


def check_timeout(key: str, value: object, upper_s: float = math.inf) -> float:
    """A timeout in seconds: a finite number > 0 (and <= ``upper_s``).

    A NaN or infinite timeout would keep a command alive for ever, so it is refused.

    Raises:
        ConfigError: naming ``key``.
    """
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(key, value, "must be a number of seconds")
    v = float(value)
    if not (math.isfinite(v) and 0.0 < v <= upper_s):
        bound = f" and <= {upper_s:g}" if math.isfinite(upper_s) else ""
        raise ConfigError(key, value, f"must be finite, > 0{bound} [s]")
    return v


class BaseWatchdog:
    """Holds the last command and decides, at each control step, whether it stands.

    Args:
        cmd_timeout_s: how long a command stands after its receipt [s].
        heartbeat_timeout_s: how long the gate may stay silent [s]; None: not watched.
    """

    def __init__(self, cmd_timeout_s: float = 0.5, heartbeat_timeout_s: float | None = None):
        self.cmd_timeout_s = check_timeout("cmd_timeout_s", cmd_timeout_s)
        self.heartbeat_timeout_s = (
            None
            if heartbeat_timeout_s is None
            else check_timeout("heartbeat_timeout_s", heartbeat_timeout_s)
        )
        self._cmd = ZERO
        self._cmd_s = -math.inf
        self._beat_s = -math.inf
        self.reason = NO_COMMAND

    def command(self, cmd: tuple[float, float, float], now_s: float) -> None:
        """A command arrived at ``now_s`` (non-finite values are kept as zeros)."""
        self._cmd = tuple(float(v) if math.isfinite(v) else 0.0 for v in cmd)  # type: ignore[assignment]
        self._cmd_s = now_s

    @property
    def last_command(self) -> tuple[float, float, float]:
        """The last command that arrived (zeros: none yet)."""
        return self._cmd  # type: ignore[return-value]

    @property
    def last_command_s(self) -> float:
        """When the last command arrived (-inf: none yet)."""
        return self._cmd_s

    def heartbeat(self, now_s: float) -> None:
        """The gate's heartbeat arrived at ``now_s``."""
        self._beat_s = now_s

    def output(self, now_s: float) -> tuple[float, float, float]:
        """The command in force at ``now_s``: the last one, or zeros (see :attr:`reason`)."""
        if self._cmd_s == -math.inf:
            self.reason = NO_COMMAND
            return ZERO
        # a dead gate explains stale commands too: when both hold, the gate is named
        # (a loaded machine may look only after both timeouts have passed)
        if self.heartbeat_timeout_s is not None and not (
            0.0 <= now_s - self._beat_s <= self.heartbeat_timeout_s
        ):
            self.reason = GATE_SILENT
            return ZERO
        age = now_s - self._cmd_s
        if not (0.0 <= age <= self.cmd_timeout_s):  # stale, or a clock that ran backwards
            self.reason = STALE
            return ZERO
        self.reason = OK
        return self._cmd

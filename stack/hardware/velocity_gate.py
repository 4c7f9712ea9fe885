"""The velocity safety gate between navigation and the robot's base driver (pure, no rclpy).

In hardware mode the navigation node publishes on ``/nav/cmd_vel``; the gate forwards to
the driver only while an operator has armed it, caps the speeds whatever navigation
asks, and sends zeros when commands stop arriving (a crashed or stalled planner must not
leave the base running on its last command).

YAML section ``velocity_gate:`` (all keys optional)::

    velocity_gate:
      max_linear_mps: 0.3      # cap on the planar speed |(vx, vy)|; both scaled together [m/s]
      max_angular_radps: 0.6   # cap on |wz| [rad/s]
      cmd_timeout_s: 0.5       # a command older than this is stale: zeros [s]
      max_linear_accel_mps2: 0.5     # how fast the planar speed may grow [m/s^2]
      max_angular_accel_radps2: 1.5  # how fast |wz| may grow [rad/s^2]
      require_arming: true     # false: starts armed (an explicit disarm still holds)

Every cap must lie within the platform's limits (:data:`PLATFORM`, the MBot's): a
file asking for more is refused, not clipped, so that a typo never becomes a speed.

Acceleration: a command that speeds up (or turns the direction of travel) is slewed
from the last output by at most ``accel * dt`` (``dt`` since that output, at most
:data:`MAX_DT_S`); slowing down along the same direction, and every zero, pass at
once (stopping is never delayed).

Time: callers pass ``now_s`` from a monotonic clock (the node uses ``time.monotonic``),
never from ROS time, which a stalled ``/clock`` or ``use_sim_time`` would freeze.

Reasons (:attr:`GateState.reason`) for the current output: ``"not armed"``, ``"stale"``,
``"non-finite command"`` (all give zeros), ``"capped"`` (the command was scaled down,
by a speed cap or the acceleration limit) and ``"ok"`` (forwarded as given).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from stack.cells import ConfigError
from stack.config import Config

ZERO = (0.0, 0.0, 0.0)
NOT_ARMED = "not armed"
STALE = "stale"
NON_FINITE = "non-finite command"
CAPPED = "capped"
OK = "ok"
MAX_DT_S = 0.1  # the acceleration limit never grants more than this much time at once


@dataclass(frozen=True)
class PlatformLimits:
    """What the base can safely be asked for at most (MBot Mega: docs/HARDWARE.md)."""

    max_linear_mps: float = 0.8
    max_angular_radps: float = 3.0
    max_linear_accel_mps2: float = 2.0
    max_angular_accel_radps2: float = 6.0
    max_cmd_timeout_s: float = 1.0


PLATFORM = PlatformLimits()


@dataclass(frozen=True)
class GateConfig(Config):
    """Caps and timeout of the gate. Body frame: x forward, y left, z up (REP 103)."""

    section = "velocity_gate"  # errors name keys "velocity_gate.<field>"

    max_linear_mps: float = 0.3
    max_angular_radps: float = 0.6
    cmd_timeout_s: float = 0.5
    max_linear_accel_mps2: float = 0.5
    max_angular_accel_radps2: float = 1.5
    require_arming: bool = True

    def check(self) -> None:
        bounds = {
            "max_linear_mps": PLATFORM.max_linear_mps,
            "max_angular_radps": PLATFORM.max_angular_radps,
            "cmd_timeout_s": PLATFORM.max_cmd_timeout_s,
            "max_linear_accel_mps2": PLATFORM.max_linear_accel_mps2,
            "max_angular_accel_radps2": PLATFORM.max_angular_accel_radps2,
        }
        for name, bound in bounds.items():
            value = getattr(self, name)
            if not value > 0:
                raise ConfigError(name, value, "must be > 0")
            if value > bound:
                raise ConfigError(name, value, f"exceeds the platform's limit {bound:g}")


@dataclass(frozen=True)
class GateState:
    """What the gate does now: ``reason`` is one of the module's reasons."""

    armed: bool
    reason: str
    last_cmd_s: float  # when the last command arrived (-inf: none since arming) [s]


class VelocityGate:
    """Arming, caps and a command timeout; every output is a (vx, vy, wz) tuple."""

    def __init__(self, config: GateConfig | None = None):
        self.config = config or GateConfig()
        self._armed = not self.config.require_arming
        self._reason = OK if self._armed else NOT_ARMED
        self._last = ZERO
        self._last_s = -math.inf
        self._out = ZERO  # the last output, for the acceleration limit
        self._out_s = -math.inf

    @property
    def armed(self) -> bool:
        return self._armed

    @property
    def state(self) -> GateState:
        return GateState(self._armed, self._reason, self._last_s)

    def arm(self, armed: bool, now_s: float) -> tuple[float, float, float]:
        """Arm or disarm; returns the output now (always zeros).

        Arming forgets the last command: only a command that arrives after arming moves
        the base. Disarming holds until the next ``arm(True)``, even with
        ``require_arming: false``.
        """
        self._armed = bool(armed)
        self._last, self._last_s = ZERO, -math.inf
        self._out, self._out_s = ZERO, now_s
        self._reason = STALE if self._armed else NOT_ARMED
        return ZERO

    def command(self, vx: float, vy: float, wz: float, now_s: float) -> tuple[float, float, float]:
        """The output for a new command: capped, or zeros (not armed, non-finite)."""
        if not all(math.isfinite(v) for v in (vx, vy, wz)):
            # a broken command also cancels the previous one: stop rather than coast
            self._last, self._last_s, self._reason = ZERO, now_s, NON_FINITE
            self._out, self._out_s = ZERO, now_s
            return ZERO
        if not self._armed:
            self._reason = NOT_ARMED
            self._out, self._out_s = ZERO, now_s
            return ZERO
        vx, vy, wz = float(vx), float(vy), float(wz)
        cfg = self.config
        reason = OK
        speed = math.hypot(vx, vy)
        if speed > cfg.max_linear_mps:
            k = cfg.max_linear_mps / speed
            vx, vy, reason = vx * k, vy * k, CAPPED
        if abs(wz) > cfg.max_angular_radps:
            wz, reason = math.copysign(cfg.max_angular_radps, wz), CAPPED
        limited = self._accel_limited((vx, vy, wz), now_s)
        if limited != (vx, vy, wz):
            reason = CAPPED
        self._last, self._last_s, self._reason = limited, now_s, reason
        self._out, self._out_s = limited, now_s
        return self._last

    def _accel_limited(
        self, target: tuple[float, float, float], now_s: float
    ) -> tuple[float, float, float]:
        """``target`` slewed from the last output within the acceleration limits."""
        cfg = self.config
        dt = min(max(now_s - self._out_s, 0.0), MAX_DT_S)
        px, py, pw = self._out
        tx, ty, tw = target
        # planar: slowing along the same direction passes; anything else is slewed
        if not (math.hypot(tx, ty) <= math.hypot(px, py) and tx * px + ty * py >= 0):
            dx, dy = tx - px, ty - py
            step = math.hypot(dx, dy)
            room = cfg.max_linear_accel_mps2 * dt
            if step > room:
                tx, ty = px + dx * room / step, py + dy * room / step
        if not (abs(tw) <= abs(pw) and tw * pw >= 0):
            room = cfg.max_angular_accel_radps2 * dt
            if abs(tw - pw) > room:
                tw = pw + math.copysign(room, tw - pw)
        return (tx, ty, tw)

    def tick(self, now_s: float) -> tuple[float, float, float]:
        """The output in force at ``now_s``: zeros when not armed or the command is stale."""
        if not self._armed:
            self._reason = NOT_ARMED
            self._out, self._out_s = ZERO, now_s
            return ZERO
        if now_s - self._last_s > self.config.cmd_timeout_s:
            self._reason = STALE
            self._out, self._out_s = ZERO, now_s
            return ZERO
        return self._last

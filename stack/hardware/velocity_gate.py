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
      require_arming: true     # false: starts armed (an explicit disarm still holds)

Reasons (:attr:`GateState.reason`) for the current output: ``"not armed"``, ``"stale"``,
``"non-finite command"`` (all give zeros), ``"capped"`` (the command was scaled down) and
``"ok"`` (forwarded as given).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from stack.hardware._config import from_dict, positive

ZERO = (0.0, 0.0, 0.0)
NOT_ARMED = "not armed"
STALE = "stale"
NON_FINITE = "non-finite command"
CAPPED = "capped"
OK = "ok"


@dataclass(frozen=True)
class GateConfig:
    """Caps and timeout of the gate. Body frame: x forward, y left, z up (REP 103)."""

    max_linear_mps: float = 0.3
    max_angular_radps: float = 0.6
    cmd_timeout_s: float = 0.5
    require_arming: bool = True

    def __post_init__(self) -> None:
        for name in ("max_linear_mps", "max_angular_radps", "cmd_timeout_s"):
            positive(f"velocity_gate.{name}", getattr(self, name))

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None, prefix: str = "velocity_gate") -> GateConfig:
        """Validate a mapping (the ``velocity_gate`` section of a YAML file).

        Raises:
            stack.cells.ConfigError: unknown key, wrong type or a value out of range.
        """
        return from_dict(cls, data, prefix)


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
        self._reason = STALE if self._armed else NOT_ARMED
        return ZERO

    def command(self, vx: float, vy: float, wz: float, now_s: float) -> tuple[float, float, float]:
        """The output for a new command: capped, or zeros (not armed, non-finite)."""
        if not all(math.isfinite(v) for v in (vx, vy, wz)):
            # a broken command also cancels the previous one: stop rather than coast
            self._last, self._last_s, self._reason = ZERO, now_s, NON_FINITE
            return ZERO
        if not self._armed:
            self._reason = NOT_ARMED
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
        self._last, self._last_s, self._reason = (vx, vy, wz), now_s, reason
        return self._last

    def tick(self, now_s: float) -> tuple[float, float, float]:
        """The output in force at ``now_s``: zeros when not armed or the command is stale."""
        if not self._armed:
            self._reason = NOT_ARMED
            return ZERO
        if now_s - self._last_s > self.config.cmd_timeout_s:
            self._reason = STALE
            return ZERO
        return self._last

"""Constant-velocity Kalman tracking of laser people in the map frame (thesis 4.5, eq. 4.8).

The thesis read the person's velocity (v_x, v_y) from ROS's
``people_velocity_tracker`` and its speed as |v| = sqrt(v_x^2 + v_y^2) (4.8). Here
each person the laser sees is a track with state [x, y, v_x, v_y] in the map
frame, predicted with a constant-velocity model driven by white acceleration noise
and corrected with the legs' midpoint. Tracking in the map frame (the legs are
transformed with the robot's pose before they get here) keeps the robot's own
motion out of the person's velocity.

Association is greedy nearest-neighbour within a gate; a track is confirmed after
``min_hits`` updates and dropped after ``max_coast_s`` without one.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from stack.config import Config, require
from stack.perception.errors import BadScanError


@dataclass(frozen=True)
class TrackerConfig(Config):
    """Attributes:
    accel_noise_mps2: standard deviation of the person's acceleration, the process
        noise of the constant-velocity model [m/s^2].
        0.35: the pelvis of a walking person moves steadily, but the legs' midpoint
        surges and stalls with every step (from 0 to ~1.5 times the walking speed
        within a step, 0.5-1.3 s); with 1.0 the filter followed those surges and the
        speed class flickered (twin walks: 81 % right against 92 % with 0.35, see
        docs/PERCEPTION.md).
    measurement_sigma_m: noise of a leg-pair position [m].
    single_leg_sigma_m: noise of a lone leg standing for a person [m]: the person is
        up to half a stride from that leg, so a lone leg moves the track less than a
        pair (used when ``update`` is given the scan's ``PersonCandidate`` objects).
    initial_speed_sigma_mps: velocity uncertainty of a new track, per axis [m/s].
    gate_m: a detection farther than this from a track's prediction is not its [m].
    min_hits: updates before a track is confirmed.
    max_coast_s: a track without an update for longer is dropped [s].
    """

    section = "tracker"  # errors name keys "tracker.<field>"

    accel_noise_mps2: float = 0.35
    measurement_sigma_m: float = 0.08
    single_leg_sigma_m: float = 0.3
    initial_speed_sigma_mps: float = 1.0
    gate_m: float = 0.6
    min_hits: int = 3
    max_coast_s: float = 1.0

    def __post_init__(self) -> None:
        require(self.accel_noise_mps2 > 0, "accel_noise_mps2", self.accel_noise_mps2, "must be > 0")
        require(self.measurement_sigma_m > 0, "measurement_sigma_m", self.measurement_sigma_m,
                "must be > 0")  # fmt: skip
        require(self.initial_speed_sigma_mps > 0, "initial_speed_sigma_mps",
                self.initial_speed_sigma_mps, "must be > 0")  # fmt: skip
        require(self.single_leg_sigma_m > 0, "single_leg_sigma_m", self.single_leg_sigma_m,
                "must be > 0")  # fmt: skip
        require(self.gate_m > 0, "gate_m", self.gate_m, "must be > 0")
        require(self.min_hits >= 1, "min_hits", self.min_hits, "must be >= 1")
        require(self.max_coast_s > 0, "max_coast_s", self.max_coast_s, "must be > 0")


@dataclass(frozen=True)
class TrackEstimate:
    """A snapshot of one track.

    Attributes:
        track_id: stable identifier.
        position_m: (x, y) in the map frame [m].
        velocity_mps: (v_x, v_y) [m/s].
        speed_mps: |v| by eq. 4.8 [m/s].
        hits: updates received.
        last_update_s: time of the last update [s].
        confirmed: hits >= min_hits.
    """

    track_id: int
    position_m: tuple[float, float]
    velocity_mps: tuple[float, float]
    speed_mps: float
    hits: int
    last_update_s: float
    confirmed: bool


class ConstantVelocityKalman:
    """Kalman filter with state [x, y, v_x, v_y] and position measurements.

    Args:
        position_m: the first measurement [m].
        config: noise parameters.
    """

    _H = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])

    def __init__(self, position_m: tuple[float, float], config: TrackerConfig):
        self.config = config
        self.x = np.array([position_m[0], position_m[1], 0.0, 0.0])
        s_p, s_v = config.measurement_sigma_m, config.initial_speed_sigma_mps
        self.P = np.diag([s_p**2, s_p**2, s_v**2, s_v**2])
        self._R = np.eye(2) * s_p**2

    def predict(self, dt_s: float) -> None:
        """Propagate the state by ``dt_s`` seconds (white-noise acceleration model)."""
        if dt_s <= 0:
            return
        F = np.eye(4)
        F[0, 2] = F[1, 3] = dt_s
        q = self.config.accel_noise_mps2**2
        q11, q12, q22 = dt_s**3 / 3.0, dt_s**2 / 2.0, dt_s
        Q = q * np.array([[q11, 0, q12, 0], [0, q11, 0, q12], [q12, 0, q22, 0], [0, q12, 0, q22]])
        self.x = F @ self.x
        self.P = F @ self.P @ F.T + Q

    def update(self, z_m: tuple[float, float], sigma_m: float | None = None) -> None:
        """Correct the state with a position measurement [m].

        Args:
            z_m: the measured position [m].
            sigma_m: its noise [m]; None uses ``config.measurement_sigma_m``.
        """
        H = self._H
        R = self._R if sigma_m is None else np.eye(2) * sigma_m**2
        y = np.asarray(z_m, dtype=float) - H @ self.x
        S = H @ self.P @ H.T + R
        K = self.P @ H.T @ np.linalg.inv(S)
        self.x = self.x + K @ y
        # Joseph form keeps P symmetric positive definite.
        ikh = np.eye(4) - K @ H
        self.P = ikh @ self.P @ ikh.T + K @ R @ K.T

    @property
    def speed_mps(self) -> float:
        """|v| = sqrt(v_x^2 + v_y^2), eq. 4.8 [m/s]."""
        return float(math.hypot(self.x[2], self.x[3]))


class Track:
    """One person's track: its filter, its updates and their times (both trackers')."""

    def __init__(self, track_id: int, position_m: tuple[float, float], stamp_s: float, cfg):
        self.id = track_id
        self.kf = ConstantVelocityKalman(position_m, cfg)
        self.hits = 1
        self.last_update_s = stamp_s

    def correct(self, z_m: tuple[float, float], sigma_m: float | None, stamp_s: float) -> None:
        """The filter's update with a detection assigned to the track at ``stamp_s``."""
        self.kf.update(z_m, sigma_m)
        self.hits += 1
        self.last_update_s = stamp_s

    def estimate(self, min_hits: int) -> TrackEstimate:
        """The track's snapshot (confirmed after ``min_hits`` updates)."""
        x = self.kf.x
        return TrackEstimate(
            track_id=self.id,
            position_m=(float(x[0]), float(x[1])),
            velocity_mps=(float(x[2]), float(x[3])),
            speed_mps=self.kf.speed_mps,
            hits=self.hits,
            last_update_s=self.last_update_s,
            confirmed=self.hits >= min_hits,
        )


class TrackSet:
    """What every tracker of people does around its association (:class:`LegTracker`,
    and :class:`stack.perception.multi.MultiTracker` for several people): the live
    tracks and their ids, the latest stamp, predicting every track to a new stamp,
    starting a track for each detection no track took, and the snapshots."""

    def __init__(self) -> None:
        self._tracks: list[Track] = []
        self._next_id = 1
        self._stamp_s = -math.inf

    @property
    def stamp_s(self) -> float:
        """Time of the latest update [s] (-inf before the first)."""
        return self._stamp_s

    def _predict_to(self, stamp_s: float, what: str) -> None:
        """Predict every track to ``stamp_s``, the new latest stamp.

        Raises:
            BadScanError: a stamp not later than the previous one (``what``: "scan stamp").
        """
        if stamp_s <= self._stamp_s:
            raise BadScanError(f"{what} {stamp_s} is not after the previous {self._stamp_s}")
        dt = stamp_s - self._stamp_s if math.isfinite(self._stamp_s) else 0.0
        self._stamp_s = stamp_s
        for t in self._tracks:
            t.kf.predict(dt)

    def _start_tracks(
        self, zs: list[tuple[float, float]], used: set[int], stamp_s: float, cfg: TrackerConfig
    ) -> None:
        """A new track for every detection whose index is not in ``used``."""
        for i, z in enumerate(zs):
            if i not in used:
                self._tracks.append(Track(self._next_id, z, stamp_s, cfg))
                self._next_id += 1

    def _snapshots(self, min_hits: int) -> tuple[TrackEstimate, ...]:
        return tuple(t.estimate(min_hits) for t in self._tracks)


def measurements(
    detections: Iterable[Any], single_leg_sigma_m: float, default_sigma_m: float | None = None
) -> tuple[list[tuple[float, float]], list[float | None]]:
    """Positions and measurement sigmas of detections: a leg-pair detection (or a bare
    (x, y)) gets ``default_sigma_m``, a one-leg detection ``single_leg_sigma_m``."""
    meas: list[tuple[float, float]] = []
    sigmas: list[float | None] = []
    for p in detections:
        legs = getattr(p, "legs", None)
        x, y = getattr(p, "position_m", p)
        meas.append((float(x), float(y)))
        single = legs is not None and len(legs) == 1
        sigmas.append(single_leg_sigma_m if single else default_sigma_m)
    return meas, sigmas


class LegTracker(TrackSet):
    """Tracks the laser's people over successive scans.

    Args:
        config: filter and association parameters.
    """

    def __init__(self, config: TrackerConfig = TrackerConfig()):
        super().__init__()
        self.config = config

    def update(
        self, stamp_s: float, positions_m: Iterable[tuple[float, float] | Any]
    ) -> tuple[TrackEstimate, ...]:
        """Predict every track to ``stamp_s`` and correct it with the scan's people.

        Args:
            stamp_s: the scan's time [s]; must be later than the previous scan's.
            positions_m: the people found in the scan, map frame [m]: (x, y) pairs,
                or the scan's ``legs.PersonCandidate`` objects (``LegDetections.people``),
                whose lone legs then count with ``single_leg_sigma_m``.

        Returns:
            All live tracks after the update.

        Raises:
            BadScanError: a stamp not later than the previous scan's.
        """
        self._predict_to(stamp_s, "scan stamp")
        meas, sigmas = measurements(positions_m, self.config.single_leg_sigma_m)
        pairs = []
        for ti, t in enumerate(self._tracks):
            for mi, z in enumerate(meas):
                d = math.dist((t.kf.x[0], t.kf.x[1]), z)
                if d <= self.config.gate_m:
                    pairs.append((d, ti, mi))
        pairs.sort()
        used_t: set[int] = set()
        used_m: set[int] = set()
        for _, ti, mi in pairs:
            if ti in used_t or mi in used_m:
                continue
            used_t.add(ti)
            used_m.add(mi)
            self._tracks[ti].correct(meas[mi], sigmas[mi], stamp_s)
        self._start_tracks(meas, used_m, stamp_s, self.config)
        self._tracks = [
            t for t in self._tracks if stamp_s - t.last_update_s <= self.config.max_coast_s
        ]
        return self.tracks()

    def tracks(self) -> tuple[TrackEstimate, ...]:
        """Snapshots of the live tracks (at the latest scan's time)."""
        return self._snapshots(self.config.min_hits)


def nearest_track(
    tracks: Iterable[TrackEstimate],
    position_m: tuple[float, float],
    gate_m: float,
    confirmed_only: bool = True,
) -> TrackEstimate | None:
    """The track nearest a position (e.g. the camera's person), within a gate.

    Args:
        tracks: candidate tracks.
        position_m: where the camera puts the person [m].
        gate_m: farther tracks are someone (or something) else [m].
        confirmed_only: ignore tracks with too few updates.

    Returns:
        The nearest track, or None when none is within the gate.
    """
    best, best_d = None, gate_m
    for t in tracks:
        if confirmed_only and not t.confirmed:
            continue
        d = math.dist(t.position_m, position_m)
        if d <= best_d:
            best, best_d = t, d
    return best

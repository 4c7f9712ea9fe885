"""Several people at once (issue 16): multi-target tracking, camera-laser association
and the person slots the planner's observation is ordered by.

Pure (numpy, scipy), no rclpy. The pieces:

- :class:`MultiTracker`: tracks every person in the map frame over frames or scans.
  Each track is a constant-velocity Kalman filter (:class:`ConstantVelocityKalman`,
  the laser tracker's); every update predicts all tracks, then assigns detections to
  tracks as a whole (global nearest neighbour: the Hungarian method,
  ``scipy.optimize.linear_sum_assignment``) on the Mahalanobis distance of each
  detection from each track's predicted position, gated at ``gate_sigma``. As in
  leg_tracker (Leigh et al., ICRA 2015) an unmatched track coasts on its prediction
  and is dropped when unseen for ``max_coast_s`` or when its position uncertainty
  grows past ``max_position_sigma_m``; an unmatched detection starts a tentative
  track, confirmed after ``min_hits``. What keeps identities through a crossing is the
  prediction: two people walking through each other keep their velocities, so after
  the meeting each detection is nearest the prediction of the track that came from
  its side, and while they overlap (one merged detection) the other track coasts.
  Unlike leg_tracker's per-detection gate, the cost of a pair also carries the
  log-determinant of the innovation covariance (the negative log-likelihood), so a
  long-coasted, vague track does not steal a detection from a fresh one; and a
  detection that two confirmed, nearly coincident tracks could both take while only
  one gets it (two people overlapping in the image, one box) updates neither
  (``MultiTrackerConfig.merge_m``), so both coast through the merge on their own
  velocities.
- :func:`associate`: camera tracks to laser tracks, Hungarian on the Euclidean
  distance within a gate (the speed class of each camera person comes from its
  laser track, thesis 4.5, per person).
- :class:`stack.perception.slots.PersonSlots`: which track is "person 1", "person
  2", ... for the planner (the rules in :mod:`stack.perception.slots`).
- :class:`PeoplePerception`: the three together, the camera's part at each frame and
  the laser's when the observations node observes, giving one
  :class:`~stack.perception.slots.SlotPerson` per slot;
  :func:`stack.perception.slots.model_persons` turns them into the per-person
  observation ``FactoredModel.observation_index`` takes.

"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from stack.cells import CellGrid
from stack.config import Config, require
from stack.perception.direction import DirectionConfig, DirectionEstimator
from stack.perception.slots import PersonSlots, SlotConfig, SlotPerson
from stack.perception.tracker import (
    TrackerConfig,
    TrackEstimate,
    TrackSet,
    measurements,
)

_FAR = 1e6  # cost of a forbidden pair (outside the gate)


@dataclass(frozen=True)
class MultiTrackerConfig(Config):
    """Attributes:
    filter: the constant-velocity filter's noises (``TrackerConfig``: accel_noise_mps2,
        measurement_sigma_m, single_leg_sigma_m, initial_speed_sigma_mps); its
        ``min_hits`` and ``max_coast_s`` are this tracker's too.
    gate_sigma: a detection farther than this many standard deviations (Mahalanobis
        distance in the innovation covariance) from a track's prediction is not its.
        3.0: a 99 % gate for a 2-D Gaussian is 3.03.
    max_position_sigma_m: a track whose position standard deviation grows past this
        while coasting is dropped [m].
    merge_m: two confirmed tracks predicted closer than this, with a detection in both
        gates that only one of them gets, are people passing so close that the
        detector sees one of them (non-maximum suppression kept one box): the
        detection is ambiguous and neither track takes it, both coast on their
        velocities until they separate [m]. 0 turns the rule off. Without it the
        track that got the detections followed whichever person was in front, lost
        its velocity and swapped identities after long merges (bench/bench_people.py).
    """

    section = "multi_tracker"

    filter: TrackerConfig = TrackerConfig(measurement_sigma_m=0.15, min_hits=2, max_coast_s=1.5)
    gate_sigma: float = 3.0
    max_position_sigma_m: float = 1.0
    merge_m: float = 0.6

    def __post_init__(self) -> None:
        require(self.merge_m >= 0, "merge_m", self.merge_m, "must be >= 0")
        require(self.gate_sigma > 0, "gate_sigma", self.gate_sigma, "must be > 0")
        require(self.max_position_sigma_m > 0, "max_position_sigma_m",
                self.max_position_sigma_m, "must be > 0")  # fmt: skip


def gnn_assign(
    means: np.ndarray, covariances: np.ndarray, detections: np.ndarray, gate_sigma: float
) -> list[tuple[int, int]]:
    """Global nearest-neighbour assignment of detections to predicted tracks.

    Args:
        means: (T, 2) predicted track positions [m].
        covariances: (T, 2, 2) innovation covariances (position covariance + noise).
        detections: (D, 2) detected positions [m].
        gate_sigma: largest Mahalanobis distance of a pair.

    Returns:
        (track index, detection index) pairs, each index at most once, all in the gate;
        the pairs minimise the summed negative log-likelihood (Mahalanobis^2 + log det).
    """
    if len(means) == 0 or len(detections) == 0:
        return []
    cost = np.full((len(means), len(detections)), _FAR)
    for t in range(len(means)):
        inv = np.linalg.inv(covariances[t])
        logdet = math.log(max(np.linalg.det(covariances[t]), 1e-12))
        d = detections - means[t]
        m2 = np.einsum("ij,jk,ik->i", d, inv, d)
        ok = m2 <= gate_sigma**2
        cost[t, ok] = m2[ok] + logdet
    rows, cols = linear_sum_assignment(cost)
    return [(int(r), int(c)) for r, c in zip(rows, cols, strict=True) if cost[r, c] < _FAR]


class MultiTracker(TrackSet):
    """Every person over time, with identities kept by prediction and joint assignment.

    Args:
        config: filter, gate and lifetime parameters.
    """

    def __init__(self, config: MultiTrackerConfig = MultiTrackerConfig()):
        super().__init__()
        self.config = config

    def update(self, stamp_s: float, detections: Iterable) -> tuple[TrackEstimate, ...]:
        """Predict every track to ``stamp_s`` and correct them with the frame's people.

        Args:
            stamp_s: the frame's (or scan's) time [s]; must increase.
            detections: map positions (x, y) [m], or the scan's ``PersonCandidate``s
                (a lone leg counts with ``filter.single_leg_sigma_m``).

        Returns:
            All live tracks, oldest first.

        Raises:
            BadScanError: a stamp not later than the previous one.
        """
        cfg = self.config.filter
        self._predict_to(stamp_s, "stamp")
        zs, sigmas = measurements(detections, cfg.single_leg_sigma_m, cfg.measurement_sigma_m)
        z = np.array(zs, dtype=float).reshape(-1, 2)
        means = np.array([t.kf.x[:2] for t in self._tracks]).reshape(-1, 2)
        # innovation covariance with the nominal measurement noise (one gate per track)
        r = np.eye(2) * cfg.measurement_sigma_m**2
        covs = np.array([t.kf.P[:2, :2] + r for t in self._tracks]).reshape(-1, 2, 2)
        used = set()
        pairs = gnn_assign(means, covs, z, self.config.gate_sigma)
        ambiguous = self._ambiguous(pairs, means, covs, z)
        for ti, di in pairs:
            used.add(di)
            if di in ambiguous:
                continue
            self._tracks[ti].correct(zs[di], sigmas[di], stamp_s)
        self._start_tracks(zs, used, stamp_s, cfg)
        limit = self.config.max_position_sigma_m**2
        self._tracks = [
            t
            for t in self._tracks
            if stamp_s - t.last_update_s <= cfg.max_coast_s
            and max(t.kf.P[0, 0], t.kf.P[1, 1]) <= limit
        ]
        return self.tracks()

    def _ambiguous(
        self, pairs: list[tuple[int, int]], means: np.ndarray, covs: np.ndarray, z: np.ndarray
    ) -> set[int]:
        """Detections that ``merge_m`` makes ambiguous (see :class:`MultiTrackerConfig`)."""
        cfg = self.config
        if cfg.merge_m <= 0 or not pairs:
            return set()
        matched = {ti for ti, _ in pairs}
        confirmed = [t.hits >= cfg.filter.min_hits for t in self._tracks]
        out = set()
        for ti, di in pairs:
            if not confirmed[ti]:
                continue
            for other in range(len(self._tracks)):
                if other in matched or not confirmed[other]:
                    continue
                if float(np.linalg.norm(means[other] - means[ti])) > cfg.merge_m:
                    continue
                d = z[di] - means[other]
                if float(d @ np.linalg.inv(covs[other]) @ d) <= cfg.gate_sigma**2:
                    out.add(di)
        return out

    def correct(
        self, positions_m: Mapping[int, tuple[float, float]], sigma_m: float
    ) -> tuple[TrackEstimate, ...]:
        """Correct the tracks named in ``positions_m`` (track id -> map position [m])
        with another sensor's measurement at the latest update's time, ``sigma_m`` its
        standard deviation; a track the frame's detections already corrected is left
        alone. Returns all live tracks, as :meth:`update`."""
        for t in self._tracks:
            z = positions_m.get(t.id)
            if z is not None and t.last_update_s < self._stamp_s:
                t.correct(z, sigma_m, self._stamp_s)
        return self.tracks()

    def tracks(self) -> tuple[TrackEstimate, ...]:
        """Snapshots of the live tracks (at the latest update's time)."""
        return self._snapshots(self.config.filter.min_hits)


def associate(
    camera: Sequence[TrackEstimate],
    laser: Sequence[TrackEstimate],
    gate_m: float,
    confirmed_only: bool = True,
) -> dict[int, TrackEstimate]:
    """Laser tracks to camera tracks: one each, nearest overall, within ``gate_m``.

    Args:
        camera: the camera's people (tracks in the map frame).
        laser: the laser's people.
        gate_m: farther pairs are different people (or furniture) [m].
        confirmed_only: ignore unconfirmed laser tracks.

    Returns:
        camera track id -> its laser track (camera tracks without one are absent).
    """
    legs = [t for t in laser if t.confirmed or not confirmed_only]
    if not camera or not legs:
        return {}
    a = np.array([c.position_m for c in camera])
    b = np.array([t.position_m for t in legs])
    dist = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)
    cost = np.where(dist <= gate_m, dist, _FAR)
    rows, cols = linear_sum_assignment(cost)
    return {
        camera[r].track_id: legs[c] for r, c in zip(rows, cols, strict=True) if cost[r, c] < _FAR
    }


class PeoplePerception:
    """Camera detections and laser tracks in, one :class:`SlotPerson` per slot out.

    Args:
        grid: the cell geometry.
        slots: slot parameters (``slots`` = the task's ``people``).
        tracker: the camera tracks' parameters.
        direction: the per-person direction rule (None: ``DirectionConfig()``).
        leg_gate_m: a laser track within this of a camera person is that person's [m].
        laser_sigma_m: the standard deviation of a laser track's position, when it
            stands in for the camera (below) [m].
        laser_max_age_s: a laser track updated longer ago than this does not [s].

    A person the camera misses (the robot in front of their legs, HOG's runs of misses
    on a standing person) is not left to coast on their last velocity while the laser
    sees them: a camera track whose laser track (the one associated with it in the last
    frame the camera saw them) is still live and within ``leg_gate_m`` is corrected
    with the laser's position. A person who walked behind the robot and stopped is kept
    where they stand, not carried on past the wall and dropped. The identity rule keeps
    furniture out: a laser track takes over only for the person it was the legs of.
    While the camera is blind the observer feeds the laser's people to :meth:`track`
    in its place (:class:`stack.perception.observer.Observer`), so a person who comes in
    during an outage is tracked too. (One person:
    :class:`stack.perception.observation.ObservationCombiner`'s own rule, the laser
    alone where the camera cannot see.)
    """

    def __init__(
        self,
        grid: CellGrid,
        slots: SlotConfig = SlotConfig(),
        tracker: MultiTrackerConfig = MultiTrackerConfig(),
        direction: DirectionConfig | None = None,
        leg_gate_m: float = 1.0,
        laser_sigma_m: float = 0.1,
        laser_max_age_s: float = 0.3,
    ):
        self.grid = grid
        self.tracker = MultiTracker(tracker)
        self.slots = PersonSlots(slots, grid)
        self._direction_config = direction if direction is not None else DirectionConfig()
        self._directions: dict[int, DirectionEstimator] = {}
        self.leg_gate_m = leg_gate_m
        self.laser_sigma_m = laser_sigma_m
        self.laser_max_age_s = laser_max_age_s
        self._legs_of: dict[int, int] = {}  # camera track id -> its laser track's id
        self._seen: set[int] = set()  # the tracks the last frame's detections updated

    def update(
        self,
        stamp_s: float,
        positions_m: Iterable[tuple[float, float]],
        laser_tracks: Sequence[TrackEstimate] = (),
    ) -> tuple[SlotPerson, ...]:
        """One frame (:meth:`track`) and the laser's tracks then (:meth:`report`).

        Returns:
            One report per slot, slot 0 first.
        """
        self.track(stamp_s, positions_m)
        return self.report(laser_tracks)

    def track(self, stamp_s: float, positions_m: Iterable[tuple[float, float]]) -> None:
        """One camera frame: the camera's people (map positions) move the tracks, their
        directions and the slots on."""
        tracks = self.tracker.update(stamp_s, positions_m)
        self._seen = {t.track_id for t in tracks if t.last_update_s >= stamp_s}
        live = {t.track_id for t in tracks}
        for tid in list(self._directions):
            if tid not in live:
                del self._directions[tid]
        for t in tracks:
            est = self._directions.setdefault(
                t.track_id, DirectionEstimator(self._direction_config)
            )
            if t.track_id in self._seen:
                est.update(stamp_s, t.position_m)
        self._legs_of = {c: leg for c, leg in self._legs_of.items() if c in live}
        self.slots.assign(tracks)

    def report(self, laser_tracks: Sequence[TrackEstimate] = ()) -> tuple[SlotPerson, ...]:
        """The slots now, with the laser's latest tracks: each person's speed from the
        laser track associated with them, and a person the last frame missed kept by
        their own laser track (see the class doc). The observations node calls it when
        it observes, not at each camera frame, so the laser tracks it uses are those of
        the observation instant whatever order the camera's and the laser's messages
        came in (the lock-step replay and the in-process loop agree).

        Returns:
            One report per slot, slot 0 first.
        """
        stamp_s = self.tracker.stamp_s
        tracks = self._laser_keeps(stamp_s, self.tracker.tracks(), laser_tracks)
        by_id = {t.track_id: t for t in tracks}
        legs = associate(tracks, laser_tracks, self.leg_gate_m)
        # a person's legs are learnt while the camera sees them: a coasting track does
        # not take up the laser track it drifts past (furniture, another person)
        self._legs_of.update({c: leg.track_id for c, leg in legs.items() if c in self._seen})
        out = []
        for k, tid in enumerate(self.slots.track_ids):
            slot = by_id.get(tid) if tid is not None else None
            if slot is None:
                out.append(SlotPerson(k))
                continue
            leg = legs.get(slot.track_id)
            out.append(
                SlotPerson(
                    slot=k,
                    track_id=slot.track_id,
                    position_m=slot.position_m,
                    cell=self.grid.cell_at(*slot.position_m),
                    direction=self._directions[slot.track_id].direction,
                    speed_mps=None if leg is None else leg.speed_mps,
                    laser_track_id=None if leg is None else leg.track_id,
                    measured=slot.last_update_s >= stamp_s,
                )
            )
        return tuple(out)

    def _laser_keeps(
        self,
        stamp_s: float,
        tracks: tuple[TrackEstimate, ...],
        laser_tracks: Sequence[TrackEstimate],
    ) -> tuple[TrackEstimate, ...]:
        """The camera tracks the frame missed, corrected with their own laser track's
        position where it is live and near (see the class doc)."""
        laser = {
            t.track_id: t
            for t in laser_tracks
            if t.confirmed and stamp_s - t.last_update_s <= self.laser_max_age_s
        }
        aids = {}
        for t in tracks:
            if t.last_update_s >= stamp_s:
                continue  # the camera saw them
            leg = laser.get(self._legs_of.get(t.track_id, -1))
            if leg is not None and math.dist(leg.position_m, t.position_m) <= self.leg_gate_m:
                aids[t.track_id] = leg.position_m
        return self.tracker.correct(aids, self.laser_sigma_m) if aids else tracks

"""The camera side of perception: frames in, the person's cell and direction out.

Per frame: HOG boxes (:mod:`stack.perception.hog`), each box's foot pixel
(figure 4.9), its floor position through the homography (eqs. 4.4-4.7), its cell
(:class:`stack.cells.CellGrid`), and the movement direction compared frame by
frame (:mod:`stack.perception.direction`). With several boxes, the one nearest the
person's last position is kept (else the strongest).

A box too short for a person standing at its foot point (the camera implied by the
homography, ``CameraConfig.short_box_ratio``) is HOG's window fitted tightly around
the person, its bottom at the knees: its feet are looked for in the
background-subtraction mask below it.

The two-missed-frames rule (thesis 4.5): a person not detected in two consecutive
frames means no person, direction "Not moving", and the laser is ignored. One
missed frame keeps the last position and direction.

Bad input never invents a position: a bad frame counts as a missed frame and its
state carries a warning; after two of them the status is ``UNKNOWN`` (the camera
cannot tell), which the observation combiner reports as "No person". A frame whose
stamp is not newer than the last one (a frozen camera) is not processed again.
Without a calibration, boxes are still reported but the status is ``UNKNOWN``.

Several people (issue 16): every state also lists all the frame's people
(``people_m``, after non-maximum suppression) for ``stack.perception.multi``; the
chosen person and the rules above are unchanged. The module is over 500 lines
because the one-person rules and the all-people list share one pass over the
candidate boxes and one configuration; splitting them would duplicate that pass.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from stack.cells import CellGrid, Direction
from stack.config import Config, require
from stack.perception.direction import DirectionConfig, DirectionEstimator
from stack.perception.errors import BadFrameError
from stack.perception.hog import (
    FootConfig,
    Foreground,
    HogConfig,
    HogPeopleDetector,
    PersonBox,
    foot_point,
    non_max_suppression,
    validate_frame,
)
from stack.perception.homography import FloorHomography


class PersonStatus(enum.Enum):
    """What the camera says about the person."""

    PERSON = "person"  # seen (or missed in one frame only)
    NO_PERSON = "no person"  # not detected in `missed_frames_no_person` consecutive frames
    UNKNOWN = "unknown"  # the camera cannot tell: bad frames or no calibration


@dataclass(frozen=True)
class CameraConfig(Config):
    """Attributes:
    hog: detector parameters.
    foot: box shrink and foot refinement.
    direction: movement direction threshold and window.
    missed_frames_no_person: consecutive frames without a detection that mean
        "no person" (thesis: 2).
    association_gate_m: a box farther than this from the last position is a
        different person (or a false positive) [m].
    black_max_level: frames whose brightest pixel is at or below this are black.
    use_foreground: refine the foot row of every box with the foreground mask
        (``FootConfig``; short boxes are refined anyway, see ``short_box_ratio``).
        Off: for every box (search widened to 0.6 box heights) it fixed the
        north-south walk but put the feet of a person walking east-west too low
        (median 0.08 -> 0.19 m); see docs/PERCEPTION.md.
    track_roi_margin_frac: while a person is tracked, search only their last box
        grown by this fraction of its size on every side (0: always the full
        configured area); nothing found there falls back to the full search.
    full_search_period_frames: with the tracking window, search the full area every
        this many frames anyway (another person, a wrong track).
    nested_box_frac: a box with at least this fraction of its area inside a taller
        box is dropped: HOG also fires on a person's upper body, whose box bottom
        sits at the knees and puts the person metres too far (twin walks).
    box_top_height_m: (low, high) height above its foot point that a box's top row
        may see [m], from the camera implied by the homography
        (``FloorHomography.height_at_row_m``; needs the calibration's image size):
        the HOG box of a 1.4-2.1 m person tops out at about 1.6-2.6 m; a box outside
        is not a person standing there. None (default): no check; in the twin
        walks (1.6, 2.6) dropped 20 % of the wrong boxes and 3 % of the right ones,
        too few to pay.
    max_foreground_frac: a foreground mask covering more than this fraction of the
        frame (the first frames, a light switched) is not used for the feet.
    person_height_m: the height assumed for the person when judging a box's size [m].
    short_box_ratio: a box whose height is less than this multiple of the image
        height of a ``person_height_m`` person standing at its foot point (the
        camera implied by the homography, ``FloorHomography.row_of_point_px``; needs
        the calibration's image size) is "short": HOG's window fitted tightly around
        the person instead of with its margins (a full-body box is 1.33-1.46 times
        the person in the twin walks, these 0.99-1.34; seen side-on, walking
        north-south), so its shrunk bottom sits at the knees and the floor point
        lies 0.6-1.9 m too far. Only a short box's foot row is refined with the
        foreground, searched down to ``short_box_search_frac`` box heights below the
        box; without a usable mask the box is kept as it is. None: no check and no
        background model (unless ``use_foreground``).
    short_box_search_frac: how far below a short box the foreground search for the
        feet goes [box heights].
    foreground_downscale: the background model (MOG2) runs on the frame resized by
        this factor (0.5: about 2-4 ms per 640 x 400 frame instead of 9-12).
    max_people: people the camera looks for (issue 16). 1: the thesis's one person,
        searched in a window round the tracked box. More: every frame is searched
        whole (the window would hide the others); either way
        ``CameraPersonState.people_m`` lists every person of the frame.
    nms_iou: two boxes overlapping by more than this (intersection over union), or
        one inside the other by ``nested_box_frac``, are one person in ``people_m``
        (``hog.non_max_suppression``).
    """

    section = "camera"  # errors name keys "camera.<field>"

    hog: HogConfig = field(default_factory=HogConfig)
    foot: FootConfig = field(default_factory=FootConfig)
    direction: DirectionConfig = field(default_factory=DirectionConfig)
    missed_frames_no_person: int = 2
    association_gate_m: float = 1.0
    black_max_level: float = 3.0
    use_foreground: bool = False
    track_roi_margin_frac: float = 0.5
    full_search_period_frames: int = 10
    nested_box_frac: float = 0.8
    box_top_height_m: tuple[float, float] | None = None
    max_foreground_frac: float = 0.3
    person_height_m: float = 1.75
    short_box_ratio: float | None = 1.3
    short_box_search_frac: float = 0.6
    foreground_downscale: float = 0.5
    max_people: int = 1
    nms_iou: float = 0.4

    def __post_init__(self) -> None:
        require(self.max_people >= 1, "max_people", self.max_people, "must be >= 1")
        require(0.0 < self.nms_iou <= 1.0, "nms_iou", self.nms_iou, "must be in (0, 1]")
        require(self.person_height_m > 0.0, "person_height_m", self.person_height_m,
                "must be > 0")  # fmt: skip
        if self.short_box_ratio is not None:
            require(self.short_box_ratio > 0.0, "short_box_ratio", self.short_box_ratio,
                    "must be > 0 (or null: no check)")  # fmt: skip
        require(self.short_box_search_frac >= 0.0, "short_box_search_frac",
                self.short_box_search_frac, "must be >= 0")  # fmt: skip
        require(0.0 < self.foreground_downscale <= 1.0, "foreground_downscale",
                self.foreground_downscale, "must be in (0, 1]")  # fmt: skip
        require(0.0 < self.max_foreground_frac <= 1.0, "max_foreground_frac",
                self.max_foreground_frac, "must be in (0, 1]")  # fmt: skip
        require(0.0 < self.nested_box_frac <= 1.0, "nested_box_frac", self.nested_box_frac,
                "must be in (0, 1]")  # fmt: skip
        if self.box_top_height_m is not None:
            lo, hi = self.box_top_height_m
            require(0.0 < lo < hi, "box_top_height_m", self.box_top_height_m,
                    "needs 0 < low < high")  # fmt: skip
        require(self.missed_frames_no_person >= 1, "missed_frames_no_person",
                self.missed_frames_no_person, "must be >= 1")  # fmt: skip
        require(self.association_gate_m > 0.0, "association_gate_m", self.association_gate_m,
                "must be > 0")  # fmt: skip
        require(0.0 <= self.black_max_level < 255.0, "black_max_level", self.black_max_level,
                "must be in [0, 255)")  # fmt: skip
        require(self.track_roi_margin_frac >= 0.0, "track_roi_margin_frac",
                self.track_roi_margin_frac, "must be >= 0")  # fmt: skip
        require(self.full_search_period_frames >= 1, "full_search_period_frames",
                self.full_search_period_frames, "must be >= 1")  # fmt: skip


@dataclass(frozen=True)
class CameraPersonState:
    """The camera's view of the person after one frame.

    Attributes:
        stamp_s: the frame's time [s].
        status: person / no person / unknown.
        position_m: (x', y') on the floor map [m]; None unless status is PERSON.
        cell: the cell containing ``position_m``; None outside the region or no person.
        direction: movement direction; NOT_MOVING unless a person is seen moving.
        foot_px: (u, v) of the chosen box's foot point [px].
        box: the chosen detection.
        boxes: every detection of the frame, for display.
        missed_frames: consecutive frames without a usable detection.
        warning: why the frame was not usable, if it was not.
        people_m: every person of the frame on the floor map [m] (one per box after
            non-maximum suppression, strongest first; issue 16), for a multi-person
            tracker (``stack.perception.multi``); not filtered by the missed-frames rule.
        people_boxes: their boxes, in the same order.
    """

    stamp_s: float
    status: PersonStatus
    position_m: tuple[float, float] | None = None
    cell: int | None = None
    direction: Direction = Direction.NOT_MOVING
    foot_px: tuple[float, float] | None = None
    box: PersonBox | None = None
    boxes: tuple[PersonBox, ...] = ()
    missed_frames: int = 0
    warning: str | None = None
    people_m: tuple[tuple[float, float], ...] = ()
    people_boxes: tuple[PersonBox, ...] = ()

    def people_to_dict(self) -> dict[str, Any]:
        """The frame's people, JSON-ready (``people_m`` and their boxes)."""
        return {
            "stamp_s": self.stamp_s,
            "people_m": [list(p) for p in self.people_m],
            "people_boxes": [
                [b.x, b.y, b.width, b.height, round(b.weight, 3)] for b in self.people_boxes
            ],
        }

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (labels as strings) for messages and logs."""
        return {
            "stamp_s": self.stamp_s,
            "status": self.status.value,
            "position_m": None if self.position_m is None else list(self.position_m),
            "cell": self.cell,
            "direction": self.direction.label,
            "foot_px": None if self.foot_px is None else list(self.foot_px),
            "boxes": [[b.x, b.y, b.width, b.height, round(b.weight, 3)] for b in self.boxes],
            "missed_frames": self.missed_frames,
            "warning": self.warning,
        }

    def silent_dict(self, silent_s: float) -> dict[str, Any]:
        """The record a camera that sent no frame for ``silent_s`` publishes (the frame
        watchdog): status unknown, no position, cell or boxes, and why."""
        return {
            **self.to_dict(),
            "status": PersonStatus.UNKNOWN.value,
            "position_m": None,
            "cell": None,
            "direction": Direction.NOT_MOVING.label,
            "boxes": [],
            "warning": f"no camera frame for {silent_s:.1f} s",
        }


class CameraPeopleTracker:
    """Frames in, :class:`CameraPersonState` out, applying the two-missed-frames rule.

    Args:
        config: the camera pipeline's parameters.
        grid: the cell geometry shared with the planner.
        homography: the image-to-floor mapping; None when the calibration is missing
            (states are then UNKNOWN, with the boxes still reported).
        detector: a detector to reuse (built from ``config.hog`` when None).
    """

    def __init__(
        self,
        config: CameraConfig,
        grid: CellGrid,
        homography: FloorHomography | None,
        detector: HogPeopleDetector | None = None,
    ):
        self.config = config
        self.grid = grid
        self.homography = homography
        self.detector = detector if detector is not None else HogPeopleDetector(config.hog)
        wants_mask = config.use_foreground or config.short_box_ratio is not None
        self._foreground = Foreground(downscale=config.foreground_downscale) if wants_mask else None
        self._short_foot = replace(
            config.foot,
            use_foreground=True,
            search_below_frac=config.short_box_search_frac,
            max_refine_frac=config.short_box_search_frac + config.foot.bottom_shrink_frac,
        )
        self._direction = DirectionEstimator(config.direction)
        self._state = CameraPersonState(stamp_s=-math.inf, status=PersonStatus.NO_PERSON)
        self._missed = 0
        self._since_full = 0

    @property
    def state(self) -> CameraPersonState:
        """The state after the latest processed frame."""
        return self._state

    def process_frame(self, image: Any, stamp_s: float) -> CameraPersonState:
        """Detect, place and track the person in one frame.

        Args:
            image: 8-bit grey or BGR frame.
            stamp_s: its capture time [s].

        Returns:
            The new state; for a repeated (frozen) stamp the previous state with a
            warning; for a bad frame a missed-frame state with a warning.
        """
        if stamp_s <= self._state.stamp_s:
            return replace(
                self._state, warning=f"frozen frame: stamp {stamp_s} repeats or goes back"
            )
        try:
            image = validate_frame(image, self.config.black_max_level)
        except BadFrameError as err:
            return self._missed_frame(stamp_s, (), bad=str(err))
        mask = self._foreground.apply(image) if self._foreground is not None else None
        if mask is not None and mask.mean() > self.config.max_foreground_frac:
            mask = None  # the model is still learning, or the whole scene changed
        boxes: tuple[PersonBox, ...] = ()
        window = self._tracking_window(image.shape) if self.config.max_people == 1 else None
        if window is not None:
            boxes = self.detector.detect(image, roi_px=window)
            self._since_full += 1
        if not boxes:  # no track, nothing in the window, or time for a full search
            boxes = self.detector.detect(image)
            self._since_full = 0
        size = (image.shape[1], image.shape[0])
        every = mask if self.config.use_foreground else None  # else for short boxes only
        return self._update(boxes, stamp_s, size, every, mask)

    def update(
        self,
        boxes: tuple[PersonBox, ...],
        stamp_s: float,
        image_size_px: tuple[int, int] | None = None,
        foreground: np.ndarray | None = None,
    ) -> CameraPersonState:
        """Track the person from one frame's detections (the logic after HOG).

        Args:
            boxes: the frame's detections in pixels.
            stamp_s: the frame's time [s]; must increase.
            image_size_px: (width, height) of the frame; when the calibration was
                made at another resolution the foot pixels are rescaled.
            foreground: optional boolean mask of moving pixels: refines every box's
                foot row as ``FootConfig`` says, and short boxes'
                (``CameraConfig.short_box_ratio``) over the wider search. (The mask
                ``process_frame`` makes goes to short boxes only, unless
                ``use_foreground``.)

        Returns:
            The new state.
        """
        return self._update(tuple(boxes), stamp_s, image_size_px, foreground, foreground)

    # -- internals ----------------------------------------------------------
    def _update(
        self,
        boxes: tuple[PersonBox, ...],
        stamp_s: float,
        image_size_px: tuple[int, int] | None,
        foreground: np.ndarray | None,
        short_mask: np.ndarray | None,
    ) -> CameraPersonState:
        """``update`` with a mask for every box's foot (``FootConfig``) and one for short boxes."""
        if stamp_s <= self._state.stamp_s:
            return replace(
                self._state, warning=f"frozen frame: stamp {stamp_s} repeats or goes back"
            )
        boxes = tuple(boxes)
        if self.homography is None:
            self._missed = 0
            self._direction.reset()
            self._state = CameraPersonState(
                stamp_s=stamp_s, status=PersonStatus.UNKNOWN, boxes=boxes,
                warning="no floor calibration: person position unknown",
            )  # fmt: skip
            return self._state
        candidates = []
        cfg = self.config
        for box in _drop_nested(boxes, cfg.nested_box_frac):
            u, v = foot_point(box, cfg.foot, foreground)
            pos = self._to_map(u, v, image_size_px)
            if short_mask is not None and pos is not None and self._short(box, pos, image_size_px):
                # A tight (knee-high) box: look for the feet in the mask below it.
                refined = foot_point(box, self._short_foot, short_mask)
                if refined != foot_point(box, self._short_foot):  # the mask found the feet
                    u, v = refined
                    pos = self._to_map(u, v, image_size_px)
            if pos is not None and self._plausible(box, pos, image_size_px):
                candidates.append((box, (u, v), pos))
        people = _suppress(candidates, cfg.nms_iou, cfg.nested_box_frac)
        return self._track(candidates, people, stamp_s, boxes)

    def message(self, state: CameraPersonState) -> dict[str, Any]:
        """The camera people node's message of ``state`` (:meth:`CameraPersonState.to_dict`,
        with every person's floor point, ``people_m``, when it tracks several)."""
        out = state.to_dict()
        if self.config.max_people > 1:  # several people (issue 16): all of them
            out["people_m"] = [list(q) for q in state.people_m]
        return out

    def update_points(
        self, points_m: tuple[tuple[float, float], ...], stamp_s: float
    ) -> CameraPersonState:
        """Track the person from one frame's people given as floor points [m] (strongest
        first), not boxes: the same rules (association gate, two missed frames,
        direction, cell) as :meth:`update`. This is how a model of the detector
        (:mod:`stack.perception.model`) feeds the tracker; the state has no boxes.
        """
        if stamp_s <= self._state.stamp_s:
            return replace(
                self._state, warning=f"frozen frame: stamp {stamp_s} repeats or goes back"
            )
        candidates = [(None, None, (float(x), float(y))) for x, y in points_m]
        return self._track(candidates, candidates, stamp_s, ())

    def _track(
        self, candidates: list, people: list, stamp_s: float, boxes: tuple[PersonBox, ...]
    ) -> CameraPersonState:
        """The tracking rules on one frame's (box, foot, position) candidates."""
        chosen = self._choose(candidates)
        if chosen is None:  # no candidates: nobody in people_m either
            return self._missed_frame(stamp_s, boxes, bad=None)
        box, foot, pos = chosen
        self._missed = 0
        direction = self._direction.update(stamp_s, pos)
        self._state = CameraPersonState(
            stamp_s=stamp_s,
            status=PersonStatus.PERSON,
            position_m=pos,
            cell=self.grid.cell_at(*pos),
            direction=direction,
            foot_px=foot,
            box=box,
            boxes=boxes,
            people_m=tuple(c[2] for c in people),
            people_boxes=tuple(c[0] for c in people if c[0] is not None),
        )
        return self._state

    def _tracking_window(self, shape: tuple[int, ...]) -> tuple[int, int, int, int] | None:
        """The search window around the tracked person's last box, or None for a full search."""
        cfg, state = self.config, self._state
        if (
            cfg.track_roi_margin_frac <= 0.0
            or state.status is not PersonStatus.PERSON
            or state.box is None
            or state.missed_frames > 0
            or self._since_full + 1 >= cfg.full_search_period_frames
        ):
            return None
        b, m = state.box, cfg.track_roi_margin_frac
        x0, y0 = b.x - m * b.width, b.y - m * b.height
        return (round(x0), round(y0), round(b.width * (1 + 2 * m)), round(b.height * (1 + 2 * m)))

    def _to_map(
        self, u: float, v: float, image_size_px: tuple[int, int] | None
    ) -> tuple[float, float] | None:
        assert self.homography is not None
        cal_size = self.homography.image_size_px
        if image_size_px is not None and cal_size is not None and image_size_px != cal_size:
            u *= cal_size[0] / image_size_px[0]
            v *= cal_size[1] / image_size_px[1]
        return self.homography.image_to_map(u, v)

    def _short(
        self, box: PersonBox, pos: tuple[float, float], image_size_px: tuple[int, int] | None
    ) -> bool:
        """Whether the box is too short for a person standing at its foot point."""
        ratio = self.config.short_box_ratio
        assert self.homography is not None
        if ratio is None:
            return False
        hom = self.homography
        v_foot = hom.row_of_point_px(pos[0], pos[1], 0.0)
        v_head = hom.row_of_point_px(pos[0], pos[1], self.config.person_height_m)
        if v_foot is None or v_head is None or v_foot - v_head <= 0.0:
            return False
        height = float(box.height)
        cal_size = hom.image_size_px
        if image_size_px is not None and cal_size is not None and image_size_px != cal_size:
            height *= cal_size[1] / image_size_px[1]
        return height < ratio * (v_foot - v_head)

    def _plausible(
        self, box: PersonBox, pos: tuple[float, float], image_size_px: tuple[int, int] | None
    ) -> bool:
        """Whether the box's top is at a person's height above its floor point."""
        limits = self.config.box_top_height_m
        assert self.homography is not None
        if limits is None:
            return True
        v_top = float(box.y)
        cal_size = self.homography.image_size_px
        if image_size_px is not None and cal_size is not None and image_size_px != cal_size:
            v_top *= cal_size[1] / image_size_px[1]
        z = self.homography.height_at_row_m(pos[0], pos[1], v_top)
        return z is None or limits[0] <= z <= limits[1]

    def _choose(self, candidates: list) -> tuple | None:
        if not candidates:
            return None
        last = self._state.position_m if self._state.status is PersonStatus.PERSON else None
        if last is None:
            return candidates[0]  # boxes come strongest first
        dist = [math.dist(c[2], last) for c in candidates]
        i = int(np.argmin(dist))
        if dist[i] <= self.config.association_gate_m:
            return candidates[i]
        # Nothing near the tracked person: a jump means a new person; direction restarts.
        self._direction.reset()
        return candidates[0]

    def _missed_frame(
        self, stamp_s: float, boxes: tuple[PersonBox, ...], bad: str | None
    ) -> CameraPersonState:
        self._missed += 1
        prev = self._state
        if (
            self._missed < self.config.missed_frames_no_person
            and prev.status is PersonStatus.PERSON
        ):
            # One miss: keep the person where they were (thesis 4.5).
            self._state = replace(
                prev,
                stamp_s=stamp_s,
                boxes=boxes,
                missed_frames=self._missed,
                warning=bad,
                people_m=(),
                people_boxes=(),
            )
            return self._state
        self._direction.reset()
        status = PersonStatus.UNKNOWN if bad is not None else PersonStatus.NO_PERSON
        if self._missed < self.config.missed_frames_no_person:
            status = prev.status if bad is None else PersonStatus.UNKNOWN
        self._state = CameraPersonState(
            stamp_s=stamp_s, status=status, boxes=boxes, missed_frames=self._missed, warning=bad
        )
        return self._state


def _suppress(candidates: list, iou: float, contained: float) -> list:
    """The (box, foot, position) candidates after non-maximum suppression of their boxes."""
    keep = set(map(id, non_max_suppression([c[0] for c in candidates], iou, contained)))
    return sorted((c for c in candidates if id(c[0]) in keep), key=lambda c: -c[0].weight)


def _drop_nested(boxes: tuple[PersonBox, ...], frac: float) -> tuple[PersonBox, ...]:
    """The boxes without those lying (by ``frac`` of their area) inside a taller one."""
    keep = []
    for b in boxes:
        inside = False
        for o in boxes:
            if o is b or o.height <= b.height:
                continue
            w = min(b.x + b.width, o.x + o.width) - max(b.x, o.x)
            h = min(b.y + b.height, o.y + o.height) - max(b.y, o.y)
            if w > 0 and h > 0 and w * h >= frac * b.width * b.height:
                inside = True
                break
        if not inside:
            keep.append(b)
    return tuple(keep)

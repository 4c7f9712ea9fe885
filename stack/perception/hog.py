"""People detection in camera frames with HOG and a linear SVM (thesis 4.5).

OpenCV's ``HOGDescriptor`` with its default people detector (Dalal and Triggs,
64 x 128 window, trained on INRIA) scans the image at several scales
(``detectMultiScale``). Its box is larger than the person: the training windows
keep a margin of about 16 px above and below a 96 px person, so the box is shrunk
until its bottom line meets the feet, and the bottom-middle pixel is the person's
image position (figure 4.9). Optionally the lowest foreground pixel inside the box
refines that foot row (FEASIBILITY: "foot within 0.3 m" rose from 0.56 to 0.74).

Speed (FEASIBILITY.md): scale step 1.05 at 640 x 480 costs 45-126 ms; halving a
1280 x 800 frame first detects as well as native 640 x 480 at a fraction of the
cost. ``downscale`` and ``roi_px`` in :class:`HogConfig` are the levers.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from stack.config import Config, require
from stack.perception.errors import BadFrameError

HOG_WINDOW_PX = (64, 128)  # (width, height) of the default people detector's window


@dataclass(frozen=True)
class HogConfig(Config):
    """Parameters of ``cv2.HOGDescriptor.detectMultiScale``.

    Attributes:
        win_stride_px: window stride (x, y) [px]; a multiple of the 8 px block stride.
        padding_px: padding added around the image (x, y) [px].
        scale_step: ratio between successive pyramid levels (> 1; 1.05 fine, 1.2 coarse).
        hit_threshold: SVM margin a window needs to count as a hit [SVM units].
        group_threshold: minimum number of overlapping hits grouped into one box.
        min_weight: boxes whose SVM weight is below this are dropped [SVM units].
        downscale: factor the frame (or ROI) is resized by before detection (0 < f <= 1).
        roi_px: (x, y, width, height) of the image area searched [px, full resolution];
            None searches the whole frame.
        threads: OpenCV worker threads (0 leaves OpenCV's default).
    """

    section = "hog"  # errors name keys "hog.<field>"

    win_stride_px: tuple[int, int] = (8, 8)
    padding_px: tuple[int, int] = (8, 8)
    scale_step: float = 1.05
    hit_threshold: float = 0.0
    group_threshold: int = 2
    min_weight: float = 0.0
    downscale: float = 1.0
    roi_px: tuple[int, int, int, int] | None = None
    threads: int = 0

    def __post_init__(self) -> None:
        for i, s in enumerate(self.win_stride_px):
            require(
                s > 0 and s % 8 == 0, f"win_stride_px[{i}]", s, "must be a positive multiple of 8"
            )
        for i, p in enumerate(self.padding_px):
            require(p >= 0, f"padding_px[{i}]", p, "must be >= 0")
        require(self.scale_step > 1.0, "scale_step", self.scale_step, "must be > 1")
        require(self.group_threshold >= 0, "group_threshold", self.group_threshold, "must be >= 0")
        require(0.0 < self.downscale <= 1.0, "downscale", self.downscale, "must be in (0, 1]")
        if self.roi_px is not None:
            x, y, w, h = self.roi_px
            require(x >= 0 and y >= 0 and w > 0 and h > 0, "roi_px", self.roi_px,
                    "needs x, y >= 0 and width, height > 0")  # fmt: skip
        require(self.threads >= 0, "threads", self.threads, "must be >= 0")


@dataclass(frozen=True)
class PersonBox:
    """One HOG detection in full-resolution image pixels.

    Attributes:
        x, y: top-left corner [px].
        width, height: box size [px].
        weight: the SVM's confidence (distance from the hyperplane).
    """

    x: int
    y: int
    width: int
    height: int
    weight: float

    @property
    def bottom_middle_px(self) -> tuple[float, float]:
        """The unshrunk box's bottom-middle pixel (u, v)."""
        return (self.x + self.width / 2.0, float(self.y + self.height))


@dataclass(frozen=True)
class FootConfig(Config):
    """How a box is shrunk to the feet (figure 4.9) and optionally refined.

    Attributes:
        bottom_shrink_frac: fraction of the box height cut from its bottom so that
            the bottom line meets the feet [-]. The detector's window holds a 96 px
            person in 128 px (0.125 margin); in the twin, standing in each of the 12
            cells, the pelvis's floor point sat 0.12-0.19 (mean 0.16) above the box bottom.
        use_foreground: refine the foot row with the lowest foreground pixel.
        search_width_frac: central fraction of the box width searched for the feet [-].
        search_below_frac: how far below the box bottom the search may go [box heights].
        min_foreground_px: foreground pixels a row needs to count as feet [px].
        max_refine_frac: largest move of the foot row by refinement [box heights];
            a larger move means the mask is wrong (shadow, second person) and is ignored.
    """

    section = "foot"  # errors name keys "foot.<field>"

    bottom_shrink_frac: float = 0.16
    use_foreground: bool = True
    search_width_frac: float = 0.6
    search_below_frac: float = 0.1
    min_foreground_px: int = 2
    max_refine_frac: float = 0.25

    def __post_init__(self) -> None:
        require(0.0 <= self.bottom_shrink_frac < 0.5, "bottom_shrink_frac",
                self.bottom_shrink_frac, "must be in [0, 0.5)")  # fmt: skip
        require(0.0 < self.search_width_frac <= 1.0, "search_width_frac",
                self.search_width_frac, "must be in (0, 1]")  # fmt: skip
        require(self.search_below_frac >= 0.0, "search_below_frac", self.search_below_frac,
                "must be >= 0")  # fmt: skip
        require(self.min_foreground_px >= 1, "min_foreground_px", self.min_foreground_px,
                "must be >= 1")  # fmt: skip
        require(self.max_refine_frac > 0.0, "max_refine_frac", self.max_refine_frac, "must be > 0")


def validate_frame(image: Any, black_max_level: float = 3.0) -> np.ndarray:
    """Check that a camera frame can be searched for people.

    Args:
        image: the frame, an 8-bit grey (H, W) or colour (H, W, 3) array.
        black_max_level: a frame whose brightest pixel is at or below this level counts
            as black (lens cap, camera off) [0-255].

    Returns:
        The same array (C-contiguous).

    Raises:
        BadFrameError: not an array, empty, not 8-bit, wrong shape, or black.
    """
    if not isinstance(image, np.ndarray):
        raise BadFrameError(f"frame must be a numpy array, got {type(image).__name__}")
    if image.size == 0:
        raise BadFrameError(f"frame is empty (shape {image.shape})")
    if image.dtype != np.uint8:
        raise BadFrameError(f"frame must be 8-bit (uint8), got {image.dtype}")
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] in (1, 3))):
        raise BadFrameError(f"frame must be (H, W) or (H, W, 3), got shape {image.shape}")
    if int(image.max()) <= black_max_level:
        raise BadFrameError(f"frame is black (max level {int(image.max())})")
    return np.ascontiguousarray(image)


def clip_roi(
    roi_px: tuple[int, int, int, int] | None, image_shape: tuple[int, ...]
) -> tuple[int, int, int, int]:
    """Clip an (x, y, w, h) region to the image; None means the whole image.

    Returns:
        (x, y, w, h) inside the image; w or h is 0 when the ROI lies outside it.
    """
    height, width = image_shape[:2]
    if roi_px is None:
        return (0, 0, width, height)
    x, y, w, h = roi_px
    x0, y0 = max(0, int(x)), max(0, int(y))
    x1, y1 = min(width, int(x + w)), min(height, int(y + h))
    return (x0, y0, max(0, x1 - x0), max(0, y1 - y0))


class HogPeopleDetector:
    """OpenCV's HOG people detector with ROI and downscaling.

    Args:
        config: detection parameters.
    """

    def __init__(self, config: HogConfig = HogConfig()):
        self.config = config
        self._hog = cv2.HOGDescriptor()
        self._hog.setSVMDetector(np.asarray(cv2.HOGDescriptor.getDefaultPeopleDetector()))
        if config.threads > 0:
            cv2.setNumThreads(config.threads)

    def detect(
        self, image: np.ndarray, roi_px: tuple[int, int, int, int] | None = None
    ) -> tuple[PersonBox, ...]:
        """Find upright people in a frame.

        Args:
            image: 8-bit grey or BGR frame (see :func:`validate_frame`).
            roi_px: (x, y, w, h) to search instead of the configured ROI [px], e.g. a
                window around the last detection.

        Returns:
            Boxes in full-resolution pixels, strongest first; empty when the searched
            area is smaller than the detector's window.

        Raises:
            BadFrameError: the frame is unusable.
        """
        image = validate_frame(image)
        cfg = self.config
        x0, y0, w, h = clip_roi(roi_px if roi_px is not None else cfg.roi_px, image.shape)
        if w == 0 or h == 0:
            return ()
        crop = image[y0 : y0 + h, x0 : x0 + w]
        f = cfg.downscale
        if f < 1.0:
            size = (max(1, round(w * f)), max(1, round(h * f)))
            crop = cv2.resize(crop, size, interpolation=cv2.INTER_AREA)
        if crop.shape[1] < HOG_WINDOW_PX[0] or crop.shape[0] < HOG_WINDOW_PX[1]:
            return ()
        rects, weights = self._hog.detectMultiScale(
            crop,
            hitThreshold=cfg.hit_threshold,
            winStride=cfg.win_stride_px,
            padding=cfg.padding_px,
            scale=cfg.scale_step,
            groupThreshold=cfg.group_threshold,
        )
        boxes = []
        for (bx, by, bw, bh), wt in zip(np.reshape(rects, (-1, 4)), np.ravel(weights), strict=True):
            if float(wt) < cfg.min_weight:
                continue
            boxes.append(
                PersonBox(
                    x=x0 + round(bx / f),
                    y=y0 + round(by / f),
                    width=round(bw / f),
                    height=round(bh / f),
                    weight=float(wt),
                )
            )
        boxes.sort(key=lambda b: -b.weight)
        return tuple(boxes)

    def detect_people(
        self,
        image: np.ndarray,
        roi_px: tuple[int, int, int, int] | None = None,
        iou_threshold: float = 0.4,
        containment_frac: float = 0.8,
    ) -> tuple[PersonBox, ...]:
        """Every person in a frame, one box each: :meth:`detect` then
        :func:`non_max_suppression` (issue 16: several people at once)."""
        return non_max_suppression(self.detect(image, roi_px), iou_threshold, containment_frac)


def box_overlap(a: PersonBox, b: PersonBox) -> tuple[float, float]:
    """(intersection over union, intersection over the smaller box) of two boxes."""
    w = min(a.x + a.width, b.x + b.width) - max(a.x, b.x)
    h = min(a.y + a.height, b.y + b.height) - max(a.y, b.y)
    if w <= 0 or h <= 0:
        return 0.0, 0.0
    inter = float(w * h)
    area_a, area_b = a.width * a.height, b.width * b.height
    return inter / (area_a + area_b - inter), inter / min(area_a, area_b)


def non_max_suppression(
    boxes: tuple[PersonBox, ...] | list[PersonBox],
    iou_threshold: float = 0.4,
    containment_frac: float = 0.8,
) -> tuple[PersonBox, ...]:
    """All the people of a frame, one box each (greedy non-maximum suppression).

    OpenCV's grouping (``group_threshold``) merges near-identical windows, but a person
    still often gets two boxes: at two pyramid scales, or a full-body box and one
    around the upper body. Boxes are taken strongest first; a box overlapping a kept
    one by more than ``iou_threshold`` (intersection over union) or lying inside it by
    ``containment_frac`` of the smaller box is the same person and dropped. Two
    people side by side overlap little and are both kept; people passing each other
    in the image overlap more and merge (the tracker coasts through that).

    Args:
        boxes: the frame's detections, any order.
        iou_threshold: largest IoU of two kept boxes (0-1).
        containment_frac: largest share of the smaller box inside a kept one (0-1].

    Returns:
        The kept boxes, strongest first.
    """
    kept: list[PersonBox] = []
    for box in sorted(boxes, key=lambda b: -b.weight):
        if all(
            iou <= iou_threshold and inside <= containment_frac
            for iou, inside in (box_overlap(box, k) for k in kept)
        ):
            kept.append(box)
    return tuple(kept)


def foot_point(
    box: PersonBox, config: FootConfig = FootConfig(), foreground: np.ndarray | None = None
) -> tuple[float, float]:
    """The person's image position: the bottom-middle pixel of the shrunk box (fig. 4.9).

    Args:
        box: a detection.
        config: the shrink and refinement parameters.
        foreground: optional boolean (H, W) mask of moving pixels of the same frame;
            with ``config.use_foreground`` the lowest foreground row in the box's lower
            part (and a little below) replaces the shrunk bottom.

    Returns:
        (u, v) in pixels.
    """
    u = box.x + box.width / 2.0
    v = box.y + box.height * (1.0 - config.bottom_shrink_frac)
    if foreground is None or not config.use_foreground:
        return (u, v)
    mask = np.asarray(foreground, dtype=bool)
    half = box.width * config.search_width_frac / 2.0
    c0, c1 = max(0, int(u - half)), min(mask.shape[1], int(np.ceil(u + half)))
    r0 = max(0, box.y + box.height // 2)
    r1 = min(mask.shape[0], int(np.ceil(box.y + box.height * (1.0 + config.search_below_frac))))
    if c1 <= c0 or r1 <= r0:
        return (u, v)
    counts = mask[r0:r1, c0:c1].sum(axis=1)
    rows = np.flatnonzero(counts >= config.min_foreground_px)
    if rows.size == 0:
        return (u, v)
    lowest = r0 + int(rows[-1])
    if abs(lowest - v) > config.max_refine_frac * box.height:
        return (u, v)
    # The feet's column: the centre of the foreground in the few lowest rows.
    band = mask[max(r0, lowest - 3) : lowest + 1, c0:c1]
    cols = np.flatnonzero(band.any(axis=0))
    u_feet = c0 + float(cols.mean()) if cols.size else u
    # OpenCV puts pixel centres at integers: the lowest pixel's bottom edge is +0.5.
    return (u_feet, float(lowest) + 0.5)


class Foreground:
    """Moving pixels by background subtraction (OpenCV MOG2), shadows suppressed.

    Args:
        history_frames: frames the background model averages over.
        var_threshold: squared Mahalanobis distance that marks a pixel as foreground.
        open_px: side of the morphological opening that removes speckle [px, at the
            model's resolution].
        downscale: the model runs on the frame resized by this factor (0 < f <= 1;
            0.5 costs about a quarter); the mask comes back at the frame's size.
    """

    def __init__(
        self,
        history_frames: int = 200,
        var_threshold: float = 25.0,
        open_px: int = 3,
        downscale: float = 1.0,
    ):
        if history_frames < 1:
            raise ValueError(f"history_frames {history_frames!r} must be >= 1")
        if not 0.0 < downscale <= 1.0:
            raise ValueError(f"downscale {downscale!r} must be in (0, 1]")
        self._downscale = downscale
        self._mog = cv2.createBackgroundSubtractorMOG2(
            history=history_frames, varThreshold=var_threshold, detectShadows=True
        )
        self._kernel = np.ones((open_px, open_px), np.uint8) if open_px > 1 else None

    def apply(self, image: np.ndarray) -> np.ndarray:
        """Update the model with a frame and return its boolean foreground mask."""
        small = image
        f = self._downscale
        if f < 1.0:
            size = (max(1, round(image.shape[1] * f)), max(1, round(image.shape[0] * f)))
            small = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
        raw = self._mog.apply(small)
        mask = (raw == 255).astype(np.uint8)  # 127 marks shadows: not the person
        if self._kernel is not None:
            mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, self._kernel)
        if small is not image:
            size = (image.shape[1], image.shape[0])
            mask = cv2.resize(mask, size, interpolation=cv2.INTER_NEAREST)
        return mask.astype(bool)

"""A statistical model of the camera pipeline, for studies that cannot afford to render.

The real pipeline renders the ceiling camera (EGL) and runs HOG on every frame
(:mod:`stack.perception.camera`): about 0.18 s of CPU per frame, 80 % of a Monte-Carlo
episode. This model draws what HOG and the homography would report for a frame, the
floor points of the people detected, from the true scene, and hands them to the real
tracker (:meth:`CameraPeopleTracker.update_points`): the association gate, the
two-missed-frames rule, the direction window and the cell lookup stay the real code,
and so do the lidar, the leg tracker, the planner, navigation and speech.

Per frame and per person in the scene:

- **detected?** A logistic model of the person's visibility from the camera
  (:class:`stack.perception.visibility.CameraVisibility`: the share of the silhouette
  in the image, the shares of the silhouette and of the legs hidden by the robot), the
  person's speed, whether they are in the room, and whether they were detected in the
  previous frame (HOG's misses come in runs: the same pose is missed again, which is
  what the two-missed-frames rule reacts to);
- **where?** the true floor point plus an error: a bias linear in the person's
  position and velocity (the foot point of a person walking across the image sits
  lower than of one walking along it) and a residual that is AR(1) from frame to
  frame, with its own standard deviation per axis;
- **false positives:** a Poisson number per frame, at floor points drawn from those
  seen in the fitted runs.

:func:`fit` estimates all of it from frame records of rendered runs (the in-process
loop writes ``detections.jsonl`` in rendered mode; ``vigil fit-perception`` runs the
episodes and writes the model file). The file (YAML) holds the coefficients, the
data they came from and the date; ``config/perception-model.yaml`` is the one the
repository ships. Pure: numpy only.
"""

from __future__ import annotations

import datetime as _dt
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from stack.cells import ConfigError
from stack.config import dump_yaml, write_text
from stack.geometry import Pose2D
from stack.perception.visibility import CameraVisibility

FEATURES = (
    "bias",
    "in_image",
    "covered",
    "legs_covered",
    "speed_mps",
    "out_of_room",
    "seen_before",
)
MATCH_GATE_M = 1.0  # a detection farther than this from every person is a false positive
MAX_FALSE_POINTS = 400  # false-positive positions kept in the file
FORMAT = "vigil-perception-model/1"
DETECTIONS_FILE = "detections.jsonl"  # rendered runs: each frame's truth and detections


@dataclass(frozen=True)
class PersonFrame:
    """One person in one camera frame, as the model sees them (truth)."""

    x_m: float
    y_m: float
    vx_mps: float
    vy_mps: float
    in_room: bool


@dataclass(frozen=True)
class PerceptionModel:
    """The fitted model (see the module doc).

    Attributes:
        detect_w: logistic weights over :data:`FEATURES`.
        bias_w: (2, 5) the position error's mean: rows x, y over [1, x, y, vx, vy].
        error_sd_m: (sx, sy) the residual's standard deviation [m].
        error_rho: the residual's frame-to-frame correlation (AR(1)).
        false_rate: false positives per frame (Poisson mean).
        false_points_m: floor points false positives were seen at.
        meta: where the fit came from (runs, frames, date, command).
    """

    detect_w: tuple[float, ...]
    bias_w: tuple[tuple[float, ...], tuple[float, ...]]
    error_sd_m: tuple[float, float]
    error_rho: float
    false_rate: float
    false_points_m: tuple[tuple[float, float], ...] = ()
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if len(self.detect_w) != len(FEATURES):
            raise ConfigError("detect_w", self.detect_w, f"needs {len(FEATURES)} weights")
        if len(self.bias_w) != 2 or any(len(r) != 5 for r in self.bias_w):
            raise ConfigError("bias_w", self.bias_w, "needs 2 rows of 5 weights")
        numbers = [*self.detect_w, *self.bias_w[0], *self.bias_w[1], *self.error_sd_m]
        if not all(math.isfinite(v) for v in numbers):
            raise ConfigError("perception model", numbers, "weights must be finite")
        if len(self.error_sd_m) != 2 or min(self.error_sd_m) < 0:
            raise ConfigError("error_sd_m", self.error_sd_m, "needs two values >= 0")
        if not -1.0 < self.error_rho < 1.0:
            raise ConfigError("error_rho", self.error_rho, "must lie in (-1, 1)")
        if not (math.isfinite(self.false_rate) and 0.0 <= self.false_rate <= 10.0):
            raise ConfigError("false_rate", self.false_rate, "must lie in [0, 10] per frame")
        if self.false_rate > 0 and not self.false_points_m:
            raise ConfigError("false_points_m", [], "needed when false_rate > 0")

    # -- file -----------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "features": list(FEATURES),
            "detect_w": [round(w, 6) for w in self.detect_w],
            "bias_w": [[round(w, 6) for w in row] for row in self.bias_w],
            "error_sd_m": [round(v, 6) for v in self.error_sd_m],
            "error_rho": round(self.error_rho, 6),
            "false_rate": round(self.false_rate, 6),
            "false_points_m": [[round(x, 3), round(y, 3)] for x, y in self.false_points_m],
            "meta": self.meta,
        }

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        write_text(
            path,
            "# The camera pipeline's model (stack/perception/model.py), fitted by\n"
            "# `vigil fit-perception`; meta says from which rendered runs and when.\n"
            + dump_yaml(self.to_dict(), sort_keys=False, width=100),
        )
        return path

    @classmethod
    def from_dict(cls, d: Any, source: str = "perception model") -> PerceptionModel:
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            raise ConfigError(f"{source}: format", (d or {}).get("format") if isinstance(
                d, dict) else d, f"must be {FORMAT}")  # fmt: skip
        if list(d.get("features") or []) != list(FEATURES):
            raise ConfigError(f"{source}: features", d.get("features"), f"must be {FEATURES}")
        try:
            return cls(
                detect_w=tuple(float(w) for w in d["detect_w"]),
                bias_w=tuple(tuple(float(w) for w in row) for row in d["bias_w"]),  # type: ignore[arg-type]
                error_sd_m=tuple(float(v) for v in d["error_sd_m"]),  # type: ignore[arg-type]
                error_rho=float(d["error_rho"]),
                false_rate=float(d["false_rate"]),
                false_points_m=tuple(
                    (float(p[0]), float(p[1])) for p in d.get("false_points_m") or ()
                ),
                meta=dict(d.get("meta") or {}),
            )
        except KeyError as err:
            raise ConfigError(f"{source}: {err.args[0]}", None, "is missing") from None
        except (TypeError, ValueError, IndexError) as err:
            raise ConfigError(source, None, f"malformed: {err}") from None

    @classmethod
    def load(cls, path: str | Path) -> PerceptionModel:
        from stack.config import read_yaml

        return cls.from_dict(read_yaml(path), str(path))

    # -- drawing --------------------------------------------------------------------------
    def p_detect(self, features: np.ndarray) -> float:
        z = float(np.dot(self.detect_w, features))
        return 1.0 / (1.0 + math.exp(-max(-50.0, min(50.0, z))))

    def bias_m(self, p: PersonFrame) -> np.ndarray:
        v = np.array([1.0, p.x_m, p.y_m, p.vx_mps, p.vy_mps])
        return np.array([np.dot(self.bias_w[0], v), np.dot(self.bias_w[1], v)])


def features_of(
    p: PersonFrame,
    visibility: CameraVisibility,
    robot_mask: np.ndarray | None,
    robot_xy: tuple[float, float] | None,
    seen_before: bool,
) -> np.ndarray:
    """The detection features of :data:`FEATURES` for one person in one frame."""
    v = visibility.point(p.x_m, p.y_m, robot_mask, robot_xy)
    return np.array(
        [
            1.0,
            v.in_image_frac,
            v.covered_frac,
            v.legs_covered_frac,
            math.hypot(p.vx_mps, p.vy_mps),
            0.0 if p.in_room else 1.0,
            1.0 if seen_before else 0.0,
        ]
    )


class ModelCamera:
    """Draws one frame's detected floor points from the truth (see the module doc).

    Args:
        model: the fitted model.
        visibility: the camera's visibility (the observations node's calibration).
        rng: the random source (seeded by the run: same seed, same detections).
    """

    def __init__(
        self, model: PerceptionModel, visibility: CameraVisibility, rng: np.random.Generator
    ):
        self.model, self.visibility, self.rng = model, visibility, rng
        self._seen: dict[int, bool] = {}
        self._residual: dict[int, np.ndarray] = {}

    def frame(self, people: Sequence[PersonFrame], robot: Pose2D) -> list[tuple[float, float]]:
        """The frame's detections as floor points, the people's first (in their order),
        then the false positives."""
        m, rng, vis = self.model, self.rng, self.visibility
        rxy = (robot.x_m, robot.y_m)
        # the robot's mask only when someone could be behind it (no mask: the same answer)
        behind = any(vis.behind_robot_possible(p.x_m, p.y_m, rxy) for p in people)
        mask = vis.robot_mask(robot) if behind else None
        out: list[tuple[float, float]] = []
        for i, p in enumerate(people):
            f = features_of(p, self.visibility, mask, rxy, self._seen.get(i, False))
            seen = bool(rng.random() < m.p_detect(f))
            self._seen[i] = seen
            # the residual runs on whether or not this frame shows the person
            prev = self._residual.get(i)
            sd = np.asarray(m.error_sd_m)
            fresh = rng.normal(0.0, 1.0, 2) * sd
            if prev is None:
                r = fresh
            else:
                r = m.error_rho * prev + math.sqrt(1.0 - m.error_rho**2) * fresh
            self._residual[i] = r
            if seen:
                e = m.bias_m(p) + r
                out.append((round(p.x_m + float(e[0]), 4), round(p.y_m + float(e[1]), 4)))
        for _ in range(int(rng.poisson(m.false_rate)) if m.false_rate > 0 else 0):
            x, y = m.false_points_m[int(rng.integers(len(m.false_points_m)))]
            jitter = rng.normal(0.0, 0.05, 2)
            out.append((round(x + float(jitter[0]), 4), round(y + float(jitter[1]), 4)))
        return out


# -- fitting --------------------------------------------------------------------------------


@dataclass(frozen=True)
class FrameRecord:
    """One rendered frame: the truth and what the pipeline detected."""

    t: float
    robot: Pose2D
    people: tuple[PersonFrame, ...]
    detections: tuple[tuple[float, float], ...]
    episode: str = ""


def frame_record(d: dict[str, Any], episode: str = "") -> FrameRecord:
    """A ``detections.jsonl`` line as a :class:`FrameRecord`."""
    return FrameRecord(
        t=float(d["t"]),
        robot=Pose2D(*(float(v) for v in d["robot"])),
        people=tuple(
            PersonFrame(float(p[0]), float(p[1]), float(p[2]), float(p[3]), bool(p[4]))
            for p in d["people"]
        ),
        detections=tuple((float(q[0]), float(q[1])) for q in d["detections"]),
        episode=episode,
    )


def _match(frame: FrameRecord) -> tuple[dict[int, int], list[int]]:
    """Greedy nearest matching of detections to people within :data:`MATCH_GATE_M`:
    (person -> detection, unmatched detections)."""
    pairs = sorted(
        (math.dist((p.x_m, p.y_m), d), i, j)
        for i, p in enumerate(frame.people)
        for j, d in enumerate(frame.detections)
    )
    matched: dict[int, int] = {}
    used: set[int] = set()
    for dist, i, j in pairs:
        if dist > MATCH_GATE_M:
            break
        if i not in matched and j not in used:
            matched[i] = j
            used.add(j)
    return matched, [j for j in range(len(frame.detections)) if j not in used]


def _logistic(X: np.ndarray, y: np.ndarray, ridge: float = 1e-3, iters: int = 50) -> np.ndarray:
    """Logistic regression by Newton's method (IRLS) with a small ridge."""
    w = np.zeros(X.shape[1])
    for _ in range(iters):
        p = 1.0 / (1.0 + np.exp(-np.clip(X @ w, -50, 50)))
        g = X.T @ (p - y) + ridge * w
        H = (X * (p * (1 - p))[:, None]).T @ X + ridge * np.eye(X.shape[1])
        step = np.linalg.solve(H, g)
        w -= step
        if np.max(np.abs(step)) < 1e-8:
            break
    return w


def fit(
    frames: Iterable[FrameRecord],
    visibility: CameraVisibility,
    meta: dict[str, Any] | None = None,
) -> tuple[PerceptionModel, dict[str, Any]]:
    """Fit the model to rendered frames (in time order within each episode).

    Returns:
        (the model, a report: frames, people-frames, detection rate, errors, and the
        detection rate binned by the model's probability against the data's).
    """
    X, y = [], []
    err_rows, err_feat = [], []
    lag_pairs: list[tuple[int, int]] = []  # rows of consecutive frames of one person
    false_pts: list[tuple[float, float]] = []
    n_frames = 0
    seen: dict[tuple[str, int], bool] = {}
    last_err: dict[tuple[str, int], tuple[float, int]] = {}
    for fr in frames:
        n_frames += 1
        mask = visibility.robot_mask(fr.robot)
        rxy = (fr.robot.x_m, fr.robot.y_m)
        matched, unmatched = _match(fr)
        for i, p in enumerate(fr.people):
            key = (fr.episode, i)
            X.append(features_of(p, visibility, mask, rxy, seen.get(key, False)))
            hit = i in matched
            y.append(1.0 if hit else 0.0)
            seen[key] = hit
            if hit:
                d = fr.detections[matched[i]]
                e = np.array([d[0] - p.x_m, d[1] - p.y_m])
                err_rows.append(e)
                err_feat.append([1.0, p.x_m, p.y_m, p.vx_mps, p.vy_mps])
                prev = last_err.get(key)
                if prev is not None and fr.t - prev[0] < 0.15:  # consecutive frames (10 Hz)
                    lag_pairs.append((prev[1], len(err_rows) - 1))
                last_err[key] = (fr.t, len(err_rows) - 1)
        false_pts += [fr.detections[j] for j in unmatched]
    if len(y) < 20 or sum(y) < 10:
        raise ValueError(f"too little data to fit: {len(y)} person-frames, {int(sum(y))} detected")
    Xa, ya = np.array(X), np.array(y)
    w = _logistic(Xa, ya)
    E, F = np.array(err_rows), np.array(err_feat)
    bias = np.linalg.lstsq(F, E, rcond=None)[0].T  # (2, 5)
    resid = E - F @ bias.T
    sd = resid.std(axis=0)
    # AR(1): the correlation of consecutive residuals of the same person
    rho = 0.0
    if len(lag_pairs) > 10:
        a, b = np.array(lag_pairs).T
        A, B = resid[a].ravel(), resid[b].ravel()
        rho = float(np.clip(np.dot(A, B) / max(np.dot(A, A), 1e-12), -0.95, 0.95))
    false_rate = len(false_pts) / max(n_frames, 1)
    rng = np.random.default_rng(0)
    if len(false_pts) > MAX_FALSE_POINTS:
        keep = rng.choice(len(false_pts), MAX_FALSE_POINTS, replace=False)
        false_pts = [false_pts[k] for k in sorted(keep)]
    model = PerceptionModel(
        detect_w=tuple(float(v) for v in w),
        bias_w=(tuple(float(v) for v in bias[0]), tuple(float(v) for v in bias[1])),
        error_sd_m=(float(sd[0]), float(sd[1])),
        error_rho=rho,
        false_rate=false_rate,
        false_points_m=tuple(false_pts),
        meta={
            "date": _dt.date.today().isoformat(),
            "frames": n_frames,
            "person_frames": len(y),
            "detected": int(ya.sum()),
            **(meta or {}),
        },
    )
    p_hat = 1.0 / (1.0 + np.exp(-np.clip(Xa @ w, -50, 50)))
    bins = [0.0, 0.2, 0.5, 0.8, 0.95, 1.0001]
    calib = []
    for lo, hi in zip(bins[:-1], bins[1:], strict=True):
        sel = (p_hat >= lo) & (p_hat < hi)
        if sel.any():
            calib.append(
                {"p_model": [lo, min(hi, 1.0)], "n": int(sel.sum()),
                 "mean_model": round(float(p_hat[sel].mean()), 3),
                 "rate_data": round(float(ya[sel].mean()), 3)}
            )  # fmt: skip
    report = {
        "frames": n_frames,
        "person_frames": len(y),
        "detection_rate": round(float(ya.mean()), 4),
        "error_mean_m": [round(float(v), 4) for v in E.mean(axis=0)],
        "error_sd_m": [round(float(v), 4) for v in sd],
        "error_rho": round(rho, 3),
        "false_per_frame": round(model.false_rate, 4),
        "calibration": calib,
    }
    return model, report

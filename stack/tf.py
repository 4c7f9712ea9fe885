"""The TF tree without ROS: frames, rigid transforms, composition and timed lookups.

REP-105 frames as vigil uses them (names in :data:`FRAMES`)::

    map -> odom -> base_link -> laser          (localisation, odometry, static mount)
    map -> camera_link -> camera_optical_frame (static, from the camera calibration)

A transform ``T_parent_child`` maps a point given in the child frame to the parent frame,
as ``geometry_msgs/TransformStamped`` with ``header.frame_id`` = parent and
``child_frame_id`` = child does. :meth:`TfBuffer.lookup` answers like tf2's
``lookup_transform(target, source, time)``: the transform that maps points in ``source``
to ``target``.

Time: a static transform holds at every time; a dynamic one is known between the oldest
and newest stamp in the cache and interpolated in between (position linearly, rotation
by slerp). Time ``None`` asks for the latest time at which the whole chain is known,
like tf2's ``Time(0)``. Nodes do not block: :class:`PendingLookup` keeps asking on each
callback and raises :class:`TfTimeout` once the timeout has passed, naming why the
transform was missing.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from stack.geometry import Pose2D

MAP = "map"
ODOM = "odom"
BASE_LINK = "base_link"
LASER = "laser"
CAMERA_LINK = "camera_link"
CAMERA_OPTICAL = "camera_optical_frame"
FRAMES = (MAP, ODOM, BASE_LINK, LASER, CAMERA_LINK, CAMERA_OPTICAL)

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]  # x, y, z, w


class TfError(LookupError):
    """A transform that cannot be given (the message says why)."""


class FrameNotFound(TfError):
    """A frame nobody has published."""


class NotConnected(TfError):
    """Both frames exist but no chain of transforms joins them."""


class ExtrapolationError(TfError):
    """The time asked lies outside what the cache holds for a link of the chain."""


class TfTimeout(TfError):
    """A lookup still failed when its timeout ran out."""


def _qmul(a: Quat, b: Quat) -> Quat:
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def _qrot(q: Quat, v: Vec3) -> Vec3:
    x, y, z, w = q
    vx, vy, vz = v
    # v + 2 w (q x v) + 2 q x (q x v)
    cx, cy, cz = y * vz - z * vy, z * vx - x * vz, x * vy - y * vx
    cx, cy, cz = 2 * cx, 2 * cy, 2 * cz
    return (
        vx + w * cx + (y * cz - z * cy),
        vy + w * cy + (z * cx - x * cz),
        vz + w * cz + (x * cy - y * cx),
    )


def quaternion_from_rpy(roll: float, pitch: float, yaw: float) -> Quat:
    """The quaternion of fixed-axis roll, pitch, yaw [rad] (tf2's ``setRPY``)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    )


def quaternion_from_matrix(m) -> Quat:
    """The unit quaternion of a 3 x 3 rotation matrix (nested sequences or an array)."""
    r = [[float(m[i][j]) for j in range(3)] for i in range(3)]
    tr = r[0][0] + r[1][1] + r[2][2]
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = ((r[2][1] - r[1][2]) / s, (r[0][2] - r[2][0]) / s, (r[1][0] - r[0][1]) / s, s / 4)
    elif r[0][0] > r[1][1] and r[0][0] > r[2][2]:
        s = 2.0 * math.sqrt(1.0 + r[0][0] - r[1][1] - r[2][2])
        q = (s / 4, (r[0][1] + r[1][0]) / s, (r[0][2] + r[2][0]) / s, (r[2][1] - r[1][2]) / s)
    elif r[1][1] > r[2][2]:
        s = 2.0 * math.sqrt(1.0 + r[1][1] - r[0][0] - r[2][2])
        q = ((r[0][1] + r[1][0]) / s, s / 4, (r[1][2] + r[2][1]) / s, (r[0][2] - r[2][0]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + r[2][2] - r[0][0] - r[1][1])
        q = ((r[0][2] + r[2][0]) / s, (r[1][2] + r[2][1]) / s, s / 4, (r[1][0] - r[0][1]) / s)
    n = math.sqrt(sum(c * c for c in q))
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


@dataclass(frozen=True)
class Transform:
    """A rigid transform: rotation (unit quaternion x, y, z, w) then translation [m].

    Raises:
        ValueError: a non-finite value, or a rotation that is not a unit quaternion
            (within 1e-6; it is renormalised then).
    """

    translation: Vec3 = (0.0, 0.0, 0.0)
    rotation: Quat = (0.0, 0.0, 0.0, 1.0)

    def __post_init__(self) -> None:
        t = tuple(float(v) for v in self.translation)
        q = tuple(float(v) for v in self.rotation)
        if len(t) != 3 or len(q) != 4:
            raise ValueError(f"a transform needs 3 translation and 4 rotation values, got {t} {q}")
        if not all(math.isfinite(v) for v in t + q):
            raise ValueError(f"a transform must be finite, got translation {t} rotation {q}")
        n = math.sqrt(sum(c * c for c in q))
        if abs(n - 1.0) > 1e-6:
            raise ValueError(f"rotation {q} is not a unit quaternion (norm {n:.6g})")
        object.__setattr__(self, "translation", t)
        object.__setattr__(self, "rotation", tuple(c / n for c in q))

    @classmethod
    def from_pose2d(cls, pose: Pose2D) -> Transform:
        """The transform of a planar pose (z = 0, rotation about z)."""
        return cls((pose.x_m, pose.y_m, 0.0), quaternion_from_rpy(0.0, 0.0, pose.yaw_rad))

    def to_pose2d(self) -> Pose2D:
        """The planar part: x, y and the yaw of the rotation (REP-103 frames)."""
        x, y, z, w = self.rotation
        yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
        return Pose2D(self.translation[0], self.translation[1], yaw)

    def compose(self, other: Transform) -> Transform:
        """``self * other``: T_a_b.compose(T_b_c) is T_a_c."""
        moved = _qrot(self.rotation, other.translation)
        t = self.translation
        q = _qmul(self.rotation, other.rotation)
        n = math.sqrt(sum(c * c for c in q))
        return Transform(
            (t[0] + moved[0], t[1] + moved[1], t[2] + moved[2]),
            (q[0] / n, q[1] / n, q[2] / n, q[3] / n),
        )

    def inverse(self) -> Transform:
        x, y, z, w = self.rotation
        inv_q = (-x, -y, -z, w)
        t = _qrot(inv_q, self.translation)
        return Transform((-t[0], -t[1], -t[2]), inv_q)

    def apply(self, point: Vec3) -> Vec3:
        """A point given in the child frame, expressed in the parent frame."""
        r = _qrot(self.rotation, point)
        t = self.translation
        return (r[0] + t[0], r[1] + t[1], r[2] + t[2])


def interpolate(a: Transform, b: Transform, f: float) -> Transform:
    """``a`` at f = 0 to ``b`` at f = 1: position linearly, rotation by slerp."""
    t = tuple(pa + f * (pb - pa) for pa, pb in zip(a.translation, b.translation, strict=True))
    qa, qb = a.rotation, b.rotation
    dot = sum(x * y for x, y in zip(qa, qb, strict=True))
    if dot < 0:
        qb, dot = (-qb[0], -qb[1], -qb[2], -qb[3]), -dot
    if dot > 0.9995:
        q = tuple(x + f * (y - x) for x, y in zip(qa, qb, strict=True))
    else:
        th = math.acos(dot)
        sa, sb = math.sin((1 - f) * th) / math.sin(th), math.sin(f * th) / math.sin(th)
        q = tuple(sa * x + sb * y for x, y in zip(qa, qb, strict=True))
    n = math.sqrt(sum(c * c for c in q))
    return Transform(t, tuple(c / n for c in q))  # type: ignore[arg-type]


@dataclass(frozen=True)
class StampedTransform:
    """T_parent_child at a time [s] (``geometry_msgs/TransformStamped``)."""

    parent: str
    child: str
    stamp_s: float
    transform: Transform


class _Link:
    """One child frame's link to its parent: static, or a time-ordered cache."""

    def __init__(self, parent: str, static: bool, cache_s: float):
        self.parent = parent
        self.static = static
        self.cache_s = cache_s
        self.samples: deque[tuple[float, Transform]] = deque()

    def add(self, stamp_s: float, tf: Transform) -> None:
        if self.static:
            self.samples = deque([(stamp_s, tf)])
            return
        if self.samples and stamp_s < self.samples[-1][0] - self.cache_s:
            # time jumped back past the cache (a restart, a looped bag, a reset twin): the
            # old samples describe another run; start over, as tf2 clears on a jump back
            self.samples = deque([(stamp_s, tf)])
            return
        if self.samples and stamp_s < self.samples[-1][0]:  # out of order: insert in place
            items = sorted([*self.samples, (stamp_s, tf)], key=lambda s: s[0])
            self.samples = deque(items)
        elif self.samples and stamp_s == self.samples[-1][0]:
            self.samples[-1] = (stamp_s, tf)
        else:
            self.samples.append((stamp_s, tf))
        newest = self.samples[-1][0]
        while len(self.samples) > 1 and self.samples[0][0] < newest - self.cache_s:
            self.samples.popleft()

    def at(self, time_s: float, child: str) -> Transform:
        if self.static:
            return self.samples[0][1]
        first, last = self.samples[0][0], self.samples[-1][0]
        if time_s < first - 1e-9 or time_s > last + 1e-9:
            raise ExtrapolationError(
                f"{self.parent} -> {child} is known for t in [{first:.3f}, {last:.3f}] s, "
                f"not at {time_s:.3f} s"
            )
        prev = self.samples[0]
        for s in self.samples:
            if s[0] >= time_s - 1e-9:
                if s[0] - prev[0] <= 1e-9:
                    return s[1]
                return interpolate(prev[1], s[1], (time_s - prev[0]) / (s[0] - prev[0]))
            prev = s
        return self.samples[-1][1]


class TfBuffer:
    """Every frame's link to its parent, as received on ``/tf`` and ``/tf_static``.

    Args:
        cache_s: how long dynamic transforms are kept, back from the newest [s].
    """

    def __init__(self, cache_s: float = 10.0):
        if not cache_s > 0:
            raise ValueError(f"cache_s must be > 0, got {cache_s!r}")
        self.cache_s = float(cache_s)
        self._links: dict[str, _Link] = {}

    def set_transform(self, st: StampedTransform, static: bool = False) -> None:
        """Add one transform (a new parent for the child replaces the old link).

        Raises:
            ValueError: an empty frame name, a frame its own parent, a non-finite stamp,
                or a link that would close a loop.
        """
        if not st.parent or not st.child:
            raise ValueError(f"frame names must not be empty: {st.parent!r} -> {st.child!r}")
        if st.parent == st.child:
            raise ValueError(f"frame {st.child!r} cannot be its own parent")
        if not math.isfinite(st.stamp_s):
            raise ValueError(f"{st.parent} -> {st.child}: stamp {st.stamp_s!r} is not finite")
        if st.child in self._ancestors(st.parent):
            raise ValueError(f"{st.parent} -> {st.child} would close a loop in the tree")
        link = self._links.get(st.child)
        if link is None or link.parent != st.parent or link.static != static:
            link = self._links[st.child] = _Link(st.parent, static, self.cache_s)
        link.add(st.stamp_s, st.transform)

    def frames(self) -> set[str]:
        return set(self._links) | {lk.parent for lk in self._links.values()}

    def parent_of(self, frame: str) -> str | None:
        link = self._links.get(frame)
        return link.parent if link else None

    def _ancestors(self, frame: str) -> list[str]:
        out = [frame]
        while frame in self._links:
            frame = self._links[frame].parent
            out.append(frame)
            if len(out) > len(self._links) + 1:  # cannot happen: loops are refused
                break
        return out

    def _chain(self, target: str, source: str) -> tuple[list[str], list[str]]:
        """The frames from each end up to (excluding) their common ancestor."""
        known = self.frames()
        for f in (target, source):
            if f not in known:
                raise FrameNotFound(f"frame {f!r} does not exist (known: {sorted(known)})")
        up_t, up_s = self._ancestors(target), self._ancestors(source)
        common = next((f for f in up_s if f in up_t), None)
        if common is None:
            raise NotConnected(
                f"{target!r} (root {up_t[-1]!r}) and {source!r} (root {up_s[-1]!r}) "
                "are in different trees"
            )
        return up_t[: up_t.index(common)], up_s[: up_s.index(common)]

    def latest_common_time(self, target: str, source: str) -> float | None:
        """The newest time the whole chain is known at; None when it is all static."""
        a, b = self._chain(target, source)
        newest = [self._links[f].samples[-1][0] for f in a + b if not self._links[f].static]
        return min(newest) if newest else None

    def stalest_link(self, target: str, source: str) -> tuple[str, str, float] | None:
        """(parent, child, newest stamp) of the chain's dynamic link heard from longest
        ago (the one holding ``latest_common_time`` back); None when all are static.

        Raises:
            FrameNotFound, NotConnected: as :meth:`lookup`.
        """
        a, b = self._chain(target, source)
        dynamic = [f for f in a + b if not self._links[f].static]
        if not dynamic:
            return None
        child = min(dynamic, key=lambda f: self._links[f].samples[-1][0])
        link = self._links[child]
        return link.parent, child, link.samples[-1][0]

    def lookup(self, target: str, source: str, time_s: float | None = None) -> Transform:
        """T_target_source at ``time_s`` (None: the latest time the chain is known at).

        Raises:
            FrameNotFound, NotConnected, ExtrapolationError: why it cannot be given.
        """
        if target == source:
            if target not in self.frames():
                raise FrameNotFound(f"frame {target!r} does not exist")
            return Transform()
        up_t, up_s = self._chain(target, source)
        if time_s is None:
            time_s = self.latest_common_time(target, source)
        t = 0.0 if time_s is None else time_s

        def to_common(chain: list[str]) -> Transform:
            tf = Transform()  # T_common_frame, built from the common ancestor down
            for f in reversed(chain):
                tf = tf.compose(self._links[f].at(t, f))
            return tf

        return to_common(up_t).inverse().compose(to_common(up_s))

    def can_transform(self, target: str, source: str, time_s: float | None = None) -> bool:
        try:
            self.lookup(target, source, time_s)
        except TfError:
            return False
        return True


def map_to_odom(map_pose: Pose2D, odom_pose: Pose2D) -> Transform:
    """T_map_odom that puts the robot at ``map_pose`` when odometry says ``odom_pose``
    (what a localisation such as AMCL publishes: map -> odom absorbs the drift)."""
    return Transform.from_pose2d(map_pose).compose(Transform.from_pose2d(odom_pose).inverse())


class PendingLookup:
    """A lookup that may wait for its transforms up to ``timeout_s`` (of the node's clock).

    A node calls :meth:`poll` from its callbacks instead of blocking: it gives the
    transform once it can be had, None while it cannot and the timeout has not run out,
    and raises :class:`TfTimeout` after that (the next poll starts a new wait).
    """

    def __init__(
        self,
        buffer: TfBuffer,
        target: str,
        source: str,
        timeout_s: float,
    ):
        if not timeout_s >= 0:
            raise ValueError(f"timeout_s must be >= 0, got {timeout_s!r}")
        self.buffer, self.target, self.source = buffer, target, source
        self.timeout_s = float(timeout_s)
        self._since_s: float | None = None

    def poll(self, now_s: float, time_s: float | None = None) -> Transform | None:
        """T_target_source at ``time_s`` (None: latest), None while waiting.

        Raises:
            TfTimeout: still missing ``timeout_s`` after the first poll that missed it.
        """
        try:
            tf = self.buffer.lookup(self.target, self.source, time_s)
        except TfError as err:
            if self._since_s is None:
                self._since_s = now_s
            if now_s - self._since_s >= self.timeout_s:
                waited = now_s - self._since_s
                self._since_s = None
                raise TfTimeout(
                    f"no transform {self.target} <- {self.source} after {waited:.2f} s: {err}"
                ) from err
            return None
        self._since_s = None
        return tf

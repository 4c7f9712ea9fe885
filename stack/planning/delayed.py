"""A deterministic upper bound from delayed state revelation (issue 12).

In the case study (a :class:`~stack.planning.momdp_model.MixedModel`) the person's dynamics
and observations depend neither on the robot nor on the action. Relax the problem by
*telling* the robot, at every step t, the person's true state two steps back,
y_{t-2}. A policy of the real problem is a policy of the relaxed one, so the relaxed
optimum W2 bounds V* from above at every belief. The fast informed bound is the same
construction with the state one step back revealed (Hauskrecht 2000): each step of
delay takes information away from the relaxation, and the bound comes down. On task
r1: QMDP (the current state revealed) 224.8, the fast informed bound 199.85, this
bound 195.8; the optimum lies near 195.0 (the dual bound, docs/BENCHMARKS.md).

With y_{t-2} revealed, what the robot knows at t is J = (y_{t-2}, z_{t-1}, z_t), and
J evolves as a Markov chain whatever the robot does: J -> (y_{t-1}, z_t, z_{t+1})
with probability P(y_{t-1}, z_{t+1} | J). W2 solves a Bellman equation on (x, J):
13 cells x 65 x 169 x 169 = 24 M values in the task. A sweep is two products with
the (y, z1) x y1 matrix TY[y, y1] OY[y1, z1] and a robot step:

    T2[x', y1, z2]  = sum_z3 P(z2, z3 | y1) W[x', y1, z2, z3]
    U[x', J]        = sum_y1 TY[y, y1] OY[y1, z1] T2[x', y1, z2] / P(z1, z2 | y)
    (H W)[x, J]     = max_a  E[R(x, y_t, a) | J] + gamma sum_x' P(x' | x, a) U[x', J]

The first two steps from the root (nothing revealed yet) are backed up on the true
beliefs (:meth:`DelayedBound.at`).

**Certified.** The sweeps run in float32 (half the time and memory of float64) and
are accelerated: plain sweeps from the fast informed bound's values, one
extrapolation along the last step, then upward sweeps W <- max(W, H W). None of that
needs to be exact, because the result is *certified* in float64: for any table W,
if H W <= W + eps everywhere then W2 <= W + eps / (1 - gamma) (H is monotone and a
gamma-contraction), so the bound at a root is its value on W plus
gamma^2 eps / (1 - gamma). The certificate is one float64 sweep.

Pure numpy; :func:`delayed_bound` runs under a deadline on the solvers' clock and can
run in a thread beside the search (numpy releases the GIL in these products).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from stack.planning import clock
from stack.planning.momdp_model import MixedModel

# a (y, z1, z2) whose probability P(z1, z2 | y) is below this is left out of the float32
# sweeps (1 / P would overflow float32); the float64 certificate covers every J
_TINY = 1e-30
PLAIN_SWEEPS = 20  # from the fast informed bound's values, before the extrapolation
# the bound's set-up alone takes ~3-8 s, a sweep 0.3-3 s: a --time-limit of 20 s at
# least (19.6 s left after the 2 % kept for writing)
DELAYED_MIN_S = 19.5
DELAYED_END_SHARE = 0.05  # of the time limit: the worker ends this much before the search
_CHUNK = 16384  # columns of J per product in a sweep's robot step
MAX_UPWARD = 30  # upward sweeps in a cycle at most
MAX_CYCLES = 8
JUMP_EVERY = 8  # upward sweeps between extrapolations of the rises
JUMP_RHO = 0.95  # the largest decay rate of the rises an extrapolation assumes
UP_TOL = 1e-5  # an upward phase ends when H W - W is at most this everywhere


@dataclass(frozen=True)
class DelayedResult:
    """The certified bound at each root, and how it was reached."""

    upper: np.ndarray  # (roots,) certified upper bounds on V* at each root (x, b)
    eps: float  # max (H W - W) in float64: the certificate's residual
    sweeps: int
    seconds: float

    def summary(self) -> dict:
        return {
            "delayed_upper": float(self.upper[0]),
            "delayed_eps": self.eps,
            "delayed_sweeps": self.sweeps,
            "delayed_seconds": self.seconds,
        }


class DelayedBound:
    """The tables of the delay-2 relaxation of a mixed model (see the module text).

    Args:
        m: the model (hidden factor y with its own dynamics and observations).
        Q: (X, Y, A) the fast informed bound (any table above its fixed point: the
            start of the sweeps; the certificate does not rely on it).
    """

    def __init__(self, m: MixedModel, Q: np.ndarray):
        self.m = m
        X, Y, A = m.R.shape
        Z = m.OY.shape[1]
        self.shape = (X, Y, Z)
        TY, OY = m.TY, m.OY
        self.K1 = TY[:, :, None] * OY[None, :, :]  # [y, y1, z1]
        self.K1f = np.ascontiguousarray(self.K1.transpose(0, 2, 1).reshape(Y * Z, Y))
        self.pz = TY @ OY  # [y, z]: P(next observation | y)
        self.P12 = (self.K1f @ self.pz).reshape(Y, Z, Z)  # P(z1, z2 | y)
        p = self.P12.reshape(Y * Z, Z)
        self.inv64 = np.where(p > 0, 1.0 / np.where(p > 0, p, 1.0), 0.0)
        # the sweeps' float32 tables
        self.live32 = p > _TINY
        self.inv32 = np.where(self.live32, self.inv64, 0.0).astype(np.float32)
        self.K1f32 = self.K1f.astype(np.float32)
        self.P12_32 = self.P12.astype(np.float32)
        # [(x, a), x']: P(x' | x, a), a row per (cell, action)
        self.TXall32 = np.ascontiguousarray(
            m.TX.transpose(1, 0, 2).reshape(X * A, X).astype(np.float32)
        )
        # E[R(x, y2, a) | y1, z2] * P(z2 | y1): [x, a, y1, z2]
        M2 = TY[:, None, :] * OY.T[None, :, :]  # [y1, z2, y2]
        self.RRp = np.einsum("kzy,xya->xakz", M2, m.R, optimize=True)
        # the start: E[V1(x, y_{t-1}, z_t) | J], V1 the delay-1 (fast informed) value
        post1 = self.K1 / np.maximum(self.K1.sum(1, keepdims=True), 1e-300)  # [y, y', z]
        V1 = np.einsum("ykz,xka->xyza", post1, Q, optimize=True).max(axis=3)  # [x, y1, z2]
        self.start = self._expect(self.pz[None] * V1, np.float64)  # (X, Y*Z, Z)
        self._roots: dict = {}

    # -- the operator ----------------------------------------------------------------
    def _expect(self, F: np.ndarray, dt) -> np.ndarray:
        """sum_y1 K1f[(y,z1), y1] F[x, y1, z2] / P(z1, z2 | y) for every x: (X, Y*Z, Z).
        F must already carry P(z2 | y1) (it is a joint weight over (y1, z2))."""
        X, Y, Z = self.shape
        G = F.transpose(1, 0, 2).reshape(Y, -1).astype(dt)
        K1f, inv = (self.K1f, self.inv64) if dt == np.float64 else (self.K1f32, self.inv32)
        out = (K1f @ G).reshape(Y * Z, X, Z).transpose(1, 0, 2)
        return np.ascontiguousarray(out) * inv[None]

    def _q64(self, W: np.ndarray, x: int):
        """(a, (H_a W)[x, :, :]) for every action a, in float64 (W: (X, Y*Z, Z))."""
        X, Y, Z = self.shape
        m = self.m
        T2 = (self.P12[None] * W.reshape(X, Y, Z, Z)).sum(axis=3)  # [x', y1, z2]
        for a in range(m.A):
            C = self.RRp[x, a] + m.discount * np.tensordot(m.TX[a, x], T2, axes=1)
            yield a, (self.K1f @ C) * self.inv64

    def relative_rewards32(self) -> np.ndarray:
        """(H_a W0 - W0)[x, J] for the start W0, (X, A, Y*Z, Z) float32 (484 MB in the
        task). The sweeps run on D = W - W0: small numbers, where float32 is exact
        enough (W itself reaches -3,000 in the cell outside the map, where a float32
        step is 2.4e-4 and its rounding alone would cost the certificate 0.3)."""
        X, Y, Z = self.shape
        W0 = self.start
        Rb = np.zeros((X, self.m.A, Y * Z, Z), dtype=np.float32)
        for x in range(X):
            for a, q in self._q64(W0, x):
                Rb[x, a] = np.where(self.live32, q - W0[x], 0.0)
        return Rb

    def sweep32(self, W: np.ndarray, Rb: np.ndarray) -> np.ndarray:
        """H W in float32 (W: (X, Y*Z, Z) float32)."""
        X, Y, Z = self.shape
        g = np.float32(self.m.discount)
        T2 = (self.P12_32[None] * W.reshape(X, Y, Z, Z)).sum(axis=3)  # [x', y1, z2]
        U = self._expect(T2, np.float32)
        U *= g
        Uf = U.reshape(X, -1)
        Rbf = Rb.reshape(X, self.m.A, -1)
        out = np.empty((X, Uf.shape[1]), dtype=np.float32)
        # in column chunks, every (cell, action) at once: U is read once a sweep (a
        # product per cell read it 13 times: 0.33 -> 0.18 s a sweep on the task)
        n = Uf.shape[1]
        for s in range(0, n, _CHUNK):
            e = min(n, s + _CHUNK)
            q = (self.TXall32 @ Uf[:, s:e]).reshape(X, self.m.A, e - s)
            q += Rbf[:, :, s:e]
            q.max(axis=1, out=out[:, s:e])
        return out.reshape(W.shape)

    def residual64(self, W: np.ndarray) -> float:
        """max over every J with P(J) > 0 of (H W - W)[x, J], in float64."""
        X, Y, Z = self.shape
        live = self.inv64 > 0
        eps = -math.inf
        for x in range(X):
            best = np.full((Y * Z, Z), -np.inf)
            for _, q in self._q64(W, x):
                np.maximum(best, q, out=best)
            r = (best - W[x])[live]
            if not np.isfinite(r).all():  # e.g. 1 / P(J) overflowed: nothing certified
                return math.inf
            if r.size:
                eps = max(eps, float(r.max()))
        return eps

    def at(self, D: np.ndarray, x: int, b: np.ndarray) -> float:
        """The bound at the root (x, b) from the table W = start + D of the relaxation:
        two steps of the true belief's Bellman operator, then W at J = (y0, z1, z2).
        (The part of W at the root's grandchildren is linear in W: the start's share is
        computed once per root, in float64; a float32 D gives an estimate.)"""
        X, Y, Z = self.shape
        m = self.m
        g = m.discount
        b = np.asarray(b, dtype=float)
        key = (x, b.tobytes())
        if key not in self._roots:
            pr1 = np.einsum("y,ykz->kz", b, self.K1)  # [y1, z1]: P(y1, z1)
            Pz1 = pr1.sum(axis=0)
            ok = Pz1 > 0
            d = np.where(ok, Pz1, 1.0)
            w = b[:, None, None] * self.P12 / d[None, :, None]  # P(y0, z2 | z1)
            U1 = np.einsum("yzw,xyzw->xz", w, self.start.reshape(X, Y, Z, Z))
            R1 = np.einsum("kz,xka->xza", pr1, m.R) / d[None, :, None]
            self._roots[key] = (w, U1, R1, Pz1, ok)
        w, U1, R1, Pz1, ok = self._roots[key]
        D4 = D.reshape(X, Y, Z, Z)
        U1 = U1 + np.einsum("yzw,xyzw->xz", w.astype(D4.dtype), D4).astype(np.float64)
        V1 = (R1 + g * np.einsum("axk,kz->xza", m.TX, U1)).max(axis=2)  # [x', z1]
        U0 = V1[:, ok] @ Pz1[ok]
        return float((b @ m.R[x] + g * m.TX[:, x, :] @ U0).max())


def delayed_bound(
    m: MixedModel,
    Q: np.ndarray,
    roots: list[tuple[int, np.ndarray]],
    deadline: float = math.inf,
    progress: Callable[[str], None] | None = None,
    stop: threading.Event | None = None,
    plain: int = PLAIN_SWEEPS,
    upward: int = MAX_UPWARD,
) -> DelayedResult | None:
    """The certified delay-2 upper bound at each root (x, person belief).

    Runs cycles of plain sweeps, an extrapolation and upward sweeps in float32 while
    time allows (each sweep is timed; the float64 certificate is kept time for), then
    certifies the table with the best float32 estimate. None when not even the
    certificate fits before ``deadline``. ``stop`` (set from another thread) ends the
    sweeps early: the table reached is certified.
    """
    t0 = clock.now()
    db = DelayedBound(m, Q)
    s0 = clock.now()
    Rb = db.relative_rewards32()
    # the certificate is the same float64 work as the relative rewards
    certify_s = 1.2 * (clock.now() - s0)
    if clock.now() + 1.5 * certify_s > deadline:
        return None
    g = m.discount
    W = np.zeros(db.start.shape, dtype=np.float32)  # the sweeps' D = W - start
    sweep_s = 0.0
    times: list[float] = []
    sweeps = 0

    def time_left(k: float) -> bool:
        # k more float32 sweeps and the certificate before the deadline
        if stop is not None and stop.is_set():
            return False
        return clock.now() + k * sweep_s + certify_s < deadline

    best: tuple[float, np.ndarray] = (math.inf, W)

    def keep_if_best(D: np.ndarray, HD: np.ndarray) -> tuple[float, float]:
        """The float32 estimate of D's certified bound at the first root (D kept if it
        is the best so far) and D's residual max (H D - D)."""
        nonlocal best
        eps32 = float((HD - D).max())  # 0 where float32 skips J (D stays 0 there)
        est = db.at(D, *roots[0]) + g * g * max(eps32, 0.0) / (1 - g)
        if est < best[0]:
            best = (est, D)
        return est, eps32

    def sweep(D: np.ndarray) -> np.ndarray:
        nonlocal sweeps, sweep_s
        s0 = clock.now()
        out = db.sweep32(D, Rb)
        sweeps += 1
        times.append(clock.now() - s0)
        sweep_s = max(times[-3:])
        return out

    for cycle in range(MAX_CYCLES):
        # down: value iteration from a supersolution stays one (each table a bound)
        step = None
        for _ in range(plain if cycle == 0 else plain // 2):
            if sweeps and not time_left(1):
                break
            HW = sweep(W)
            est, _ = keep_if_best(W, HW)
            HW = np.minimum(HW, W)
            step = W - HW
            W = HW
            if progress is not None and sweeps % 5 == 0:
                progress(f"delayed bound: down sweep {sweeps}, estimate {est:.3f}")
        if step is None:
            break
        # value iteration's error decays by about gamma a sweep (the slowest mode of
        # a discounted chain): jump to the geometric series' limit, below the
        # fixed point in places
        W = W - np.float32(g / (1.0 - g)) * step
        # up: W <- max(W, H W) until W is (nearly) a supersolution again; every
        # JUMP_EVERY sweeps the rises, which decay geometrically, are extrapolated
        prev = None
        for k in range(upward):
            if not time_left(1):
                break
            HW = sweep(W)
            est, eps32 = keep_if_best(W, HW)
            rise = np.maximum(HW - W, 0.0)
            total = float(rise.sum(dtype=np.float64))
            W = W + rise
            if k % JUMP_EVERY == JUMP_EVERY - 1 and prev:
                rho = min(JUMP_RHO, total / prev)
                W += np.float32(rho / (1.0 - rho)) * rise
            prev = total
            if progress is not None and sweeps % 5 == 0:
                progress(f"delayed bound: up sweep {sweeps}, estimate {est:.3f}")
            if eps32 < UP_TOL:
                break
        if not time_left(plain // 2 + 10):
            break
    if clock.now() + certify_s > deadline and sweeps:
        return None
    D = best[1].astype(np.float64)
    W64 = db.start + D
    eps = db.residual64(W64)
    # plus float64's own rounding in the residual (~1e-13 |W|; 3e-8 on the task)
    eps = max(eps, 0.0) + 1e-12 * float(np.abs(W64).max())
    c = g * g * eps / (1 - g)
    upper = np.array([db.at(D, x, b) + c for x, b in roots])
    if not np.isfinite(upper).all():
        return None
    return DelayedResult(upper, eps, sweeps, clock.now() - t0)


class DelayedWorker:
    """The delayed bound (stack/planning/delayed.py) in a thread beside the search: it
    starts from the search's fast informed bound, ends by the search's deadline, and
    caps the roots' upper bounds (the search takes them at its next stopping check)."""

    def __init__(self, search, deadline: float, grace: float, progress):
        self.result: DelayedResult | None = None
        self.error = ""
        self.deadline = deadline
        self.grace = grace  # how long past the deadline finish() waits for the thread
        self.stop = threading.Event()
        self.thread = threading.Thread(
            target=self._run, args=(search, progress), name="delayed-bound", daemon=True
        )

    @classmethod
    def start(cls, search, time_limit_s: float | None, progress) -> DelayedWorker | None:
        """A started worker for a :class:`~stack.planning.momdp.MixedSearch` whose time
        limit is ``time_limit_s``; None, with the search's ``delayed_note`` saying why,
        without a limit or with one too short for the bound."""
        if time_limit_s is None:
            # its sweeps end with the search: without a time limit the bound would
            # depend on the machine's speed, and a solve by trials is deterministic
            search.delayed_note = "delayed bound: only under a time limit"
            return None
        if time_limit_s < DELAYED_MIN_S:
            search.delayed_note = (
                f"delayed bound: needs a time limit of {DELAYED_MIN_S:.0f} s or more, "
                f"got {time_limit_s:.1f} s"
            )
            return None
        # done before the search's end less the time it keeps for writing its policy
        end = DELAYED_END_SHARE * time_limit_s
        w = cls(search, search.deadline - end, end, progress)
        w.thread.start()
        return w

    def _run(self, search, progress) -> None:
        try:
            roots = [(r.x, r.node.b) for r in search.roots]
            self.result = delayed_bound(
                search.m,
                search.Q_upper,
                roots,
                deadline=self.deadline,
                progress=progress,
                stop=self.stop,
            )
            if self.result is None:
                self.error = "delayed bound: not certified within the time limit"
            else:
                search.root_caps = self.result.upper  # the search applies them
        except MemoryError:
            self.error = "delayed bound: out of memory (~2 GB for the process on the task)"
        except Exception as e:  # reported in the result, never lost with the thread
            self.error = f"delayed bound: failed: {type(e).__name__}: {e}"

    def finish(self, search):
        """(DelayedResult or None, note) once the thread is done; the caps applied. A
        search that ended first (trials, gap) stops the sweeps: the table reached is
        certified (a few seconds), not swept on to the deadline."""
        self.stop.set()
        # the worker ends by its deadline; one still running after a grace period (a
        # machine far slower than measured) is left behind, its bound not taken
        self.thread.join(timeout=max(1.0, self.grace + self.deadline - clock.now()))
        if self.thread.is_alive():
            return None, "delayed bound: not certified within the time limit"
        if self.result is not None:
            search.root_caps = self.result.upper  # again: a cap is taken at most once
            bad = search.take_root_caps()
            if bad:
                return None, bad
        return self.result, self.error

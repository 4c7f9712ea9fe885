"""Write a RockSample[N, K] model as a Cassandra ``.pomdp`` file.

The text has the form of the RockSample files in ../shared/pomdp/ (Trey Smith's
generator, as distributed with ZMDP): states ``s<x><y><rock_0>...<rock_{K-1}>`` with x
varying slowest, then y, then the rocks (rock 0 the most significant bit, 1 = good),
and one terminal state ``st`` last; actions ``amn ame ams amw ac0 .. ac{K-1} as``;
observations ``ogood obad``. Moving east off the grid ends the episode with +10; moving
off any other edge, or sampling where there is no rock, ends it with -100; sampling a
good rock earns +10 and makes it bad, a bad one costs -10. A check of rock i at
distance d reads right with probability (1 + eta) / 2, eta = 2^(-d / d0). The start
belief is the start square with every rock good or bad at random (uniform).

The standard instances use the published rock positions, start square and d0
(``STANDARD``); RockSample_4_4's file uses eta = e^-d (d0 = ln 2). Other sizes place
the rocks at distinct random squares (``--seed``), start at (0, N // 2), d0 = 20.

    python bench/gen_rocksample.py 7 8 -o /tmp/RockSample_7_8.pomdp

Generated 4_4 and 5_7 are byte for byte the files in ../shared/pomdp/
(tests/test_heldout_rocksample.py).
"""

from __future__ import annotations

import argparse
import io
import math
import random
import sys
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class RockSample:
    n: int  # grid side
    rocks: tuple[tuple[int, int], ...]  # (x, y) of each rock
    start: tuple[int, int]
    half_efficiency: float  # d0: the check's efficiency halves every d0 squares
    numbered: bool  # states/actions/observations as counts (5_7) or names (4_4)

    @property
    def k(self) -> int:
        return len(self.rocks)

    @property
    def n_states(self) -> int:
        return self.n * self.n * 2**self.k + 1


# The published instances (Smith & Simmons 2004; SARSOP's RockSample_7_8.pomdpx and
# RockSample_11_11.pomdpx for the two larger ones).
STANDARD: dict[tuple[int, int], RockSample] = {
    (4, 4): RockSample(4, ((3, 1), (2, 1), (1, 3), (1, 0)), (0, 2), math.log(2), False),
    (5, 7): RockSample(
        5, ((1, 0), (2, 1), (1, 2), (2, 2), (4, 2), (0, 3), (3, 4)), (0, 2), 20.0, True
    ),
    (7, 8): RockSample(
        7, ((2, 0), (0, 1), (3, 1), (6, 3), (2, 4), (3, 4), (5, 5), (1, 6)), (0, 3), 20.0, True
    ),
    (11, 11): RockSample(
        11,
        ((0, 3), (0, 7), (1, 8), (2, 4), (3, 3), (3, 8), (4, 3), (5, 8), (6, 1), (9, 3), (9, 9)),
        (0, 5),
        20.0,
        True,
    ),
}


def instance(n: int, k: int, seed: int = 0) -> RockSample:
    """The standard instance for (n, k), else k rocks at distinct random squares."""
    if n < 1 or k < 0:
        raise ValueError(f"RockSample[{n}, {k}]: need n >= 1 and k >= 0")
    if (n, k) in STANDARD:
        return STANDARD[(n, k)]
    if k > n * n:
        raise ValueError(f"RockSample[{n}, {k}]: {k} rocks do not fit on {n * n} squares")
    squares = [(x, y) for x in range(n) for y in range(n)]
    rocks = tuple(random.Random(seed).sample(squares, k))
    return RockSample(n, rocks, (0, n // 2), 20.0, True)


def format_rocksample(m: RockSample) -> str:
    """The ``.pomdp`` text of a RockSample instance."""
    n, k = m.n, m.k
    if not m.numbered and n > 10:
        raise ValueError("named states s<x><y>... need a grid of at most 10 x 10")
    n_rock_states = 2**k
    terminal = n * n * n_rock_states
    acts = ["amn", "ame", "ams", "amw", *[f"ac{i}" for i in range(k)], "as"]
    if m.numbered:
        sname = [str(i) for i in range(terminal + 1)]
        aname = [str(i) for i in range(len(acts))]
        good, bad = "0", "1"
    else:
        sname = [
            f"s{x}{y}{r:0{k}b}" if k else f"s{x}{y}"
            for x in range(n)
            for y in range(n)
            for r in range(n_rock_states)
        ] + ["st"]
        aname = acts
        good, bad = "ogood", "obad"
    sname[terminal] = "st" if not m.numbered else str(terminal)
    rock_at = {pos: i for i, pos in enumerate(m.rocks)}
    d0 = m.half_efficiency

    out = io.StringIO()
    w = out.write
    w("# state naming convention: s <x> <y> <rock_0> <rock_1> .. <rock_{n-1}>\n")
    w("# action naming convention:\n")
    w("#   amn, ame, ams, amw: move in the cardinal directions\n")
    w('#   ac0, ac1 .. ac{n-1}: do the "check" action on the indicated rock\n')
    w("#   as: sample the rock in the robot's square\n")
    w("# observation naming convention:\n")
    w('#   ogood, obad: the check sensor is indicating a "good" or "bad" reading\n')
    w("#                for the rock.  actions other than check always return ogood.\n")
    w(f"# initial position is: ({m.start[0]}, {m.start[1]})\n")
    w("# rock positions are: " + "".join(f"({x},{y}) " for x, y in m.rocks) + "\n")
    w("\ndiscount: 0.95\nvalues: reward\n")
    if m.numbered:
        w(f"actions: {len(acts)}\nobservations: 2\nstates: {terminal + 1}\n\n")
    else:
        w(f"actions: {' '.join(acts)}\nobservations: ogood obad\n\n")
        w(f"states: {' '.join(sname)}\n\n")
    p0 = 1.0 / n_rock_states
    first = (m.start[0] * n + m.start[1]) * n_rock_states
    w(
        "start: "
        + " ".join(
            f"{p0:g}" if first <= s < first + n_rock_states else "0" for s in range(terminal + 1)
        )
        + "\n\n"
    )
    w(f"# E: {sname[terminal]}\n\n")

    def entry(a: int, s: int, nxt: int, reward: float, obs: list[tuple[str, float]]) -> None:
        if reward:
            w(f"R: {aname[a]:<3} : {sname[s]:<10} : * : * {reward:f}\n")
        w(f"T: {aname[a]:<3} : {sname[s]:<10} : {sname[nxt]:<10} {1.0:f}\n")
        for z, p in obs:
            w(f"O: {aname[a]:<3} : {sname[s]:<10} : {z:<10} {p:f}\n")
        w("\n")

    always_good = [(good, 1.0)]
    for x in range(n):
        for y in range(n):
            here = (x * n + y) * n_rock_states
            for r in range(n_rock_states):
                s = here + r
                # moves: north, east, south, west
                entry(0, s, s + n_rock_states if y + 1 < n else terminal,
                      0.0 if y + 1 < n else -100.0, always_good)  # fmt: skip
                entry(1, s, s + n * n_rock_states if x + 1 < n else terminal,
                      0.0 if x + 1 < n else 10.0, always_good)  # fmt: skip
                entry(2, s, s - n_rock_states if y > 0 else terminal,
                      0.0 if y > 0 else -100.0, always_good)  # fmt: skip
                entry(3, s, s - n * n_rock_states if x > 0 else terminal,
                      0.0 if x > 0 else -100.0, always_good)  # fmt: skip
                for i, (rx, ry) in enumerate(m.rocks):
                    is_good = (r >> (k - 1 - i)) & 1
                    eta = 2.0 ** (-math.hypot(rx - x, ry - y) / d0)
                    right = 0.5 + 0.5 * eta
                    p_good = right if is_good else 1.0 - right
                    entry(4 + i, s, s, 0.0, [(good, p_good), (bad, 1.0 - p_good)])
                i = rock_at.get((x, y))
                if i is None:
                    entry(4 + k, s, terminal, -100.0, always_good)
                elif (r >> (k - 1 - i)) & 1:
                    entry(4 + k, s, s - (1 << (k - 1 - i)), 10.0, always_good)
                else:
                    entry(4 + k, s, s, -10.0, always_good)
    for a in range(len(acts)):
        entry(a, terminal, terminal, 0.0, always_good)
    return out.getvalue()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("n", type=int, help="grid side")
    ap.add_argument("k", type=int, help="number of rocks")
    ap.add_argument("--seed", type=int, default=0, help="rock positions of a non-standard size")
    ap.add_argument("-o", "--output", help="file to write (default: stdout)")
    args = ap.parse_args(argv)
    try:
        m = instance(args.n, args.k, args.seed)
    except ValueError as exc:
        print(f"gen_rocksample: {exc}", file=sys.stderr)
        return 2
    if m.n_states > 200_000:
        print(f"gen_rocksample: {m.n_states:,} states is more than a .pomdp reader takes",
              file=sys.stderr)  # fmt: skip
        return 2
    text = format_rocksample(m)
    if args.output:
        Path(args.output).write_text(text, encoding="utf-8")
        print(f"{args.output}: RockSample[{m.n}, {m.k}], {m.n_states:,} states", file=sys.stderr)
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())

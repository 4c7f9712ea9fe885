"""The task POMDP of chapter 3: factored tables and the flat model built from them.

State variables (table 3.1): the robot's cell R (p cells + out of the map) and,
per person i, a position P_i (p cells + no person) and a direction D_i
(North, South, East, West, Not moving). Actions (table 3.2): North, South, East,
West, Do nothing. Observations (table 3.3): the robot's cell (exact, section
3.2.4), per person a cell (p + no person) and a velocity (not moving + 4
directions x 3 speed classes, section 4.2).

The factored form keeps one table per variable; the flat form multiplies them
out into the :class:`~stack.planning.pomdp.POMDP` the solvers use. Flat index
order is (R, P_1, D_1, ..., P_n, D_n) with R slowest, and likewise
(O_R, O_P1, O_V1, ...) for observations.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import reduce

import numpy as np
import scipy.sparse as sp

from stack.cells import MOVING_DIRECTIONS, Direction
from stack.planning.pomdp import POMDP, ModelError
from stack.planning.task import DIRECTION_NAMES, Task
from stack.vocabulary import (  # the labels are defined once, there
    ACTIONS,
    NO_PERSON,
    OUT_OF_MAP,
    SPEED_CLASSES,
    VELOCITIES,
)

ACTION_DIRECTIONS = (Direction.NORTH, Direction.SOUTH, Direction.EAST, Direction.WEST, None)


class ModelSizeError(ModelError):
    """The flat model would be too large to hold in memory."""


def velocity_index(direction: Direction | str, speed: str | None = None) -> int:
    """Index of a velocity observation: ``velocity_index("East", "higher")``.

    ``Not moving`` (or Direction.NOT_MOVING) is index 0.
    """
    if isinstance(direction, str):
        label = direction if speed is None else f"{direction} {speed}"
        try:
            return VELOCITIES.index(label)
        except ValueError:
            raise KeyError(f"unknown velocity observation {label!r}; known: {VELOCITIES}") from None
    if direction == Direction.NOT_MOVING:
        return 0
    return 1 + 3 * int(direction) + SPEED_CLASSES.index(speed or "higher")


def direction_index(name: str) -> int:
    key = name.lower().replace("_", " ")
    try:
        return DIRECTION_NAMES.index(key)
    except ValueError:
        raise KeyError(f"unknown direction {name!r}; known: {DIRECTION_NAMES}") from None


@dataclass(frozen=True, eq=False)
class FactoredModel:
    """One table per variable (the dynamic Bayesian network of figure 3.1).

    Shapes (p cells; Rn = p + 1 robot values; Pn = p + 1 person positions):
        robot_T[a, r, r']       P(R' | R, A)
        direction_T[d, d']      P(D' | D)
        position_T[x, d, x']    P(P' | P, D)
        obs_position[x', z]     P(O_P | P')
        obs_velocity[x', d', z] P(O_V | P', D')
        guard[k, x, d]          person (x, d) makes restricted cell k worth guarding (table 4.1)
    """

    task: Task
    robot_T: np.ndarray
    direction_T: np.ndarray
    position_T: np.ndarray
    obs_position: np.ndarray
    obs_velocity: np.ndarray
    guard: np.ndarray

    # -- sizes and labels ------------------------------------------------------
    @property
    def n_cells(self) -> int:
        return self.task.grid.n_cells

    @property
    def people(self) -> int:
        return self.task.people

    @property
    def state_shape(self) -> tuple[int, ...]:
        p1 = self.n_cells + 1
        return (p1,) + (p1, 5) * self.people

    @property
    def obs_shape(self) -> tuple[int, ...]:
        p1 = self.n_cells + 1
        return (p1,) + (p1, len(VELOCITIES)) * self.people

    @property
    def n_states(self) -> int:
        return int(np.prod(self.state_shape))

    @property
    def n_observations(self) -> int:
        return int(np.prod(self.obs_shape))

    def robot_label(self, r: int) -> str:
        return OUT_OF_MAP if r == self.n_cells else str(r + 1)

    def position_label(self, x: int) -> str:
        return NO_PERSON if x == self.n_cells else str(x + 1)

    # -- indices ---------------------------------------------------------------
    def robot_index(self, cell: int | None) -> int:
        """Robot value index of a cell (None: out of the map)."""
        return self.n_cells if cell is None else self.task.grid.cells.index(cell)

    def position_index(self, cell: int | None) -> int:
        """Person position index of a cell (None: no person)."""
        return self.n_cells if cell is None else self.task.grid.cells.index(cell)

    def state_index(self, robot: int | None, persons: list[tuple[int | None, str]]) -> int:
        idx = [self.robot_index(robot)]
        for cell, direction in persons:
            idx += [self.position_index(cell), direction_index(direction)]
        return int(np.ravel_multi_index(idx, self.state_shape))

    def observation_index(self, robot: int | None, persons: list[tuple[int | None, str]]) -> int:
        """Flat observation index from (robot cell, [(person cell, velocity label)])."""
        idx = [self.robot_index(robot)]
        for cell, velocity in persons:
            idx += [self.position_index(cell), velocity_index(velocity)]
        return int(np.ravel_multi_index(idx, self.obs_shape))

    def robot_blocks(self) -> np.ndarray:
        """(n_states,) the robot index of every flat state: the blocks the observations
        reveal (every observation names the robot's cell), for the lookahead's
        per-block vectors (:class:`stack.planning.pbvi.BlockVectors`)."""
        return np.unravel_index(np.arange(self.n_states), self.state_shape)[0]

    def decode_state(self, s: int) -> tuple[int, list[tuple[int, int]]]:
        """(robot index, [(position index, direction index)]) of a flat state."""
        idx = np.unravel_index(int(s), self.state_shape)
        return int(idx[0]), [(int(idx[1 + 2 * i]), int(idx[2 + 2 * i])) for i in range(self.people)]

    def initial_belief(
        self,
        robot: int | None = None,
        persons: list[tuple[int | None, str]] | None = None,
    ) -> np.ndarray:
        """A certain initial belief (chapter 5: "all experiments assumed initial states
        with complete certainty"), by default the task file's ``initial`` section."""
        ini = self.task.initial
        robot = ini.robot if robot is None else robot
        if persons is None:
            persons = [(ini.person, ini.direction)] * self.people
        b = np.zeros(self.n_states)
        b[self.state_index(robot, persons)] = 1.0
        return b

    # -- the reward --------------------------------------------------------------
    def reward_table(self) -> np.ndarray:
        """R over (R, P_1, D_1, ..., P_n, D_n, A): table 4.1 plus the move cost."""
        t = self.task
        rw = t.rewards
        p = self.n_cells
        shape = self.state_shape
        base = np.full(p + 1, rw.other_cell)
        base[p] = rw.out_of_map
        base[self.robot_index(t.rest_cell)] = rw.rest_cell
        R = np.broadcast_to(base.reshape((-1,) + (1,) * (len(shape) - 1)), shape).copy()
        for k, cell in enumerate(t.restricted_cells):
            # any person guarding-worthy makes the visit worth it
            guarded = np.zeros(shape[1:], dtype=bool)
            for i in range(self.people):
                g = self.guard[k]
                expand = [1] * (2 * self.people)
                expand[2 * i], expand[2 * i + 1] = g.shape
                guarded |= g.reshape(expand)
            R[self.robot_index(cell)] = np.where(guarded, rw.restricted_guarded, rw.restricted_idle)
        move = np.array([rw.move if d is not None else 0.0 for d in ACTION_DIRECTIONS])
        return R[..., None] + move

    # -- the flat model ------------------------------------------------------------
    def person_transition(self) -> np.ndarray:
        """P((P', D') | (P, D)) for one person as a (5 Pn, 5 Pn) matrix."""
        Pn = self.n_cells + 1
        M = self.position_T[:, :, :, None] * self.direction_T[None, :, None, :]
        return M.reshape(Pn * 5, Pn * 5)

    def person_observation(self) -> np.ndarray:
        """P((O_P, O_V) | (P', D')) for one person as a (5 Pn, Pn * 13) matrix."""
        Pn = self.n_cells + 1
        V = len(VELOCITIES)
        M = self.obs_position[:, None, :, None] * self.obs_velocity[:, :, None, :]
        return M.reshape(Pn * 5, Pn * V)

    def flat(self, max_nonzeros: int = 30_000_000, name: str | None = None) -> POMDP:
        """Multiply the factors out into a flat POMDP.

        Raises:
            ModelSizeError: if T or O would hold more than ``max_nonzeros`` entries
                (n = 2 on the 12-cell grid does: track its belief with
                :class:`~stack.planning.belief.FactoredBelief` instead).
        """
        PT = sp.csr_matrix(self.person_transition())
        PO = sp.csr_matrix(self.person_observation())
        n = self.people
        t_nnz = max(sp.csr_matrix(self.robot_T[a]).nnz for a in range(len(ACTIONS))) * PT.nnz**n
        o_nnz = (self.n_cells + 1) * PO.nnz**n
        if max(t_nnz, o_nnz) > max_nonzeros:
            raise ModelSizeError(
                f"the flat model of {n} people on {self.n_cells} cells needs about "
                f"{max(t_nnz, o_nnz):,} non-zeros (limit {max_nonzeros:,}); "
                "use the factored model and FactoredBelief for tracking"
            )
        PTn = reduce(lambda x, y: sp.kron(x, y, format="csr"), [PT] * n)
        POn = reduce(lambda x, y: sp.kron(x, y, format="csr"), [PO] * n)
        T = tuple(
            sp.kron(sp.csr_matrix(self.robot_T[a]), PTn, format="csr") for a in range(len(ACTIONS))
        )
        O_one = sp.kron(sp.identity(self.n_cells + 1, format="csr"), POn, format="csr")
        R = self.reward_table().reshape(self.n_states, len(ACTIONS))
        return POMDP(
            states=self._state_names(),
            actions=tuple(a.replace(" ", "") for a in ACTIONS),
            observations=self._observation_names(),
            T=T,
            O=(O_one,) * len(ACTIONS),
            R=R,
            discount=self.task.discount,
            b0=self.initial_belief(),
            name=name or self.task.name,
        )

    def _state_names(self) -> tuple[str, ...]:
        rob = [f"r{c}" for c in self.task.grid.cells] + ["rout"]
        pos = [f"p{c}" for c in self.task.grid.cells] + ["pnone"]
        dirs = ["n", "s", "e", "w", "nm"]
        names = rob
        for i in range(self.people):
            suffix = "" if self.people == 1 else str(i + 1)
            names = [f"{a}_{b}{suffix}_{d}" for a in names for b in pos for d in dirs]
        return tuple(names)

    def _observation_names(self) -> tuple[str, ...]:
        rob = [f"r{c}" for c in self.task.grid.cells] + ["rout"]
        pos = [f"p{c}" for c in self.task.grid.cells] + ["pnone"]
        vel = [v.lower().replace(" ", "").replace("-", "to").replace(".", "") for v in VELOCITIES]
        names = rob
        for _ in range(self.people):
            names = [f"{a}_{b}_{v}" for a in names for b in pos for v in vel]
        return tuple(names)


# -- building the tables ---------------------------------------------------------------


def build_model(task: Task) -> FactoredModel:
    """Build the factored model of a task (sections 3.2.1-3.2.4, appendix A)."""
    return FactoredModel(
        task=task,
        robot_T=_robot_transition(task),
        direction_T=_direction_transition(task),
        position_T=_position_transition(task),
        obs_position=_position_observation(task),
        obs_velocity=_velocity_observation(task),
        guard=_guard_table(task),
    )


def _robot_transition(task: Task) -> np.ndarray:
    """Figures A.5-A.6: the robot reaches the neighbouring cell with ``move_success``
    (leaving the map at an edge) and stays otherwise; "out of the map" is absorbing."""
    g = task.grid
    p = g.n_cells
    ms = task.robot.move_success
    T = np.zeros((len(ACTIONS), p + 1, p + 1))
    for a, direction in enumerate(ACTION_DIRECTIONS):
        T[a, p, p] = 1.0
        for i, cell in enumerate(g.cells):
            if direction is None:
                T[a, i, i] = 1.0
                continue
            nb = g.neighbour(cell, direction)
            j = p if nb is None else g.cells.index(nb)
            T[a, i, j] += ms
            T[a, i, i] += 1.0 - ms
    return T


def _direction_transition(task: Task) -> np.ndarray:
    """P(D' | D), section 3.2.1: keeping the direction is likeliest, turning back least."""
    m = task.direction
    stop = 1.0 - m.keep - 2 * m.turn - m.reverse
    T = np.zeros((5, 5))
    for d in MOVING_DIRECTIONS:
        for d2 in MOVING_DIRECTIONS:
            if d2 == d:
                T[d, d2] = m.keep
            elif d2 == d.opposite:
                T[d, d2] = m.reverse
            else:
                T[d, d2] = m.turn
        T[d, Direction.NOT_MOVING] = stop
    T[Direction.NOT_MOVING, :4] = (1.0 - m.rest_stay) / 4.0
    T[Direction.NOT_MOVING, Direction.NOT_MOVING] = m.rest_stay
    return T


def _perpendicular(d: Direction) -> tuple[Direction, Direction]:
    if d in (Direction.NORTH, Direction.SOUTH):
        return (Direction.EAST, Direction.WEST)
    return (Direction.NORTH, Direction.SOUTH)


def _position_transition(task: Task) -> np.ndarray:
    """P(P' | P, D), section 3.2.1.

    A resting person most likely stays; a moving person stays in the (large) cell or
    moves ahead, the adjacent cell ahead likelier than two cells ahead. A move into
    a wall keeps the person in the cell, except at the region's open edge where a
    share ``leave_at_edge`` of it leaves the region (no person).
    """
    g = task.grid
    m = task.position
    p = g.n_cells
    none = p
    T = np.zeros((p + 1, 5, p + 1))
    T[none, :, none] = 1.0 - m.enter
    T[none, :, :p] = m.enter / p
    for i, cell in enumerate(g.cells):
        for d in Direction:
            w = np.zeros(p + 1)

            def to(
                target: int | None,
                weight: float,
                edge_leaves: bool = False,
                w: np.ndarray = w,
                i: int = i,
            ) -> None:
                if target is not None:
                    w[g.cells.index(target)] += weight
                elif edge_leaves:
                    w[none] += weight * m.leave_at_edge
                    w[i] += weight * (1.0 - m.leave_at_edge)
                else:
                    w[i] += weight

            if d == Direction.NOT_MOVING:
                w[i] += m.rest_stay
                for d4 in MOVING_DIRECTIONS:
                    to(g.neighbour(cell, d4), m.rest_side, edge_leaves=True)
                for da in (Direction.NORTH, Direction.SOUTH):
                    nb = g.neighbour(cell, da)
                    for db in (Direction.EAST, Direction.WEST):
                        to(None if nb is None else g.neighbour(nb, db), m.rest_diagonal)
            else:
                w[i] += m.moving_stay
                ahead = g.neighbour(cell, d)
                if ahead is None:
                    to(None, m.moving_ahead + m.moving_ahead2, edge_leaves=True)
                else:
                    to(ahead, m.moving_ahead)
                    to(g.neighbour(ahead, d) or ahead, m.moving_ahead2)
                for d4 in MOVING_DIRECTIONS:
                    if d4 != d:
                        to(g.neighbour(cell, d4), m.moving_side)
                for side in _perpendicular(d):
                    to(None if ahead is None else g.neighbour(ahead, side), m.moving_diagonal)
            w /= w.sum()
            row = (1.0 - m.leave - m.floor) * w
            row[none] += m.leave
            row[:p] += m.floor / p
            T[i, d] = row / row.sum()
    return T


def _position_observation(task: Task) -> np.ndarray:
    """P(O_P | P'), section 3.2.4: the true cell likeliest, near cells likelier than far
    ones, a missed detection reads "No person", and false positives are possible."""
    g = task.grid
    m = task.obs_position
    p = g.n_cells
    O = np.zeros((p + 1, p + 1))
    for i, cell in enumerate(g.cells):
        w = np.array(
            [0.0 if c == cell else m.near_decay ** (g.chebyshev(cell, c) - 1) for c in g.cells]
        )
        O[i, :p] = (1.0 - m.correct - m.miss) * w / w.sum()
        O[i, i] = m.correct
        O[i, p] = m.miss
    O[p, :p] = m.false_positive / p
    O[p, p] = 1.0 - m.false_positive
    return O


def _velocity_observation(task: Task) -> np.ndarray:
    """P(O_V | P', D'), section 3.2.4 and 4.5: a moving person is likeliest seen moving
    their way, at a high speed; the opposite direction is the least likely; a resting or
    absent person is likeliest seen "Not moving", and slow speeds likelier than fast."""
    m = task.obs_velocity
    p = task.grid.n_cells
    V = len(VELOCITIES)
    fast = np.asarray(m.moving_speed) / sum(m.moving_speed)
    slow = np.asarray(m.other_speed) / sum(m.other_speed)
    O = np.zeros((p + 1, 5, V))
    for d in Direction:
        row = np.zeros(V)
        if d == Direction.NOT_MOVING:
            row[0] = m.rest_not_moving
            for d2 in MOVING_DIRECTIONS:
                row[1 + 3 * d2 : 4 + 3 * d2] = (1.0 - m.rest_not_moving) / 4.0 * slow
        else:
            share = {d: m.moving_direction, d.opposite: m.moving_reverse}
            for side in _perpendicular(d):
                share[side] = m.moving_turn
            for d2, s in share.items():
                row[1 + 3 * d2 : 4 + 3 * d2] = s * (fast if d2 == d else slow)
            row[0] = 1.0 - sum(share.values())
        O[:p, d] = row
    O[p, :, 0] = m.absent_not_moving
    O[p, :, 1:] = (1.0 - m.absent_not_moving) / (V - 1)
    return O


def _guard_table(task: Task) -> np.ndarray:
    """Table 4.1's "person's behaviour" column, per restricted cell: the person is at the
    cell, adjacent and not moving away, or two cells away and moving towards it.

    Distances count diagonal neighbours as adjacent (5.2.1: cells 9-11 adjoin 12; 5.1:
    cells 5 and 6 are two cells from 1). "Towards" and "away" mean that one step in the
    person's direction makes the distance smaller or larger.
    """
    g = task.grid
    p = g.n_cells
    G = np.zeros((len(task.restricted_cells), p + 1, 5), dtype=bool)
    for k, target in enumerate(task.restricted_cells):
        tr, tc = g.rowcol(target)
        for i, cell in enumerate(g.cells):
            r, c = g.rowcol(cell)
            dist = max(abs(r - tr), abs(c - tc))
            for d in Direction:
                dr, dc = d.step
                after = max(abs(r + dr - tr), abs(c + dc - tc))
                if dist == 0:
                    G[k, i, d] = True
                elif dist == 1:
                    G[k, i, d] = after <= dist
                elif dist == 2:
                    G[k, i, d] = after < dist
    return G


def guard_plans(model: FactoredModel) -> tuple[list[list[int]], int]:
    """Open-loop plans "walk to cell c by a shortest route, then do nothing", for every
    start and target cell: seeds for the solvers' lower bound (see bounds.plan_alphas).

    Returns:
        (plans as action-index lists, the index of "Do nothing").
    """
    g = model.task.grid
    plans: list[list[int]] = []
    for start in g.cells:
        for target in g.cells:
            (r0, c0), (r1, c1) = g.rowcol(start), g.rowcol(target)
            ew = [2] * max(c1 - c0, 0) + [3] * max(c0 - c1, 0)  # East / West
            ns = [1] * max(r1 - r0, 0) + [0] * max(r0 - r1, 0)  # South / North
            plans.append(ew + ns)
            if ew and ns:
                plans.append(ns + ew)
    unique = [list(p) for p in dict.fromkeys(tuple(p) for p in plans)]
    return unique, ACTIONS.index("Do nothing")

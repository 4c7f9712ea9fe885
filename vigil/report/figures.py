"""Figures for run reports (plotting lives here, never inside an algorithm): the
chapter 5 replay, a run's positions and belief (figures 5.1-5.4), the guarding
timeline, and the scenario set's overview."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402

from stack.cells import CellGrid  # noqa: E402
from stack.files import save_figure  # noqa: E402
from stack.planning.model import FactoredModel  # noqa: E402
from stack.vocabulary import ACTIONS, DIRECTIONS, NO_PERSON, OUT_OF_MAP  # noqa: E402
from vigil.report.records import UNKNOWN, cell_of_label  # noqa: E402

if TYPE_CHECKING:
    from stack.planning.replay import Table
    from vigil.report.metrics import Timeline
    from vigil.report.tables import StepRow

# PNG metadata without a software version: the same figure gives the same bytes.
_PNG_METADATA = {"Software": None}


def observed_rewards(model: FactoredModel, result) -> np.ndarray:
    """Reward per step as the thesis's figures 5.1-5.4 count it: table 4.1 at the observed
    robot and person cells and observed direction, plus the move cost of the action."""
    R = model.reward_table()
    out = []
    for st in result.table.steps:
        direction = st.velocity.split()[0] if st.velocity != "Not moving" else "Not moving"
        r = model.robot_index(st.robot)
        p = model.position_index(st.person)
        d = DIRECTIONS.index(direction)
        out.append(R[r, p, d, ACTIONS.index(st.action)])
    return np.asarray(out)


def draw_cell_bands(ax, restricted: Sequence[int], rest_cell: int | None) -> None:
    """Mark restricted cells (red) and the rest cell (green) as bands on a cell axis."""
    for c in restricted:
        ax.axhline(c, color="r", alpha=0.3, lw=6)
    if rest_cell is not None:
        ax.axhline(rest_cell, color="g", alpha=0.2, lw=6)


def plot_replay(model: FactoredModel, result, path: str | Path) -> Path:
    """Positions, cumulative reward and the person-position belief over the steps."""
    t = result.table
    steps = np.arange(1, len(t.steps) + 1)
    p = model.n_cells
    fig, axes = plt.subplots(3, 1, figsize=(8, 9), sharex=False)
    ax = axes[0]
    ax.step(steps, [s.robot for s in t.steps], where="mid", label="robot (observed)", lw=2)
    person = [s.person if s.person is not None else 0 for s in t.steps]
    ax.plot(steps, person, "o--", label="person (observed; 0 = no person)")
    draw_cell_bands(ax, model.task.restricted_cells, model.task.rest_cell)
    ax.set_ylabel("cell")
    ax.set_yticks(range(0, p + 1))
    ax.set_title(f"Table {t.name}: {t.title} - agreement {result.agreement}/{len(t.steps)}")
    ax.legend(loc="upper right", fontsize=8)
    for s in result.steps:
        if not s.agrees:
            ax.annotate(s.chosen_action, (s.step, t.steps[s.step - 1].robot), fontsize=7, color="r")

    axes[1].plot(steps, np.cumsum(observed_rewards(model, result)), "k-o")
    axes[1].set_ylabel("cumulative reward")
    axes[1].grid(alpha=0.3)

    # person position marginal after each step's observations
    beliefs = np.array([b.reshape(model.state_shape).sum(axis=(0, 2)) for b in result.beliefs])
    labels = [str(c) for c in model.task.grid.cells] + ["none"]
    im = axes[2].imshow(
        beliefs.T,
        aspect="auto",
        origin="lower",
        cmap="viridis",
        vmin=0,
        vmax=1,
        extent=(-0.5, len(beliefs) - 0.5, -0.5, p + 0.5),
    )
    axes[2].set_yticks(range(p + 1), labels)
    axes[2].set_xlabel("step (0 = initial belief)")
    axes[2].set_ylabel("P(person at cell)")
    fig.colorbar(im, ax=axes[2], fraction=0.03)
    fig.tight_layout()
    path = Path(path)
    save_figure(fig, path, dpi=90)
    plt.close(fig)
    return path


# -- run reports (vigil.report) -----------------------------------------------------------


def _cell_values(values: Sequence[int | None | float]) -> np.ndarray:
    """Cells as plot values: a cell number, 0 for None (no person / out of the map),
    NaN for unknown (``float('nan')``) so that the line breaks there."""
    out = []
    for v in values:
        if v is None:
            out.append(0.0)
        else:
            out.append(float(v))
    return np.asarray(out, dtype=float)


def plot_positions(
    path: str | Path,
    steps: Sequence[int],
    series: Sequence[tuple[str, Sequence[int | None | float], str]],
    *,
    n_cells: int,
    restricted: Sequence[int],
    rest_cell: int | None,
    rewards: Mapping[str, Sequence[float]] | None = None,
    title: str = "",
) -> Path:
    """Figures 5.1-5.4 for a run: cells over the steps and the cumulative reward.

    Args:
        path: the PNG to write.
        steps: the x values (step numbers).
        series: (label, cells, matplotlib format) per line; a cell is a number, None
            (no person / out of the map, drawn at 0) or NaN (unknown: a gap).
        n_cells: the number of cells (y axis 0..n_cells).
        restricted, rest_cell: cells to mark.
        rewards: label -> cumulative reward per step (second panel), if any.
        title: the figure title.
    """
    x = np.asarray(steps, dtype=float)
    n_panels = 2 if rewards else 1
    fig, axes = plt.subplots(n_panels, 1, figsize=(9, 3.6 * n_panels), squeeze=False)
    ax = axes[0, 0]
    for label, values, fmt in series:
        y = _cell_values(values)
        if len(y) != len(x) or not len(x):
            continue
        if fmt.startswith("step:"):
            ax.step(x, y, fmt[5:], where="mid", label=label, lw=2)
        else:
            ax.plot(x, y, fmt, label=label, ms=5)
    draw_cell_bands(ax, restricted, rest_cell)
    ax.set_ylabel("cell (0 = no person / out of the map)")
    ax.set_yticks(range(0, n_cells + 1))
    ax.set_ylim(-0.5, n_cells + 0.5)
    ax.set_xlabel("step")
    ax.grid(alpha=0.2)
    if title:
        ax.set_title(title)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    if rewards:
        rax = axes[1, 0]
        for label, values in rewards.items():
            y = np.asarray([np.nan if v is None else v for v in values], dtype=float)
            if len(y) == len(x) and len(x):
                rax.plot(x, y, "-o", label=label, ms=4)
        rax.set_ylabel("cumulative discounted reward")
        rax.set_xlabel("step")
        rax.grid(alpha=0.3)
        if rax.get_legend_handles_labels()[0]:
            rax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    fig.tight_layout()
    path = Path(path)
    save_figure(fig, path, dpi=90, metadata=_PNG_METADATA)
    plt.close(fig)
    return path


def plot_belief_grids(
    path: str | Path,
    grid: CellGrid,
    panels: Sequence[Mapping],
    *,
    restricted: Sequence[int] = (),
    ncols: int = 6,
    max_panels: int = 60,
    title: str = "",
) -> Path:
    """The person belief through a run: one small grid heatmap per step.

    Each panel is laid out as the cells lie on the floor (``grid.numbering``: north up,
    east right). A panel is a mapping with ``title`` (str), ``probs`` ({cell: P(person
    in cell)} or None for "no belief"), and optionally ``robot`` (a cell, drawn as a
    black square), ``person`` (the true cell, drawn as a cross) and ``note`` (text under
    the panel, e.g. P(no person)). Restricted cells get a red frame. With more than
    ``max_panels`` panels, evenly spaced ones are drawn (the first and last kept).
    """
    panels = list(panels)
    shown = panels
    if len(panels) > max_panels:
        idx = np.unique(np.linspace(0, len(panels) - 1, max_panels).round().astype(int))
        shown = [panels[i] for i in idx]
    n = max(len(shown), 1)
    cols = max(1, min(ncols, n))
    rows = math.ceil(n / cols)
    gr, gc = grid.rows, grid.columns
    w = 0.36 * gc + 0.15
    h = 0.36 * gr + 0.45
    fig, axes = plt.subplots(
        rows, cols, figsize=(w * cols + 0.8, h * rows + 0.4), squeeze=False, layout="constrained"
    )
    im = None
    for k in range(rows * cols):
        ax = axes[k // cols, k % cols]
        ax.set_xticks([])
        ax.set_yticks([])
        if k >= len(shown):
            ax.axis("off")
            continue
        panel = shown[k]
        probs = panel.get("probs")
        img = np.full((gr, gc), np.nan)
        if probs is not None:
            for cell, p in probs.items():
                r, c = grid.rowcol(int(cell))
                img[r, c] = float(p)
        im = ax.imshow(img, cmap="viridis", vmin=0.0, vmax=1.0, origin="upper")
        for r in range(gr):
            for c in range(gc):
                cell = grid.numbering[r][c]
                ax.text(c, r, str(cell), ha="center", va="center", fontsize=5, color="w")
        for cell in restricted:
            r, c = grid.rowcol(cell)
            ax.add_patch(Rectangle((c - 0.5, r - 0.5), 1, 1, fill=False, ec="r", lw=1.5))
        robot = panel.get("robot")
        if robot is not None:
            r, c = grid.rowcol(int(robot))
            ax.add_patch(Rectangle((c - 0.35, r - 0.35), 0.7, 0.7, fill=False, ec="k", lw=1.2))
        person = panel.get("person")
        if person is not None:
            r, c = grid.rowcol(int(person))
            ax.plot([c], [r], "x", color="magenta", ms=6, mew=1.5)
        ax.set_title(str(panel.get("title", "")), fontsize=6)
        if probs is None:
            ax.text(0.5, 0.5, "no belief", transform=ax.transAxes, ha="center", fontsize=6)
        if panel.get("note"):
            ax.set_xlabel(str(panel["note"]), fontsize=5)
    sup = title
    if len(shown) < len(panels):
        sup += f" ({len(shown)} of {len(panels)} steps shown)"
    sup += "  [square: robot, x: true person, red: restricted]"
    fig.suptitle(sup.strip(), fontsize=8)
    if im is not None:
        fig.colorbar(im, ax=axes, shrink=0.8, aspect=30, label="P(person in cell)")
    path = Path(path)
    save_figure(fig, path, dpi=100, metadata=_PNG_METADATA)
    plt.close(fig)
    return path


def plot_run(
    run_dir: Path,
    model: FactoredModel,
    rows: Sequence[StepRow],
    thesis_table: Table | None,
    title: str,
) -> list[str]:
    """positions.png and belief.png of a run from its step table; the file names."""

    def cells(labels: Sequence[str]) -> list:
        return [float("nan") if x == UNKNOWN else cell_of_label(x) for x in labels]

    task = model.task
    steps = [r.step for r in rows]
    series = [
        ("robot (observed)", cells([r.obs_robot for r in rows]), "step:b-"),
        ("robot (true)", cells([r.true_robot for r in rows]), "c--"),
        ("person (observed)", cells([r.obs_person for r in rows]), "o"),
        ("person (true)", cells([r.true_person for r in rows]), "x:"),
    ]
    if thesis_table is not None:
        th = list(thesis_table.steps[: len(rows)])
        pad = [float("nan")] * (len(rows) - len(th))
        series.append(("robot (thesis)", [st.robot for st in th] + pad, "s-"))
        series.append(("person (thesis)", [st.person for st in th] + pad, "d:"))
        title += f" - thesis table {thesis_table.name}"
    rewards = {"cumulative discounted reward": [r.cumulative for r in rows]}
    files = []
    plot_positions(
        run_dir / "positions.png",
        steps,
        [s for s in series if not all(isinstance(v, float) and np.isnan(v) for v in s[1])],
        n_cells=model.n_cells,
        restricted=task.restricted_cells,
        rest_cell=task.rest_cell,
        rewards=rewards,
        title=title,
    )
    files.append("positions.png")
    panels = []
    for r in rows:
        true_p = r.true_person if r.true_person not in (UNKNOWN, NO_PERSON) else None
        robot = r.obs_robot if r.obs_robot not in (UNKNOWN, OUT_OF_MAP) else None
        if robot is None and r.true_robot not in (UNKNOWN, OUT_OF_MAP):
            robot = r.true_robot
        panels.append(
            {
                "title": f"{r.step}: {r.action}",
                "probs": r.belief_person,
                "robot": None if robot is None else int(robot),
                "person": None if true_p is None else int(true_p),
                "note": "" if r.belief_none is None else f"P(none) {r.belief_none:.2f}",
            }
        )
    plot_belief_grids(
        run_dir / "belief.png",
        task.grid,
        panels,
        restricted=task.restricted_cells,
        title=f"{title}: P(person in cell) after each step",
    )
    files.append("belief.png")
    return files


def plot_timeline(
    path: str | Path,
    tl: Timeline,
    metrics: Mapping[str, Any],
    *,
    n_cells: int,
    restricted: Sequence[int],
    rest_cell: int | None,
    steps: Sequence[tuple[float, str]] = (),
    title: str = "",
) -> Path:
    """The guarding timeline: true person and robot cells over time, each visit shaded
    (green guarded, red not; a cross where the robot abandoned it), warnings as ticks
    (green timely, red late), false trips, and each step's outcome (misses red).

    Args:
        steps: (stamp, outcome) per decision step (:func:`metrics.step_outcome`).
    """
    fig, ax = plt.subplots(figsize=(10, 4.2))
    t = np.asarray(tl.t, float)

    def y(cells: Sequence[int | None]) -> np.ndarray:
        return np.asarray([np.nan if c is None else c for c in cells], float)

    for v in metrics.get("visits", []):
        end = v["person_left_t"] if v["person_left_t"] is not None else (t[-1] if len(t) else 0)
        ax.axvspan(v["person_arrival_t"], end, color="g" if v["guarded"] else "r", alpha=0.12, lw=0)
        if v["abandoned"]:
            ax.plot([v["abandoned_t"]], [v["cell"]], "rx", ms=10, mew=2)
    draw_cell_bands(ax, restricted, rest_cell)
    if len(t):
        ax.step(t, y(tl.person), "g-", where="post", lw=1.5, label="person (true)")
        ax.step(t, y(tl.robot), "b-", where="post", lw=2, alpha=0.8, label="robot (true)")
    for w in metrics.get("warnings", []):
        ax.axvline(w["t"], color="g" if w["timely"] else "r", lw=1, ls="--", alpha=0.8)
    for f in metrics.get("false_trips", []):
        ax.plot([f["t"]], [f["cell"]], "mv", ms=9)
    colours = {"miss": "r", "unseen": "orange", "wrong cell": "m", "seen": "g", "phantom": "k"}
    for stamp, outcome in steps:
        ax.plot([stamp], [-0.3], "|", color=colours.get(outcome, "0.6"), ms=10, mew=2)
    ax.set_ylim(-0.8, n_cells + 0.5)
    ax.set_yticks(range(0, n_cells + 1), ["none"] + [str(c) for c in range(1, n_cells + 1)])
    ax.set_xlabel("time [s]")
    ax.set_ylabel("cell")
    ax.grid(alpha=0.2)
    legend = [
        plt.Line2D([], [], color="g", lw=1.5, label="person (true)"),
        plt.Line2D([], [], color="b", lw=2, label="robot (true)"),
        plt.Line2D([], [], color="g", ls="--", label="warning, timely"),
        plt.Line2D([], [], color="r", ls="--", label="warning, late"),
        plt.Line2D([], [], color="r", marker="|", ls="", ms=10, mew=2, label="step: miss"),
        plt.Line2D([], [], color="orange", marker="|", ls="", ms=10, mew=2, label="step: unseen"),
        plt.Line2D([], [], color="m", marker="|", ls="", ms=10, mew=2, label="step: wrong cell"),
        plt.Line2D([], [], color="g", marker="|", ls="", ms=10, mew=2, label="step: seen"),
        plt.Line2D([], [], color="r", marker="x", ls="", ms=8, mew=2, label="abandoned"),
        plt.Line2D([], [], color="m", marker="v", ls="", ms=8, label="false trip"),
    ]
    ax.legend(handles=legend, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7)
    ax.set_title(
        (title + "\n" if title else "") + "shaded: visits (green guarded, red not guarded)",
        fontsize=9,
    )
    fig.tight_layout()
    path = Path(path)
    save_figure(fig, path, dpi=90, metadata=_PNG_METADATA)
    plt.close(fig)
    return path


def plot_set(
    path: str | Path, rows: Sequence[tuple[str, Mapping[str, Any] | None]], title: str = ""
) -> Path:
    """The scenario set at a glance: per scenario, visits guarded / not guarded /
    abandoned, warnings timely / late, false trips (left); the 'No person' miss rate
    and the share of unseen steps among steps with the person on the grid (right)."""
    names = [n for n, _ in rows]
    ms = [m or {} for _, m in rows]
    x = np.arange(len(rows))
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(13, 4.8), sharey=True)
    guarded = np.array([m.get("guarded", 0) for m in ms])
    visits = np.array([m.get("n_visits", 0) for m in ms])
    abandoned = np.array([m.get("abandoned", 0) for m in ms])
    timely = np.array([m.get("timely_warnings", 0) for m in ms])
    late = np.array([m.get("late_warnings", 0) for m in ms])
    trips = np.array([m.get("n_false_trips", 0) for m in ms])
    h = 0.2
    a1.barh(x - 1.5 * h, guarded, h, color="g", label="visits guarded")
    a1.barh(x - 1.5 * h, visits - guarded, h, left=guarded, color="r", label="visits not guarded")
    a1.barh(x - 0.5 * h, abandoned, h, color="darkred", label="visits abandoned")
    a1.barh(x + 0.5 * h, timely, h, color="limegreen", label="warnings timely")
    a1.barh(x + 0.5 * h, late, h, left=timely, color="orange", label="warnings late")
    a1.barh(x + 1.5 * h, trips, h, color="m", label="false trips")
    a1.set_yticks(x, names)
    a1.invert_yaxis()
    a1.set_xlabel("count")
    a1.legend(fontsize=7, loc="lower right")
    a1.grid(alpha=0.2, axis="x")
    rate = np.array([np.nan if m.get("miss_rate") is None else m["miss_rate"] for m in ms])
    with_p = np.array([m.get("steps_with_person", 0) for m in ms], float)
    unseen = np.array([m.get("unseen_with_person", 0) for m in ms], float)
    unseen_share = np.divide(unseen, with_p, out=np.full_like(unseen, np.nan), where=with_p > 0)
    a2.barh(x - 0.2, 100 * rate, 0.4, color="r", label="'No person' misses")
    a2.barh(x + 0.2, 100 * unseen_share, 0.4, color="orange", label="'Unseen'")
    a2.axvline(10, color="k", ls=":", lw=1, label="10 % (issue 11's bar for misses)")
    a2.set_xlabel("% of steps with the person on the grid")
    a2.legend(fontsize=7, loc="lower right")
    a2.grid(alpha=0.2, axis="x")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    path = Path(path)
    save_figure(fig, path, dpi=90, metadata=_PNG_METADATA)
    plt.close(fig)
    return path

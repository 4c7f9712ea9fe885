"""Figures for run reports (plotting lives here, never inside an algorithm)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from stack.planning.model import ACTIONS, DIRECTIONS, FactoredModel  # noqa: E402


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
    for c in model.task.restricted_cells:
        ax.axhline(c, color="r", alpha=0.3, lw=6)
    ax.axhline(model.task.rest_cell, color="g", alpha=0.2, lw=6)
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
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path

"""The planner's vocabulary: every label of the task's actions and observations, once.

The thesis's tables print observations as labels (tables 5.1-5.4): the robot's cell
or "Out of the map"; the person's cell or "No person"; the velocity "Not moving" or a
direction and a speed class ("East higher", "West 0.2-0.7", "South 0-0.2"). vigil adds
"Unseen": the camera could not look at all (outage, frozen frames), which is no
evidence about the person either way (docs/PERCEPTION.md). An observation may also say
which cells the camera could not see (``hidden``, parsed by :func:`parse_hidden`).
Planning, perception, the run report and the tests read these names from here.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

ACTIONS = ("North", "South", "East", "West", "Do nothing")
# vigil's trip command (issue 26): "To 1" asks navigation to drive straight into cell 1
# at top speed, entering where no person stands, instead of one cell move per step.
# The planner's model still counts it as the first move of the way (its belief update).
TRIP_PREFIX = "To "
TRIP_INSET_M = 0.35  # how far inside the cell a trip ends, by default [m]
DIRECTIONS = ("North", "South", "East", "West", "Not moving")  # index = cells.Direction
SPEED_CLASSES = ("higher", "0.2-0.7", "0-0.2")  # > 0.7, 0.2-0.7, 0-0.2 m/s (section 4.2)
NOT_MOVING = "Not moving"
NO_PERSON = "No person"
OUT_OF_MAP = "Out of the map"
UNSEEN = "Unseen"
VELOCITIES = (NOT_MOVING,) + tuple(f"{d} {s}" for d in DIRECTIONS[:4] for s in SPEED_CLASSES)


def trip_command(cell: int) -> str:
    """The trip command to ``cell`` ("To 1")."""
    return f"{TRIP_PREFIX}{int(cell)}"


def parse_trip(label: str) -> int | None:
    """The destination cell of a trip command ("To 1", "to 12"), or None for any other
    label (an action name, a number)."""
    words = label.strip().split()
    if len(words) == 2 and words[0].lower() == TRIP_PREFIX.strip().lower():
        if words[1].isdigit():
            return int(words[1])
    return None


def parse_hidden(data: Any) -> tuple[tuple[int, float], ...]:
    """The ``hidden`` field: {"3": 0.33, ...} or [[3, 0.33], ...] -> ((3, 0.33), ...).

    Raises:
        ValueError: not a mapping or list of (cell, fraction), or a fraction outside [0, 1].
    """
    if data is None:
        return ()
    items = data.items() if isinstance(data, Mapping) else data
    out = []
    try:
        for cell, frac in items:
            c, f = int(cell), float(frac)
            if not 0.0 <= f <= 1.0:
                raise ValueError(f"hidden fraction {frac!r} of cell {cell!r} is not in [0, 1]")
            out.append((c, f))
    except (TypeError, ValueError) as err:
        raise ValueError(f"hidden must map cells to fractions in [0, 1]: {err}") from None
    return tuple(sorted(out))

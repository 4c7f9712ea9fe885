"""The planner's vocabulary: every label of the task's actions and observations, once.

The thesis's tables print observations as labels (tables 5.1-5.4): the robot's cell
or "Out of the map"; the person's cell or "No person"; the velocity "Not moving" or a
direction and a speed class ("East higher", "West 0.2-0.7", "South 0-0.2"). vigil adds
"Unseen": the camera could not look at all (outage, frozen frames), which is no
evidence about the person either way (docs/PERCEPTION.md). Planning, perception, the
run report and the tests read these names from here.
"""

from __future__ import annotations

ACTIONS = ("North", "South", "East", "West", "Do nothing")
DIRECTIONS = ("North", "South", "East", "West", "Not moving")  # index = cells.Direction
SPEED_CLASSES = ("higher", "0.2-0.7", "0-0.2")  # > 0.7, 0.2-0.7, 0-0.2 m/s (section 4.2)
NOT_MOVING = "Not moving"
NO_PERSON = "No person"
OUT_OF_MAP = "Out of the map"
UNSEEN = "Unseen"
VELOCITIES = (NOT_MOVING,) + tuple(f"{d} {s}" for d in DIRECTIONS[:4] for s in SPEED_CLASSES)

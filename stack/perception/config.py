"""Perception's configuration: the deployment file's sections for its components.

Every perception component has a frozen dataclass for its configuration whose
``from_dict`` uses :func:`stack.config.from_mapping` (known keys, the field's type,
:class:`stack.cells.ConfigError` naming the key, the value and the rule). Rules
beyond the type (``> 0``, ordering) live in each dataclass's ``__post_init__``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from stack.cells import CellGrid
from stack.config import read_yaml

__all__ = ["load_config_file"]


def load_config_file(path: str | Path | None) -> tuple[CellGrid, dict[str, Any]]:
    """Read a deployment YAML: its ``grid`` section and the raw mapping of the rest.

    Args:
        path: the file; empty or None gives the default grid and no sections.

    Returns:
        (grid, mapping) where mapping holds the file's sections (``camera``, ``legs``,
        ``tracker``, ``observations``, ...) for the components' ``from_dict``.

    Raises:
        ConfigError: unreadable file, not a mapping, or a bad ``grid`` section.
    """
    if not path:
        return CellGrid(), {}
    data = read_yaml(path)
    grid = CellGrid.from_mapping(data["grid"]) if "grid" in data else CellGrid()
    return grid, data

"""A quick look at the twin: the ceiling camera's view and a top view of the map.

``snapshot(out_dir)`` builds the twin, lets it run a moment (the person walks in through
the door, the robot stands still at its start cell) and writes two PNGs:

- ``camera.png``: the ceiling camera's RGB image at the configured resolution;
- ``top.png``: the occupancy map in map coordinates, the cells of the twin's
  ``CellGrid`` outlined and numbered, the robot's true pose (arrow), the person's true
  position and the lidar's returns placed in the map frame from the robot's true pose.

Run: ``MUJOCO_GL=egl .venv/bin/python -m twin.snapshot --out runs/snapshot``.
"""

from __future__ import annotations

import argparse
import math
import os
from collections.abc import Sequence
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import cv2  # noqa: E402
import matplotlib  # noqa: E402

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from stack.files import save_figure, write_bytes  # noqa: E402
from stack.nav.occupancy import FREE, OCCUPIED, OccupancyMap  # noqa: E402
from twin.config import TwinConfig, load_twin_config  # noqa: E402
from twin.scene import LIDAR_SITE  # noqa: E402
from twin.twin import Twin, VelocityCommand  # noqa: E402

CAMERA_FILE = "camera.png"
TOP_FILE = "top.png"
DEFAULT_SETTLE_S = 3.0  # the default person steps through the door at about 2 s


def _map_image(occ: OccupancyMap) -> np.ndarray:
    """Grey levels of the occupancy map: free white, occupied black, unknown grey."""
    img = np.full(occ.data.shape, 0.8)
    img[occ.data == FREE] = 1.0
    img[occ.data == OCCUPIED] = 0.0
    return img


def _scan_points_map(tw: Twin) -> np.ndarray:
    """(N, 2) lidar returns in the map frame, placed with the robot's true pose."""
    gt = tw.ground_truth().robot
    c, s = math.cos(gt.yaw_rad), math.sin(gt.yaw_rad)
    rot = np.array([[c, -s], [s, c]])
    # the lidar's mounting offset in the robot frame (ahead of the centre)
    site = tw.data.site_xpos[tw.model.site(LIDAR_SITE).id][:2]
    offset = rot.T @ (site - np.array([gt.x_m, gt.y_m]))
    pts = tw.scan().points_m()
    return (pts + offset) @ rot.T + np.array([gt.x_m, gt.y_m])


def _draw_top(tw: Twin, path: Path) -> None:
    occ = tw.occupancy_map()
    rows, cols = occ.data.shape
    r = occ.resolution_m
    x0, y0 = occ.origin_m
    extent = (x0, x0 + cols * r, y0, y0 + rows * r)
    fig, ax = plt.subplots(figsize=(8, 6), dpi=100)
    try:
        ax.imshow(
            _map_image(occ),
            cmap="gray",
            vmin=0.0,
            vmax=1.0,
            origin="lower",  # data row 0 is the map's south edge
            extent=extent,
            interpolation="nearest",
        )
        grid = tw.config.grid
        for cell in grid.cells:
            bx0, by0, bx1, by1 = grid.bounds(cell)
            ax.add_patch(
                plt.Rectangle(
                    (bx0, by0), bx1 - bx0, by1 - by0, fill=False, edgecolor="tab:blue", lw=1.2
                )
            )
            # the number in the cell's north-west corner: the centre is the robot's waypoint
            ax.text(bx0 + 0.06, by1 - 0.06, str(cell), color="tab:blue", ha="left", va="top")
        pts = _scan_points_map(tw)
        if len(pts):
            ax.scatter(pts[:, 0], pts[:, 1], s=3, c="tab:red", label="lidar (true pose)")
        gt = tw.ground_truth()
        robot = gt.robot
        ax.arrow(
            robot.x_m,
            robot.y_m,
            0.5 * math.cos(robot.yaw_rad),
            0.5 * math.sin(robot.yaw_rad),
            width=0.06,
            head_width=0.22,
            head_length=0.2,
            length_includes_head=True,
            color="tab:green",
            label="robot",
        )
        if gt.person is not None and gt.person.in_room:
            p = gt.person.pose
            ax.plot(p.x_m, p.y_m, "o", ms=10, color="tab:orange", label="person")
        ax.set_xlim(extent[0], extent[1])
        ax.set_ylim(extent[2], extent[3])
        ax.set_aspect("equal")
        ax.set_xlabel("x [m] (east)")
        ax.set_ylabel("y [m] (north)")
        ax.set_title(f"twin at t = {tw.time_s:.2f} s")
        ax.legend(loc="upper left", fontsize=8)
        fig.tight_layout()
        save_figure(fig, path)  # never through a link planted there (issue 23)
    finally:
        plt.close(fig)


def snapshot(
    out_dir: Path,
    config_path: Path | None = None,
    seed: int = 0,
    *,
    settle_s: float = DEFAULT_SETTLE_S,
) -> list[Path]:
    """Build the twin, run it a moment and write the camera view and a top view.

    Args:
        out_dir: directory for ``camera.png`` and ``top.png`` (created if absent).
        config_path: twin YAML file (``load_twin_config``); None for ``TwinConfig()``.
        seed: seed of the twin's noise generator.
        settle_s: simulated time to run first with a zero command [s] (rounded to whole
            control periods); the default lets the default person walk into the room.

    Returns:
        [camera_path, top_path].

    Raises:
        ConfigError: the configuration is invalid.
        OSError: a file cannot be read or written.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    cfg = load_twin_config(config_path) if config_path is not None else TwinConfig()
    camera_path, top_path = out_dir / CAMERA_FILE, out_dir / TOP_FILE
    with Twin(cfg, seed=seed) as tw:
        tw.run(settle_s, VelocityCommand())
        rgb = tw.render_camera()
        ok, png = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        if not ok:
            raise OSError(f"cannot encode {camera_path}")
        write_bytes(camera_path, png.tobytes())  # never through a link planted there
        _draw_top(tw, top_path)
    return [camera_path, top_path]


def main(argv: Sequence[str] | None = None) -> int:
    """Command line: write the snapshot and print the paths."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("runs/snapshot"), help="output directory")
    ap.add_argument("--config", type=Path, default=None, help="twin YAML (default: built-in)")
    ap.add_argument("--seed", type=int, default=0, help="noise seed")
    args = ap.parse_args(argv)
    for p in snapshot(args.out, args.config, args.seed):
        print(p)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

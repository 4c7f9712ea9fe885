"""twin.snapshot: the camera view and the top view land as PNGs."""

from __future__ import annotations

import cv2
import numpy as np

from twin.config import TwinConfig
from twin.snapshot import main, snapshot


def test_snapshot_writes_camera_and_top_view(tmp_path, capsys):
    paths = snapshot(tmp_path / "snap", seed=1)
    assert [p.name for p in paths] == ["camera.png", "top.png"]
    for p in paths:
        assert p.is_file()

    cam = cv2.imread(str(paths[0]))
    assert cam is not None
    c = TwinConfig().camera
    assert cam.shape == (c.height_px, c.width_px, 3)
    assert cam.std() > 10.0  # a real scene, not a blank frame

    top = cv2.imread(str(paths[1]))
    assert top is not None
    assert top.shape == (600, 800, 3)  # figsize 8x6 in at 100 dpi
    colours = np.unique(top.reshape(-1, 3) // 32, axis=0)  # coarse bins ignore antialiasing
    assert len(colours) >= 5  # map greys + cells, lidar, robot, person

    # the command line writes the same two files and prints their paths
    out = tmp_path / "cli"
    assert main(["--out", str(out), "--seed", "2"]) == 0
    printed = capsys.readouterr().out.split()
    assert printed == [str(out / "camera.png"), str(out / "top.png")]


def test_a_link_planted_where_the_snapshot_writes_is_refused_and_its_target_kept(tmp_path):
    import pytest

    precious = tmp_path / "precious.txt"
    precious.write_text("mine")
    for name in ("camera.png", "top.png"):
        out = tmp_path / name.split(".")[0]
        out.mkdir()
        (out / name).symlink_to(precious)
        with pytest.raises(OSError):
            snapshot(out, seed=1)
        assert precious.read_text() == "mine" and (out / name).is_symlink()

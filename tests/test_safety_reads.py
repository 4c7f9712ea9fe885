"""Bounded reads (issue 23): every file the program reads, whoever names it, must be a
regular file and is read with a size cap. A camera_info that is /dev/zero grew the
camera node to 3.6 GB before a MemoryError traceback; a named pipe blocked a reader
for ever (it was opened before anything was checked)."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from collections.abc import Callable
from pathlib import Path

import pytest

from stack.cells import ConfigError
from stack.config import open_regular, read_bytes_capped, read_text_capped

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def fifo(tmp_path) -> Path:
    path = tmp_path / "pipe.yaml"
    os.mkfifo(path)
    return path


def _within(call: Callable[[], object], seconds: float = 10.0) -> BaseException | None:
    """Run ``call`` in a thread; the exception it raised (None if none). Fails when it
    is still running after ``seconds`` (a read blocked on a pipe)."""
    out: list[BaseException | None] = []

    def run() -> None:
        try:
            call()
            out.append(None)
        except BaseException as exc:  # noqa: BLE001 - returned to the test
            out.append(exc)

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(seconds)
    assert out, f"still reading after {seconds} s (blocked)"
    return out[0]


def test_the_helper_refuses_devices_pipes_folders_and_big_files(tmp_path, fifo):
    with pytest.raises(ValueError, match="not a regular file"):
        read_text_capped("/dev/zero")
    err = _within(lambda: read_text_capped(fifo), 10.0)
    assert isinstance(err, ValueError) and "not a regular file" in str(err)
    with pytest.raises(IsADirectoryError):
        read_text_capped(tmp_path)
    big = tmp_path / "big.yaml"
    big.write_bytes(b"a" * 1001)
    with pytest.raises(ValueError, match="longer than 1000 bytes"):
        read_bytes_capped(big, 1000)
    with pytest.raises(ValueError, match="longer than 1000 bytes"):
        open_regular(big, 1000)
    assert read_bytes_capped(big, 1001) == b"a" * 1001
    link = tmp_path / "link.yaml"
    link.symlink_to("/dev/zero")
    with pytest.raises(ValueError, match="not a regular file"):
        read_text_capped(link)


def test_a_camera_info_that_is_dev_zero_is_refused_in_one_line():
    from stack.hardware.camera_stream import load_calibration

    with pytest.raises(ConfigError) as err:
        load_calibration("/dev/zero")
    assert err.value.key == "camera_info_file" and "not a regular file" in str(err.value)
    assert "\n" not in str(err.value)


def test_the_camera_node_refuses_a_dev_zero_camera_info_with_one_line_and_little_memory():
    """The node process itself: one [FATAL] line, exit 2, no MemoryError, well under
    the 3.6 GB it reached before."""
    code = (
        "import resource, sys;"
        "resource.setrlimit(resource.RLIMIT_AS, (3 * 2**30, resource.RLIM_INFINITY));"
        "from stack.hardware.node_camera_stream import main;"
        "main(['--ros-args', '-p', 'camera_info_file:=/dev/zero', '-p', 'url:=test'])"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=60,
        env=dict(os.environ, PYTHONPATH=str(REPO)),
    )
    out = proc.stdout + proc.stderr
    assert "MemoryError" not in out and "Traceback" not in out, out
    assert proc.returncode == 2, out
    fatal = [ln for ln in out.splitlines() if "FATAL" in ln]
    assert len(fatal) == 1 and "camera_info_file" in fatal[0], out


def _readers(tmp: Path) -> dict[str, Callable[[Path], object]]:
    from stack.nav.occupancy import load_map_yaml
    from stack.perception.homography import load_calibration, load_points_file
    from stack.planning.agent import read_state
    from stack.planning.policy import AlphaPolicy, read_policy_xml
    from stack.planning.pomdp_format import read_text_capped as read_pomdp
    from stack.planning.task import load_task
    from twin.config import load_twin_config
    from vigil.deployment import load_deployment
    from vigil.scenario import load_scenario

    return {
        "scenario": load_scenario,
        "deployment": load_deployment,
        "task": load_task,
        "twin scene": load_twin_config,
        "calibration": load_calibration,
        "points": load_points_file,
        "map": load_map_yaml,
        "policy": lambda p: AlphaPolicy.load(p),
        "policy xml": read_policy_xml,
        "pomdp": read_pomdp,
        "state": read_state,
    }


@pytest.mark.parametrize("special", ["/dev/zero", "fifo"])
def test_every_reader_refuses_a_device_or_a_pipe_with_its_own_error(tmp_path, fifo, special):
    from tests.test_fuzz_files import allowed_errors

    path = Path(special) if special != "fifo" else fifo
    for name, read in _readers(tmp_path).items():
        err = _within(lambda read=read: read(path), 20.0)
        assert err is not None, f"{name} accepted {special}"
        assert isinstance(err, allowed_errors()), f"{name}: {type(err).__name__}: {err}"

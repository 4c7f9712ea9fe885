"""Every deployment value is checked where it is read (vigil/deployment.py, issue 23):
of its type, finite, in range; refused in one line naming the key, before any process
starts. Types and finiteness held before; the ranges, topic names and the voice did not
(a seed past 2^32 - 1, a 1e9 Hz control rate, 10^15 steps, 10^12 restarts, a stop
timeout of 30 years, an empty or spaced topic name, a voice starting with "-" reached
the nodes)."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from stack.cells import ConfigError
from vigil.deployment import load_deployment, parse_deployment

REPO = Path(__file__).resolve().parents[1]
TWIN = REPO / "config" / "twin.yaml"

HOSTILE = [
    ("twin", "seed", 2**40),
    ("twin", "seed", -1),
    ("twin", "odom_rate_hz", 1e9),
    ("twin", "stall_timeout_s", 1e12),
    ("twin", "stall_abort_s", 0.5),
    ("navigation", "control_rate_hz", 1e9),
    ("navigation", "pose_topic", "not a topic"),
    ("planner", "max_steps", 10**15),
    ("planner", "start_delay_s", 1e300),
    ("planner", "nav_timeout_s", 1e12),
    ("planner", "obs_timeout_s", 0.0),
    ("nodes", "max_restarts", 10**12),
    ("nodes", "stop_timeout_s", 1e9),
    ("topics", "cmd_vel", ""),
    ("topics", "cmd_vel", "cmd vel"),
    ("topics", "scan", "/scan//x"),
    ("topics", "odom", "odom"),
    ("speech", "voice", ""),
    ("speech", "voice", "-w/home/user/.bashrc"),
    # held before, kept: types and finiteness
    ("twin", "odom_rate_hz", math.inf),
    ("planner", "obs_timeout_s", math.nan),
    ("nodes", "restart", "yes"),
    ("ros", "domain_id", True),
]


@pytest.mark.parametrize(("section", "key", "value"), HOSTILE)
def test_a_hostile_deployment_value_is_refused_naming_the_key(section, key, value):
    data = yaml.safe_load(TWIN.read_text())
    data.setdefault(section, {})[key] = value
    with pytest.raises(ConfigError) as err:
        parse_deployment(data, TWIN)
    line = str(err.value)
    assert line.startswith(f"{section}.{key}: ") and "\n" not in line, line


def test_the_shipped_deployments_pass():
    for name in ("twin.yaml", "twin-diff.yaml", "twin-tf.yaml", "hardware.yaml"):
        load_deployment(REPO / "config" / name)


def test_vigil_run_refuses_a_hostile_deployment_in_one_line_before_starting(tmp_path):
    data = yaml.safe_load(TWIN.read_text())
    data["task"] = str(REPO / "config" / "task-r2.yaml")
    data["twin"]["scene"] = str(REPO / "config" / "twin-scene.yaml")
    data["nodes"]["max_restarts"] = 10**12
    (tmp_path / "dep.yaml").write_text(yaml.safe_dump(data))
    proc = subprocess.run(
        [sys.executable, "-m", "vigil.cli", "run", str(REPO / "scenarios" / "5.2.2.yaml"),
         "--config", str(tmp_path / "dep.yaml"), "--out", str(tmp_path / "run")],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        "vigil run: error: nodes.max_restarts: 1000000000000 is invalid: must be in [0, 1000]"
    ]
    assert not (tmp_path / "run").exists()

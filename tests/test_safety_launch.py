"""``vigil launch``: ``vigil run``'s run-folder rules, and the planner resumes an earlier
launch's state only when asked, only for the same deployment, task and policy, and
only while it is young (issue 23)."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from stack.cells import ConfigError
from vigil import launch_command as vl
from vigil.run_folder import RUN_MARK, fresh_run_dir

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / "config" / "twin.yaml"


def _cli(*argv: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(REPO))
    return subprocess.run(
        [sys.executable, "-m", "vigil.cli", *argv],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )


def test_launch_refuses_a_foreign_folder_and_leaves_it_untouched(tmp_path):
    """Today's launch wrote its params.yaml over the user's (and started the system)."""
    (tmp_path / "params.yaml").write_text("precious: true\n")
    proc = _cli("launch", str(CONFIG), "--out", str(tmp_path))
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "did not make" in lines[0], proc.stderr
    assert (tmp_path / "params.yaml").read_text() == "precious: true\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["params.yaml"]


@pytest.mark.parametrize("bad", ["nan", "inf", "-1", "0"])
def test_launch_refuses_a_resume_bound_that_is_no_bound(tmp_path, bad):
    proc = _cli("launch", str(CONFIG), "--out", str(tmp_path / "x"), "--resume-max-age-s", bad)
    assert proc.returncode == 2, proc.stderr
    assert "--resume-max-age-s" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "x").exists()


# -- the run folder and the resumption, without starting a process ------------------------
@pytest.fixture
def files(tmp_path, monkeypatch):
    """A task and a policy file, and vigil.system.prepare replaced by a stand-in that
    writes params.yaml and names them (the real one solves and calibrates)."""
    from vigil.system import System

    task, policy = tmp_path / "task.yaml", tmp_path / "policy.npz"
    task.write_text("task: 1\n")
    policy.write_bytes(b"alphas")
    current = {"task": task}

    def fake_prepare(dep, run_dir, scenario=None, say=print):
        (run_dir / "params.yaml").write_text("planner: {}\n")
        planner = {
            "task_file": str(current["task"]),
            "policy_file": str(policy),
            "state_file": str(run_dir / vl.STATE_FILE),
        }
        return System(run_dir, [], {"planner": planner})

    monkeypatch.setattr("vigil.system.prepare", fake_prepare)
    return current


def _earlier_launch(out: Path, files, age_s: float = 10.0) -> Path:
    """A launch into ``out`` that saved a planner state ``age_s`` ago."""
    lines: list[str] = []
    _, system, _ = vl.prepare_launch(CONFIG, out, say=lines.append)
    state = Path(system.params["planner"]["state_file"])
    state.write_text(json.dumps({"step": 7, "belief": [1.0]}))
    t = time.time() - age_s
    os.utime(state, (t, t))
    return state


def test_a_new_launch_does_not_resume_and_keeps_the_earlier_folder(tmp_path, files):
    out = tmp_path / "launch"
    state = _earlier_launch(out, files)
    before = state.read_text()
    lines: list[str] = []
    _, system, _ = vl.prepare_launch(CONFIG, out, say=lines.append)
    assert system.run_dir == tmp_path / "launch-2"  # numbered, like vigil run
    assert not (system.run_dir / vl.STATE_FILE).exists()  # today: resumed yesterday's
    assert state.read_text() == before
    said = [ln for ln in lines if "planner:" in ln]
    assert len(said) == 1 and "not resumed without --resume" in said[0], lines


def test_resume_takes_a_young_state_of_the_same_task_policy_and_deployment(tmp_path, files):
    out = tmp_path / "launch"
    state = _earlier_launch(out, files)
    lines: list[str] = []
    _, system, _ = vl.prepare_launch(CONFIG, out, resume=True, say=lines.append)
    copied = system.run_dir / vl.STATE_FILE
    assert system.run_dir != out and copied.read_text() == state.read_text()
    said = [ln for ln in lines if "planner:" in ln]
    assert len(said) == 1 and "resuming from" in said[0] and "step 7" in said[0], lines
    # a third launch resumes from the newest (the second's copy, if it saved since)
    newer = json.dumps({"step": 9, "belief": [1.0]})
    copied.write_text(newer)
    _, third, _ = vl.prepare_launch(CONFIG, out, resume=True, say=lines.append)
    assert (third.run_dir / vl.STATE_FILE).read_text() == newer


def test_resume_refuses_an_old_state_and_says_why(tmp_path, files):
    out = tmp_path / "launch"
    _earlier_launch(out, files, age_s=3 * 3600)
    lines: list[str] = []
    _, system, _ = vl.prepare_launch(
        CONFIG, out, resume=True, resume_max_age_s=600, say=lines.append
    )
    assert not (system.run_dir / vl.STATE_FILE).exists()
    said = [ln for ln in lines if "planner:" in ln]
    assert len(said) == 1 and "older than --resume-max-age-s 600" in said[0], lines


def test_resume_refuses_a_state_of_another_task(tmp_path, files):
    out = tmp_path / "launch"
    _earlier_launch(out, files)
    other = tmp_path / "other.yaml"
    other.write_text("task: 2\n")
    files["task"] = other
    lines: list[str] = []
    _, system, _ = vl.prepare_launch(CONFIG, out, resume=True, say=lines.append)
    assert not (system.run_dir / vl.STATE_FILE).exists()
    assert any("another task" in ln for ln in lines), lines


def test_resume_refuses_a_state_from_the_future(tmp_path, files):
    out = tmp_path / "launch"
    _earlier_launch(out, files, age_s=-3600)
    lines: list[str] = []
    _, system, _ = vl.prepare_launch(CONFIG, out, resume=True, say=lines.append)
    assert not (system.run_dir / vl.STATE_FILE).exists()
    assert any("in the future" in ln for ln in lines), lines


def test_resume_ignores_a_state_in_a_folder_vigil_did_not_make(tmp_path, files):
    out = tmp_path / "launch"
    state = _earlier_launch(out, files)
    (out / RUN_MARK).unlink()  # now a foreign folder: refused as --out, never read
    with pytest.raises(ConfigError, match="did not make"):
        vl.prepare_launch(CONFIG, out, resume=True, say=lambda _: None)
    assert vl.previous_state(out) is None and state.exists()


def test_resume_decision_without_an_identity_file(tmp_path):
    run = fresh_run_dir(tmp_path / "r", "id")
    (run / vl.STATE_FILE).write_text("{}")
    state, line = vl.resume_decision(run / vl.STATE_FILE, {}, True, 600.0, time.time())
    assert state is None and "records nothing" in line
    with pytest.raises(ConfigError, match="resume-max-age-s"):
        vl.prepare_launch(CONFIG, tmp_path / "x", resume_max_age_s=math.nan)


def test_a_hung_ros_teardown_ends_by_its_own_alarm_with_the_deployments_stop_timeout(tmp_path):
    """A node whose ROS teardown hangs (seen: the markers node in ``destroy_service``
    after Ctrl-C of a hardware launch) ends itself by its alarm, ``TEARDOWN_S`` (8 s)
    into the teardown, and the launcher warns. With the deployment's default
    ``nodes.stop_timeout_s`` (5 s) the launcher sent SIGKILL 7 s after SIGINT, before
    the alarm: the stop became a failure (``markers exited (code -9, SIGKILL) at
    shutdown``, exit 3)."""
    import signal

    from stack.exits import TEARDOWN_S
    from vigil.deployment import NodesSection
    from vigil.processes import ProcessSpec

    # as stack.ros_main.spin_node: SIGINT and SIGTERM set its stop flag (SIGTERM dumps the
    # stacks too); the teardown then hangs until the alarm
    hung = (
        "import faulthandler, signal, sys, time\nfrom stack.ros_main import _teardown_alarm\n"
        "signal.signal(signal.SIGTERM, lambda *a: None)\n"
        "faulthandler.register(signal.SIGTERM, file=sys.stderr, all_threads=True, chain=True)\n"
        "signal.signal(signal.SIGINT, lambda *a: (_teardown_alarm(), time.sleep(60)))\n"
        "print('ready', flush=True)\ntime.sleep(60)\n"
    )
    spec = ProcessSpec("hung", "", command=[sys.executable, "-u", "-c", hung])
    la = vl.Launcher([spec], tmp_path / "logs", {"PYTHONPATH": str(REPO)}, say=lambda s: None)
    la.start()
    log = tmp_path / "logs" / "hung.log"
    deadline = time.monotonic() + 60.0
    while time.monotonic() < deadline and not (log.exists() and "ready" in log.read_text()):
        time.sleep(0.1)
    t0 = time.monotonic()
    codes = la.stop(NodesSection().stop_timeout_s)  # 5 s
    assert codes == {"hung": -signal.SIGALRM}, log.read_text()
    assert la.failures == [] and la.warnings[0].startswith("hung: its ROS teardown hung")
    assert TEARDOWN_S <= time.monotonic() - t0 < TEARDOWN_S + 5.0


def test_a_launch_with_a_scenario_walks_it_and_a_hardware_launch_refuses_one(tmp_path):
    """``--scenario``: the twin's people and the planner's steps from the scenario (the
    host with the planner ends after them); on a robot there is no scenario to walk."""
    from vigil.scenario import load_scenario

    scenario = load_scenario(REPO / "scenarios" / "guard" / "fast-walker.yaml")
    _, system, _ = vl.prepare_launch(CONFIG, tmp_path / "twin", say=lambda _: None,
                                     scenario=scenario)  # fmt: skip
    assert system.params["planner"]["max_steps"] == scenario.steps
    assert system.params["planner"]["initial_robot_cell"] == scenario.robot_cell
    with pytest.raises(ConfigError, match="--scenario.*twin"):
        vl.prepare_launch(REPO / "config" / "hardware.yaml", tmp_path / "hw",
                          say=lambda _: None, scenario=scenario)  # fmt: skip
    assert not (tmp_path / "hw").exists()
    # the command line: a scenario that is no file is refused in one line, nothing made
    proc = _cli("launch", str(CONFIG), "--out", str(tmp_path / "cli"), "--scenario",
                str(tmp_path / "missing.yaml"))  # fmt: skip
    assert proc.returncode == 2 and "missing.yaml" in proc.stderr, proc.stderr
    assert not (tmp_path / "cli").exists()

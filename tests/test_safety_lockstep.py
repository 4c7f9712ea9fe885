"""Run privacy and lock-step faults (issue 13): two runs never take each other's nodes
for their own, a stalled run ends with an error naming what stalled, stamps round
correctly."""

import os
import signal
import subprocess
import sys
import time

import pytest

from stack.lockstep import Ack, Ledger
from vigil.launch import Launcher, ProcessSpec
from vigil.ros_domain import claim_domain, domain_range


def ack(node, run, inc="a", recv=None, sent=None):
    return Ack(node, inc, dict(recv or {}), dict(sent or {}), {}, run=run)


def test_a_ledger_ignores_the_participants_of_another_run():
    led = Ledger(("navigation",), run_id="run-a")
    assert led.update(ack("navigation", "run-a", recv={"/scan": 0}), 0.0)
    # the other run's navigation, a new incarnation each time: once taken for a restart
    for i in range(50):
        assert not led.update(ack("navigation", "run-b", inc=str(i), recv={"/scan": 9}), 1.0)
    assert led.events == [] and led.quiescent()
    assert led.members["navigation"].ack.run == "run-a"
    assert led.foreign == {"navigation@run-b": 50}
    # a hostile peer with endless names is remembered only up to a bound
    for i in range(1000):
        led.update(ack(f"n{i}", f"r{i}"), 2.0)
    assert len(led.foreign) <= 64
    # and the run id survives the wire
    assert Ack.from_json(ack("x", "run-a").to_json()).run == "run-a"


def test_each_run_claims_its_own_domain_until_it_ends(tmp_path):
    a = claim_domain(tmp_path, range(150, 153))
    b = claim_domain(tmp_path, range(150, 153))
    assert a.domain_id != b.domain_id
    # a domain held by another live process is skipped; its death frees it
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time; from vigil.ros_domain import claim_domain; "
            f"c = claim_domain({str(tmp_path)!r}, range(150, 153)); print(c.domain_id); "
            "sys.stdout.flush(); time.sleep(60)",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        held = int(holder.stdout.readline())
        assert held not in (a.domain_id, b.domain_id)
        with pytest.raises(ValueError, match="in use"):
            claim_domain(tmp_path, range(150, 153))
    finally:
        holder.kill()
        holder.wait()
    assert claim_domain(tmp_path, range(150, 153)).domain_id == held
    a.release()
    assert claim_domain(tmp_path, range(150, 153)).domain_id == a.domain_id
    assert domain_range("10-12") == range(10, 13)
    with pytest.raises(ValueError, match="VIGIL_DOMAINS"):
        domain_range("0-500")


def test_stamp_of_rounds_to_the_nearest_nanosecond():
    from twin.bridge_node import stamp_of

    for t, want in [
        (2.9999999999, (3, 0)),
        (2.9999999994, (2, 999_999_999)),
        (0.1 + 0.2, (0, 300_000_000)),
        (12.04, (12, 40_000_000)),
        (0.0, (0, 0)),
    ]:
        s = stamp_of(t)
        assert (s.sec, s.nanosec) == want, t
    # monotone over a long run of ticks: never a frame "out of order"
    prev = -1
    for i in range(20000):
        s = stamp_of(i * 0.04)
        ns = s.sec * 1_000_000_000 + s.nanosec
        assert ns > prev and 0 <= s.nanosec < 1_000_000_000
        prev = ns


@pytest.mark.ros
def test_a_stalled_lockstep_run_ends_with_an_error_naming_what_stalled(tmp_path):
    """A participant that never comes: the bridge exits with EXIT_STALLED, and the
    launcher's reason names the missing node."""
    from twin.bridge_node import EXIT_STALLED

    params = tmp_path / "params.yaml"
    params.write_text(
        "twin_bridge:\n  ros__parameters:\n    lockstep: true\n"
        "    participants: [ghost_planner]\n    stall_warn_s: 0.5\n"
        "    stall_timeout_s: 1.0\n    stall_abort_s: 3.0\n"
    )
    spec = ProcessSpec("twin_bridge", "twin.bridge_node", params, restart=False)
    la = Launcher([spec], tmp_path / "logs", {"MUJOCO_GL": "egl"}, say=lambda s: None)
    la.start()
    deadline = time.monotonic() + 120
    try:
        while la.poll() and time.monotonic() < deadline:
            time.sleep(0.2)
    finally:
        la.stop(2.0)
    assert la.exit_codes["twin_bridge"] == EXIT_STALLED
    assert "lock-step stalled" in la.stopped_because
    assert "ghost_planner" in la.stopped_because


def test_launcher_reports_a_node_that_fails_at_shutdown(tmp_path):
    code = (
        "import signal, sys, time\n"
        "signal.signal(signal.SIGINT, lambda *a: (print('[ERROR] boom at exit'), sys.exit(1)))\n"
        "print('ready', flush=True)\n"
        "time.sleep(60)\n"
    )
    clean = (
        "import time\ntry:\n    print('ready', flush=True)\n    time.sleep(60)\n"
        "except KeyboardInterrupt:\n    pass\n"
    )
    specs = [
        ProcessSpec("bad", "", command=[sys.executable, "-u", "-c", code]),
        ProcessSpec("good", "", command=[sys.executable, "-u", "-c", clean]),
    ]
    la = Launcher(specs, tmp_path / "logs", say=lambda s: None)
    # started from a process that ignores SIGINT (a background job, a test runner): the
    # nodes must still get it
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        la.start()
    finally:
        signal.signal(signal.SIGINT, previous)
    # both children have set up their SIGINT handling (a loaded machine starts them slowly)
    deadline = time.monotonic() + 60.0
    logs = [tmp_path / "logs" / f"{n}.log" for n in ("bad", "good")]
    while time.monotonic() < deadline and not all(
        p.exists() and "ready" in p.read_text() for p in logs
    ):
        time.sleep(0.1)
    assert la.poll()
    codes = la.stop(5.0)
    assert codes == {"bad": 1, "good": 0}
    assert la.failures == ["bad exited (code 1): [ERROR] boom at exit at shutdown"]


def test_run_sets_a_private_domain_and_run_id_for_every_node(tmp_path, monkeypatch):
    """vigil run (table mode, quick): the nodes' environment holds the claimed domain
    and the run id, whatever ROS_DOMAIN_ID the caller had."""
    from vigil import run as run_mod

    seen = {}

    class Spy(Launcher):
        def start(self):
            seen.update(self.env)
            raise run_mod.RunError("spied")

    import numpy as np
    import yaml

    from stack.planning.model import build_model
    from stack.planning.policy import AlphaPolicy
    from stack.planning.task import load_task

    monkeypatch.setattr(run_mod, "Launcher", Spy)
    monkeypatch.setenv("ROS_DOMAIN_ID", "0")
    scenario = run_mod.REPO / "scenarios" / "5.1.1.yaml"
    task = run_mod.load_scenario(scenario).task
    n = build_model(load_task(task)).flat().n_states
    AlphaPolicy(np.zeros((2, n)), np.array([0, 1]), {}).save(tmp_path / "p.npz")
    config = yaml.safe_load((run_mod.REPO / "config" / "twin.yaml").read_text())
    config.update(task=str(task), policy=str(tmp_path / "p.npz"))
    config["twin"]["scene"] = str(run_mod.REPO / "config" / "twin-scene.yaml")
    (tmp_path / "twin.yaml").write_text(yaml.safe_dump(config))
    with pytest.raises(run_mod.RunError, match="spied"):
        run_mod.run_scenario(
            scenario,
            config_path=tmp_path / "twin.yaml",
            out=tmp_path / "run",
            observations="table",
            say=lambda s: None,
        )
    assert int(seen["ROS_DOMAIN_ID"]) in domain_range()
    assert len(seen["VIGIL_RUN_ID"]) == 12
    assert os.environ["ROS_DOMAIN_ID"] == "0"  # the caller's own environment untouched

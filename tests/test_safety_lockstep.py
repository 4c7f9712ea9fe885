"""Run privacy and lock-step faults (issue 13): two runs never take each other's nodes
for their own, a stalled run ends with an error naming what stalled, stamps round
correctly."""

import os
import signal
import subprocess
import sys
import time

import pytest

from stack.exits import TEARDOWN_S
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
    from twin.ros_sensors import stamp_of

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
@pytest.mark.parametrize("process", ["twin_bridge", "container"])
def test_a_stalled_lockstep_run_ends_with_an_error_naming_what_stalled(tmp_path, process):
    """A participant that never comes: the bridge exits with EXIT_STALLED, and the
    launcher's reason names the missing node; the same with the bridge in the lock-step
    run's one process (vigil.container)."""
    from twin.bridge_node import EXIT_STALLED

    params = tmp_path / "params.yaml"
    params.write_text(
        "twin_bridge:\n  ros__parameters:\n    lockstep: true\n"
        "    participants: [ghost_planner]\n    stall_warn_s: 0.5\n"
        "    stall_timeout_s: 1.0\n    stall_abort_s: 3.0\n"
    )
    spec = ProcessSpec("twin_bridge", "twin.bridge_node", params, restart=False)
    if process == "container":
        argv = [sys.executable, "-u", "-m", "vigil.container", "--nodes", "twin_bridge"]
        command = [*argv, "--ros-args", "--params-file", str(params)]
        spec = ProcessSpec("container", "vigil.container", params, False, command=command)
    la = Launcher([spec], tmp_path / "logs", {"MUJOCO_GL": "egl"}, say=lambda s: None)
    la.start()
    deadline = time.monotonic() + 120
    try:
        while la.poll() and time.monotonic() < deadline:
            time.sleep(0.2)
    finally:
        la.stop(2.0)
    assert la.exit_codes[process] == EXIT_STALLED
    assert "lock-step stalled" in la.stopped_because
    assert "ghost_planner" in la.stopped_because
    # what vigil run makes of it: the "stalled" ending, its own exit code, the bridge's line
    from vigil.ending import KINDS, from_launcher

    ending = from_launcher(la)
    assert ending is not None and ending.kind == "stalled"
    assert ending.code == KINDS["stalled"] and "ghost_planner" in ending.cause


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
    # its last words said, its teardown hangs until its own alarm (stack.ros_main)
    hung = (
        "import signal, time\nfrom stack.ros_main import _teardown_alarm\n"
        "signal.signal(signal.SIGINT, lambda *a: (_teardown_alarm(), time.sleep(60)))\n"
        "print('ready', flush=True)\ntime.sleep(60)\n"
    )
    specs = [
        ProcessSpec("bad", "", command=[sys.executable, "-u", "-c", code]),
        ProcessSpec("good", "", command=[sys.executable, "-u", "-c", clean]),
        ProcessSpec("hung", "", command=[sys.executable, "-u", "-c", hung]),
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
    logs = [tmp_path / "logs" / f"{n}.log" for n in ("bad", "good", "hung")]
    while time.monotonic() < deadline and not all(
        p.exists() and "ready" in p.read_text() for p in logs
    ):
        time.sleep(0.1)
    assert la.poll()
    codes = la.stop(TEARDOWN_S + 5.0)
    assert codes == {"bad": 1, "good": 0, "hung": -signal.SIGALRM}
    assert la.failures == ["bad exited (code 1): [ERROR] boom at exit at shutdown"]
    assert la.warnings and la.warnings[0].startswith("hung: its ROS teardown hung")
    assert "Thread 0x" in (tmp_path / "logs" / "hung.log").read_text()  # its stacks


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


@pytest.mark.ros
@pytest.mark.usefixtures("private_ros_domain")
def test_a_participant_acknowledges_once_its_subscriptions_have_matched(ros):
    """A restarted node's first acknowledgement tells the coordinator "I hear from now
    on": it waits until its subscriptions have matched the publishers the graph knows
    (a reliable subscription never matches a best-effort publisher: it waits the most,
    then says which topic), while a topic nobody publishes holds it only briefly."""
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rostest import spin_until
    from std_msgs.msg import Empty
    from vigil_interfaces.msg import LockstepAck

    from stack.lockstep import ACK_TOPIC
    from stack.ros_lockstep import READY_MAX_S, READY_MIN_S, Participant

    heard: list[str] = []
    watcher = Node("watcher")
    watcher.create_subscription(LockstepAck, ACK_TOPIC, lambda m: heard.append(m.node), 50)
    talker = Node("talker")
    talker.create_publisher(Empty, "/ready_a", QoSProfile(depth=10))
    best_effort = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
    talker.create_publisher(Empty, "/ready_b", best_effort)
    quick, slow = Node("quick"), Node("slow")
    pq, ps = Participant(quick, True), Participant(slow, True)
    pq.subscription(Empty, "/ready_a", lambda m: None, 10)
    pq.subscription(Empty, "/nobody_publishes", lambda m: None, 10)
    ps.subscription(Empty, "/ready_b", lambda m: None, 10)  # made reliable: no match
    for n in (watcher, talker, quick, slow):
        ros.add_node(n)
    t0 = time.monotonic()
    assert spin_until(ros, lambda: "quick" in heard, READY_MAX_S - 1.0)
    assert time.monotonic() - t0 >= READY_MIN_S - 0.1  # not before discovery had its time
    assert not ps.ready and "slow" not in heard
    assert spin_until(ros, lambda: "slow" in heard, READY_MAX_S + 3.0)
    assert time.monotonic() - t0 >= READY_MAX_S - 0.1


@pytest.mark.ros
def test_the_batching_executor_calls_its_hooks_once_a_batch(ros):
    """Every callback ready at one wake-up runs before the hooks, which run once before
    each wait (what a participant's one acknowledgement a batch rests on)."""
    from rclpy.node import Node

    from stack.ros_main import BatchingExecutor

    log: list[str] = []
    node = Node("batching")
    gcs = [node.create_guard_condition(lambda i=i: log.append(f"gc{i}")) for i in (1, 2)]
    ex = BatchingExecutor()
    ex.before_wait.append(lambda: log.append("wait"))
    ex.add_node(node)
    for gc in gcs:
        gc.trigger()
    for _ in range(3):
        ex.spin_once(timeout_sec=0.05)
    assert log == ["wait", "gc1", "gc2", "wait"]
    ex.shutdown()
    node.destroy_node()


@pytest.mark.ros
def test_a_participant_acknowledges_a_batch_once_and_reads_matches_before_the_start(ros):
    from builtin_interfaces.msg import Time
    from rclpy.node import Node
    from rosgraph_msgs.msg import Clock
    from std_msgs.msg import Empty

    from stack.ros_lockstep import Participant
    from stack.ros_main import BatchingExecutor

    acks: list[dict] = []
    node = Node("batched")
    p = Participant(node, True)
    p.publisher(Empty, "/batched_out", 10)
    p.ready = True  # past its start-up wait
    p.ack = lambda: acks.append(dict(p._matched_counts()))  # type: ignore[method-assign]
    ex = BatchingExecutor()
    ex.add_node(node)
    for _ in range(3):  # three callbacks of one batch
        p.ack_soon()
    assert acks == []
    ex.spin_once(timeout_sec=0.01)  # the batch is over: one acknowledgement
    assert len(acks) == 1
    ex.spin_once(timeout_sec=0.01)
    assert len(acks) == 1  # nothing new, nothing sent

    asked: list[int] = []
    pub = p._publishers[0]
    pub.get_subscription_count = lambda: asked.append(1) or 0  # type: ignore[method-assign]
    p._matched_counts()
    assert len(asked) == 1  # before the first /clock: asked every time
    p._clock_cb(Clock(clock=Time(sec=1)))
    p._matched_counts()
    p._matched_counts()
    assert len(asked) == 1  # after it: the last answer...
    p._heartbeat()
    assert len(asked) == 2  # ...until a heartbeat asks again
    ex.shutdown()

    at_once: list[int] = []
    other = Node("unbatched")
    q = Participant(other, True)
    q.ready = True
    q.ack = lambda: at_once.append(1)  # type: ignore[method-assign]
    ros.add_node(other)
    q.ack_soon()
    assert at_once == [1]  # under another executor: at once

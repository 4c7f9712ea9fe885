"""The nodes of a lock-step twin run in one process (issue 25: the run at real time).

``python -m vigil.container --nodes twin_bridge,localisation,... --ros-args --params-file
FILE`` builds each named node (the same classes their own processes run, each reading
its own section of the parameters file) and spins them all on one
:class:`stack.ros_main.BatchingExecutor` (:func:`stack.ros_main.spin_nodes`). Nothing of
the lock-step protocol changes: the nodes still talk over ROS topics, the participants
still acknowledge their counts on ``/lockstep/ack`` and the bridge still waits for every
phase, so a run is the same as with one process a node (the same seed, the same steps
and trace). What goes is the cost of eleven interpreters waking for every message: one
executor wakes once for what every node has ready, and one process's messages to itself
never leave it (Fast DDS delivers them intra-process).

Only for the twin's lock-step run (:func:`vigil.system.prepare` decides, deployment key
``nodes.processes``): a real-time twin, a robot (``hardware``), a system over several
hosts and a scenario that kills one node need each node in its own process. One
process is one failure domain: a node that raises ends the process and so the run, as
the bridge's own exit does (a run with ``nodes.restart`` restarts nothing here); the
safety timeouts stay on the receiving side (the twin's base stops without ``/cmd_vel``,
the planner's observation timeout), as with separate processes.
"""

from __future__ import annotations

import argparse
import importlib
import re
import sys
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

from stack.cells import ConfigError
from stack.files import open_write
from vigil.deployment import Deployment
from vigil.processes import ProcessSpec
from vigil.scenario import Scenario
from vigil.system import System, write_params

# node name -> (module, node class, its last words or ""): what each module's main() spins
NODES: dict[str, tuple[str, str, str]] = {
    "twin_bridge": ("twin.bridge_node", "TwinBridge", ""),
    "localisation": ("stack.nav.node_localisation", "LocalisationNode", ""),
    "camera_people": ("stack.perception.node_camera_people", "CameraPeopleNode", ""),
    "legs": ("stack.perception.node_legs", "LegsNode", ""),
    "observations": ("stack.perception.node_observations", "ObservationsNode", ""),
    "navigation": ("stack.nav.node_navigation", "NavigationNode", "stop_base"),
    "speech": ("stack.nav.node_speech", "SpeechNode", ""),
    "planner": ("stack.planning.node_planner", "PlannerNode", ""),
    "recorder": ("vigil.node_recorder", "RecorderNode", ""),
    "markers": ("vigil.node_markers", "MarkersNode", ""),
    "bag": ("vigil.node_bag", "BagNode", ""),
}
PROCESS_NAME = "container"  # the process's name (its log, its exit code)
_LOGGED_BY = re.compile(r"\[[A-Z]+\] \[[0-9.]+\] \[([A-Za-z0-9_]+)\]")  # rclpy's line


def separate_because(dep: Deployment, scenario: Scenario | None) -> str:
    """Why a run's nodes need a process each ("" when one process can hold them all:
    a lock-step twin run whose scenario kills no node)."""
    if dep.mode != "twin":
        return "a robot's nodes run beside their hardware"
    if dep.hosts:
        return "the deployment spreads the nodes over hosts"
    if not dep.lockstep:
        return "only the lock-step twin runs in one process (a real-time twin does not)"
    kills = sorted({f.node for f in scenario.faults if f.kind == "kill"}) if scenario else []
    if kills:
        return f"the scenario kills {', '.join(kills)} (a node in its own process)"
    return ""


def one_process(dep: Deployment, system: System, scenario: Scenario | None, say=print) -> System:
    """``vigil run``: the system with its nodes in one process (:mod:`vigil.container`)
    when the deployment's ``nodes.processes`` asks for it ("one", or "auto" where
    :func:`separate_because` finds nothing against it); else ``system`` as it is.

    The nodes, their parameters and the run folder stay the same: only the processes
    change (one ``container`` process, never restarted: a node that fails ends the run).

    Raises:
        ConfigError: ``nodes.processes: one`` where one process cannot hold the nodes.
    """
    mode = dep.nodes.processes
    why = separate_because(dep, scenario)
    if mode == "one" and why:
        raise ConfigError("nodes.processes", mode, f"{why}: use separate (or auto)")
    if mode == "separate" or why:
        return system
    names = [s.name for s in system.specs]
    odd = [n for n in names if n not in NODES]
    if odd:  # a node the container does not know (none today): each in its own process
        say(f"[run] one process cannot hold {', '.join(odd)}: a process a node")
        return system
    params = dict(system.params)
    if "twin_bridge" in params:  # one process: the frame is rendered beside the nodes
        params["twin_bridge"] = {**params["twin_bridge"], "render_ahead": True}
    params_file = write_params(system.run_dir, names, params)
    command = [sys.executable, "-u", "-m", "vigil.container", "--nodes", ",".join(names)]
    spec = ProcessSpec(
        PROCESS_NAME,
        "vigil.container",
        params_file,
        restart=False,
        command=[*command, "--ros-args", "--params-file", str(params_file)],
    )
    return replace(system, specs=[spec], params=params)


def split_log(log_dir: Path, names: list[str]) -> None:
    """``<name>.log`` for each node, from the container's log: the lines its logger
    wrote (as its own process's log would have them; a traceback, whichever node's,
    stays in ``container.log`` alone)."""
    try:
        text = (log_dir / f"{PROCESS_NAME}.log").read_text(errors="replace")
    except OSError:
        return
    lines: dict[str, list[str]] = {n: [] for n in names}
    for line in text.splitlines(keepends=True):
        m = _LOGGED_BY.match(line)
        if m and m.group(1) in lines:
            lines[m.group(1)].append(line)
    for name, own in lines.items():
        try:
            with open_write(log_dir / f"{name}.log", "w") as f:
                f.write("".join(own))
        except OSError:  # a full disk: container.log holds them all the same
            return


def split_logs(system: System, log_dir: Path) -> None:
    """After a run: with its nodes in one process (:func:`one_process`), each node's
    log lines in ``<node>.log`` too, as with a process a node; else nothing."""
    for spec in system.specs:
        if spec.name == PROCESS_NAME and spec.command:
            split_log(log_dir, spec.command[spec.command.index("--nodes") + 1].split(","))


def makers(names: list[str]) -> list[tuple[Callable[[], Any], Callable[[Any], None] | None]]:
    """(node class, last words) of each node, in order.

    Raises:
        ValueError: a name that is not a node the container can hold.
    """
    out: list[tuple[Callable[[], Any], Callable[[Any], None] | None]] = []
    for name in names:
        if name not in NODES:
            raise ValueError(f"{name!r} is not a node the container can hold ({sorted(NODES)})")
        module_name, cls, last = NODES[name]
        module = importlib.import_module(module_name)
        out.append((getattr(module, cls), getattr(module, last) if last else None))
    return out


def main(argv: list[str] | None = None) -> None:
    argv = list(sys.argv[1:] if argv is None else argv)
    ros_at = argv.index("--ros-args") if "--ros-args" in argv else len(argv)
    ap = argparse.ArgumentParser(prog="python -m vigil.container", description=__doc__)
    ap.add_argument("--nodes", required=True, help="comma-separated node names, in order")
    ns = ap.parse_args(argv[:ros_at])
    try:
        built = makers([n for n in ns.nodes.split(",") if n])
    except ValueError as err:
        print(f"[FATAL] {PROCESS_NAME}: {err}", file=sys.stderr)
        sys.exit(2)
    # every QoS is the run's own (and a participant says which subscription never
    # matched): the middleware-event handlers are not waited for (their cost grows
    # with the square of the process's publishers and subscriptions)
    from stack.ros_main import spin_nodes  # rclpy: only in the process itself

    spin_nodes(built, ["vigil.container", *argv[ros_at:]], name=PROCESS_NAME, qos_events=False)


if __name__ == "__main__":
    main()

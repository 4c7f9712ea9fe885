"""The planner node: observations in, actions out, one decision step at a time (4.3).

Each step: choose an action from the belief, publish it, wait until navigation reports
the action done (a move: the robot entered its target cell; anything else: and at least
``min_step_s``), ask for the step's observations, update
the belief, record the step (section 4.3). A step also ends early, at least
``min_event_step_s`` after it began, when the observations show the person in a cell
other than at the last step (entering the room, a restricted cell, any new cell):
the robot reacts to a walker instead of finishing a move first. Navigation keeps
driving meanwhile; a next action toward the same cell does not stop it.

Subscribes (names are parameters):
    ``/nav/result`` std_msgs/String: navigation's JSON result of the action.
    ``/observations`` std_msgs/String: the observations node's JSON
        {"robot": "7", "person": "9", "velocity": "East higher", ...}.

Publishes:
    ``/nav/action`` std_msgs/String: "North", "South", "East", "West", "Do nothing".
    ``/observations/request`` std_msgs/Empty: asks for the step's observations.
    ``/planner/belief`` std_msgs/String: JSON {"robot": {"1": p, ...}, "person": {...},
        "direction": {...}} after every update.
    ``/planner/step`` std_msgs/String: JSON record of each step (as ``steps_file``).
    ``/planner/done`` std_msgs/String: JSON {steps} when ``max_steps`` are done.

Parameters: ``task_file``, ``policy_file`` (alpha vectors, ``vigil solve``),
``state_file`` (belief and step, written after every change; an existing one is
resumed), ``steps_file`` (JSON lines, appended), ``initial_robot_cell`` (0: the
task's), ``initial_person_cell`` (-1: the task's, 0: nobody), ``initial_direction``
("": the task's), ``max_steps`` (0: no end), ``start_delay_s``, ``nav_timeout_s``,
``obs_timeout_s``, ``resume_wait_s``, ``min_step_s`` (a step lasts at least this long: "Do
nothing" is done at once, but the model's time steps are of one length, about one
cell's move), ``min_event_step_s`` (a step ends on a person event no sooner; 0: no
events), ``lockstep`` (see :mod:`stack.ros_lockstep`).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from rclpy.node import Node
from std_msgs.msg import Empty, String

import stack.topics as topic
from stack.cells import ConfigError
from stack.planning.agent import ObservationError, Observed, PlannerAgent, StateFileError
from stack.planning.model import ACTIONS, build_model
from stack.planning.policy import AlphaPolicy
from stack.planning.task import load_task
from stack.ros_lockstep import Participant
from stack.ros_main import spin_node


class PlannerNode(Node):
    """Holds the policy and the belief; drives the decision steps."""

    def __init__(self, **kwargs):
        super().__init__("planner", **kwargs)
        p = self.declare_parameter
        task_file = p("task_file", "").value
        policy_file = p("policy_file", "").value
        self.state_file = p("state_file", "").value
        self.steps_file = p("steps_file", "").value
        robot = int(p("initial_robot_cell", 0).value)
        person = int(p("initial_person_cell", -1).value)
        direction = p("initial_direction", "").value
        self.max_steps = int(p("max_steps", 0).value)
        self.start_delay_s = float(p("start_delay_s", 1.0).value)
        self.nav_timeout_s = float(p("nav_timeout_s", 60.0).value)
        self.obs_timeout_s = float(p("obs_timeout_s", 5.0).value)
        self.resume_wait_s = float(p("resume_wait_s", 3.0).value)
        self.min_step_s = float(p("min_step_s", 0.0).value)
        self.min_event_step_s = float(p("min_event_step_s", 0.0).value)  # 0: no events
        if not task_file or not policy_file:
            raise ConfigError("task_file/policy_file", (task_file, policy_file), "both are needed")
        model = build_model(load_task(task_file))
        pomdp = model.flat()
        policy = AlphaPolicy.load(policy_file, pomdp.n_states)
        ini = model.task.initial
        first_person = ini.person if person < 0 else (person or None)
        b0 = model.initial_belief(
            robot or ini.robot, [(first_person, direction or ini.direction)] * model.people
        )
        self.agent = PlannerAgent(model, pomdp, policy, b0)
        self.resumed = False
        if self.state_file:
            try:
                self.resumed = self.agent.restore(self.state_file)
            except StateFileError as err:
                bad = self.state_file + ".bad"
                os.replace(self.state_file, bad)
                self.get_logger().error(f"{err}; kept as {bad}, starting from the initial belief")

        ls = self.lockstep = Participant(self, p("lockstep", False).value)
        self.pub_action = ls.publisher(String, topic.NAV_ACTION, 10)
        self.pub_request = ls.publisher(Empty, topic.OBSERVATIONS_REQUEST, 10)
        self.pub_belief = ls.publisher(String, topic.PLANNER_BELIEF, 10)
        self.pub_step = ls.publisher(String, topic.PLANNER_STEP, 10)
        self.pub_done = ls.publisher(String, topic.PLANNER_DONE, 10)
        ls.subscription(String, topic.NAV_RESULT, self.on_result, 10)
        ls.subscription(String, topic.OBSERVATIONS, self.on_observation, 10)
        ls.timer(0.1, self.poll)

        self.waiting = ""  # "" | "nav" | "hold" (min_step_s) | "obs"
        self.since_s = self.step_start_s = self.hold_until_s = 0.0
        self.requests = 0
        self.last_nav: dict | None = None
        self.sent_action = ""
        self.last_person = "" if first_person is None else str(first_person)
        self.started = False
        what = f"resuming at step {self.agent.step + 1}" if self.resumed else "initial belief"
        self.get_logger().info(
            f"planner: {Path(task_file).name}, {len(policy.alphas)} vectors, {what}"
        )

    def now_s(self) -> float:
        return self.lockstep.now_s()

    # -- the step machine --------------------------------------------------------------
    def poll(self) -> None:
        now = self.now_s()
        if not self.started:
            if now < self.start_delay_s:
                return
            self.started = True
            self.start()
            return
        if self.waiting == "hold" and now >= self.hold_until_s:
            self.request_observations()
        elif self.waiting == "nav" and now - self.since_s > self.nav_timeout_s:
            self.get_logger().warning(
                f"no navigation result for {self.nav_timeout_s:g} s: reading observations"
            )
            self.last_nav = {"result": "timeout"}
            self.request_observations()
        elif self.waiting == "obs" and now - self.since_s > self.obs_timeout_s:
            self.get_logger().warning(
                f"no observations {self.obs_timeout_s:g} s after request {self.requests}: "
                "asking again"
            )
            self.request_observations()

    def start(self) -> None:
        phase = self.agent.phase
        if phase == "done":
            self.finish()
        elif phase == "acting":  # the action's result may have been lost while down
            self.waiting, self.since_s = (
                "nav",
                self.now_s() - self.nav_timeout_s + self.resume_wait_s,
            )
            self.get_logger().info(f"resumed during step {self.agent.step + 1}: waiting for it")
        else:
            self.act()

    def act(self) -> None:
        if self.max_steps and self.agent.step >= self.max_steps:
            self.finish()
            return
        a = self.agent.decide()
        self.save()
        self.waiting, self.since_s, self.last_nav = "nav", self.now_s(), None
        self.step_start_s = self.since_s
        self.sent_action = ACTIONS[a]
        self.pub_action.publish(String(data=ACTIONS[a]))
        self.get_logger().info(f"step {self.agent.step + 1}: {ACTIONS[a]}")

    def request_observations(self) -> None:
        self.waiting, self.since_s = "obs", self.now_s()
        self.requests += 1
        self.pub_request.publish(Empty())

    def on_result(self, msg: String) -> None:
        try:
            body = json.loads(msg.data)
        except ValueError:
            body = {"result": "malformed", "raw": msg.data[:200]}
            self.get_logger().warning(f"malformed navigation result {msg.data[:80]!r}")
        if self.waiting != "nav":
            return  # a result nobody waits for (e.g. after a timeout)
        if isinstance(body, dict) and body.get("action") not in (None, self.sent_action):
            return  # the result of an earlier action, superseded
        self.last_nav = body if isinstance(body, dict) else {"result": str(body)}
        self.hold_until_s = self.step_start_s + self.min_step_s
        moved = self.sent_action != "Do nothing" and self.last_nav.get("result") == "succeeded"
        if moved or self.now_s() >= self.hold_until_s:  # a move ends on arrival
            self.request_observations()
        else:
            self.waiting = "hold"

    @staticmethod
    def _person_key(label: str) -> str:
        return label if label.isdigit() else ""

    def on_observation(self, msg: String) -> None:
        if self.waiting not in ("obs", "nav", "hold"):
            return
        try:
            observed = Observed.from_dict(json.loads(msg.data))
        except (ValueError, ObservationError) as err:
            self.get_logger().error(f"observation ignored: {err}", throttle_duration_sec=5.0)
            return
        trigger = "step"
        if self.waiting != "obs":  # an event: the person shows up in a new cell
            person = self._person_key(observed.person)
            elapsed = self.now_s() - self.step_start_s
            if not (
                self.min_event_step_s > 0
                and person
                and person != self.last_person
                and elapsed >= self.min_event_step_s
            ):
                return
            trigger = f"person in {person}"
            if self.last_nav is None:
                self.last_nav = {"result": "in progress", "action": self.sent_action}
        try:
            record = self.agent.observe(observed)
        except (ValueError, ObservationError) as err:
            self.get_logger().error(f"observation ignored: {err}")
            return
        self.last_person = self._person_key(observed.person)
        record.update(
            stamp_s=round(self.now_s(), 6), nav=self.last_nav, resumed=self.resumed, trigger=trigger
        )
        self.resumed = False
        self.waiting = ""
        self.save()
        self.write_record(record)
        self.pub_belief.publish(String(data=json.dumps(record["belief"])))
        self.pub_step.publish(String(data=json.dumps(record)))
        o = record["observation"]
        self.get_logger().info(
            f"step {record['step']}: {record['action']} -> robot {o['robot']}, "
            f"person {o['person']}, {o['velocity']}"
        )
        self.act()

    def finish(self) -> None:
        self.agent.phase = "done"
        self.waiting = ""
        self.save()
        self.pub_done.publish(String(data=json.dumps({"steps": self.agent.step})))
        self.get_logger().info(f"done after {self.agent.step} steps")

    # -- files --------------------------------------------------------------------------
    def save(self) -> None:
        if self.state_file:
            self.agent.save(self.state_file)

    def write_record(self, record: dict) -> None:
        if not self.steps_file:
            return
        with open(self.steps_file, "a") as f:
            f.write(json.dumps(record, sort_keys=True) + "\n")
            f.flush()
            os.fsync(f.fileno())


def main(args=None) -> None:
    spin_node(PlannerNode, args)


if __name__ == "__main__":
    main()

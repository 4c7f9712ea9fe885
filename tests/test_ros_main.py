"""The one node main loop (stack/ros_main.spin_node): a stop signal never interrupts a
callback halfway (CI saw the planner exit 1 with pybind11's "Unable to convert call
argument" when SIGINT raised inside rclpy's message conversion)."""

import os
import subprocess
import sys
import textwrap

import pytest

pytest.importorskip("rclpy")

# the node's timer signals its own process, then keeps working: every line must be done
NODE = textwrap.dedent(
    """
    import os, signal, sys
    from rclpy.node import Node
    from std_msgs.msg import String
    from stack.ros_main import spin_node

    class Busy(Node):
        def __init__(self):
            super().__init__("busy")
            self.pub = self.create_publisher(String, "/busy", 10)
            self.create_timer(0.05, self.tick)
            self.ticks = 0

        def tick(self):
            self.ticks += 1
            if self.ticks == 3:
                os.kill(os.getpid(), signal.{sig})
                for i in range(20000):  # far more bytecodes than a signal waits for
                    self.pub.publish(String(data=str(i)))
                print("callback finished", file=sys.stderr, flush=True)

    def last_words(node):
        print(f"last words after {{node.ticks}} ticks", file=sys.stderr, flush=True)

    spin_node(Busy, on_exit=last_words)
    """
)


def _run(code: str, timeout_s: float) -> subprocess.CompletedProcess:
    """A node's script in a Python process of its own."""
    return subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=timeout_s,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )


@pytest.mark.ros
@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
def test_a_signal_during_a_callback_lets_it_finish_and_the_node_exits_0(sig):
    proc = _run(NODE.format(sig=sig), 60)
    assert proc.returncode == 0, proc.stderr
    assert "callback finished" in proc.stderr
    # the loop stops after the callback in which the signal came, before another tick
    assert "last words after 3 ticks" in proc.stderr
    assert "Traceback" not in proc.stderr


@pytest.mark.ros
def test_a_slow_release_of_the_nodes_files_is_not_cut_short_by_the_teardown_alarm():
    """The teardown alarm (stack.exits.TEARDOWN_S) covers the middleware's teardown
    only: a :class:`stack.ros_main.Releasing` node's release (closing a bag, a trace)
    runs before it is set, however long it takes, and the node exits 0."""
    from stack.exits import TEARDOWN_S

    code = textwrap.dedent(
        f"""
        import os, signal, sys, time
        from rclpy.node import Node
        from stack.ros_main import Releasing, spin_node

        class Slow(Releasing, Node):
            def __init__(self):
                super().__init__("slow")
                self.create_timer(0.05, lambda: os.kill(os.getpid(), signal.SIGINT))

            def _release(self):
                time.sleep({TEARDOWN_S + 1.0})
                print("released", file=sys.stderr, flush=True)

        spin_node(Slow)
        """
    )
    proc = _run(code, 120)
    assert proc.returncode == 0, proc.stderr
    assert "released" in proc.stderr


@pytest.mark.ros
def test_nodes_in_one_process_each_say_their_last_words_and_release_even_if_one_fails():
    """stack.ros_main.spin_nodes (the lock-step twin's one process, vigil.container):
    on a stop, every node's last words, then every node's release, then the teardown,
    each for every node although the first node's last words raise; the error is then
    raised (the process fails) once all of it is done."""
    code = textwrap.dedent(
        """
        import os, signal, sys
        from rclpy.node import Node
        from stack.ros_main import Releasing, spin_nodes

        class Holder(Releasing, Node):
            def __init__(self, name):
                super().__init__(name)
                if name == "b":
                    self.create_timer(0.2, lambda: os.kill(os.getpid(), signal.SIGINT))

            def _release(self):
                print(f"released {self.get_name()}", file=sys.stderr, flush=True)

        def failing(node):
            raise RuntimeError("last words of a failed")

        def fine(node):
            print(f"last words of {node.get_name()}", file=sys.stderr, flush=True)

        spin_nodes([(lambda: Holder("a"), failing), (lambda: Holder("b"), fine)])
        """
    )
    proc = _run(code, 60)
    assert proc.returncode == 1, proc.stderr
    said = [line for line in proc.stderr.splitlines() if line.startswith(("last", "released"))]
    assert said == ["last words of b", "released a", "released b"], proc.stderr
    assert "RuntimeError: last words of a failed" in proc.stderr

"""SROS2 for hardware mode (issue 13): the keystore ``vigil security keystore`` writes,
and what happens when a secured deployment meets the DDS installed here.

With DDS Security available, the two-process test shows that a participant without a
certificate can neither arm nor drive while the operator's enclave can. The Fast DDS
of the PyPI rmw_fastrtps_cpp wheel has no security plugins: there a keystore is
refused with an error naming what is missing, and a node asked to enforce security
refuses to start rather than run open (both tested).
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from stack.cells import ConfigError
from vigil.security import create_keystore, security_env, security_support

REPO = Path(__file__).resolve().parents[1]
HERE = REPO / "tests" / "safety_peers"

pytestmark = [pytest.mark.slow, pytest.mark.ros]


@pytest.fixture(scope="module")
def keystore(tmp_path_factory):
    path = tmp_path_factory.mktemp("ks") / "keystore"
    names = create_keystore(path, domain_id=42)
    return path, names


def openssl(*args):
    return subprocess.run(["openssl", *args], capture_output=True, text=True, timeout=30)


def test_keystore_layout_signatures_and_permissions(keystore):
    path, names = keystore
    assert "/vigil/velocity_gate" in names and "/vigil/operator" in names
    ca = path / "public" / "ca.cert.pem"
    assert (path / "private" / "ca.key.pem").stat().st_mode & 0o077 == 0
    gov = openssl("smime", "-verify", "-in", str(path / "enclaves" / "governance.p7s"),
                  "-CAfile", str(ca), "-out", "/dev/stdout")  # fmt: skip
    assert gov.returncode == 0 and "<data_protection_kind>ENCRYPT" in gov.stdout
    assert "<allow_unauthenticated_participants>false" in gov.stdout
    for name in names:
        d = path / "enclaves" / name.strip("/")
        for f in ("cert.pem", "key.pem", "permissions.p7s", "governance.p7s",
                  "identity_ca.cert.pem", "permissions_ca.cert.pem"):  # fmt: skip
            assert (d / f).exists(), (name, f)
        assert openssl("verify", "-CAfile", str(ca), str(d / "cert.pem")).returncode == 0
        subject = openssl("x509", "-in", str(d / "cert.pem"), "-noout", "-subject").stdout
        assert f"CN = {name}" in subject
        perms = openssl("smime", "-verify", "-in", str(d / "permissions.p7s"),
                        "-CAfile", str(ca), "-out", "/dev/stdout")  # fmt: skip
        assert perms.returncode == 0
        text = perms.stdout
        deny = (
            text.split("<deny_rule>")[1].split("</deny_rule>")[0] if "<deny_rule>" in text else ""
        )
        pub_denied = deny.split("</publish>")[0] if "<publish>" in deny else ""
        may_drive = "rt/cmd_vel" not in pub_denied
        may_arm = "rt/arm" not in pub_denied
        may_beat = "rt/velocity_gate/heartbeat" not in pub_denied  # no forged heartbeat
        assert may_drive == (name == "/vigil/velocity_gate"), name
        assert may_beat == (name == "/vigil/velocity_gate"), name
        assert may_arm == (name == "/vigil/operator"), name
        may_observe = "rt/observations" not in pub_denied  # a forged one steers the planner
        assert may_observe == (name == "/vigil/observations"), name
        assert ("rq/velocity_gate/set_parametersRequest" not in pub_denied) == (
            name == "/vigil/operator"
        )
    # never over an existing keystore
    with pytest.raises(ConfigError, match="new or empty"):
        create_keystore(path, domain_id=42)


def test_a_secured_deployment_is_refused_where_dds_cannot_enforce_it(keystore, tmp_path):
    from vigil.deployment import parse_deployment

    ok, why = security_support()
    (tmp_path / "cal.yaml").write_text("unused: true\n")
    data = yaml.safe_load((REPO / "config" / "hardware.yaml").read_text())
    data.update(task=str(REPO / "config" / "task-r2.yaml"), perception={"calibration": "cal.yaml"})
    data["ros"] = {**data["ros"], "keystore": str(keystore[0])}
    if ok:
        dep = parse_deployment(data, tmp_path / "hardware.yaml")
        assert dep.ros.keystore
        return
    with pytest.raises(ConfigError) as err:
        parse_deployment(data, tmp_path / "hardware.yaml")
    assert err.value.key == "ros.keystore" and "without DDS Security" in str(err.value)


def spawn(script, seconds, env):
    return subprocess.Popen(
        [sys.executable, str(HERE / script), str(seconds)],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


def clean_env(domain):
    env = {k: v for k, v in os.environ.items() if not k.startswith(("ROS_SECURITY", "ROS_DOMAIN"))}
    env.update(ROS_DOMAIN_ID=str(domain), PYTHONPATH=str(REPO))
    return env


def test_an_enforcing_node_never_runs_open(keystore):
    """Where DDS lacks security, a node told to enforce it fails to start (it does not
    fall back to an open participant)."""
    if security_support()[0]:
        pytest.skip("DDS Security present: covered by the two-process test")
    env = {**clean_env(42), **security_env(keystore[0])}
    env["ROS_SECURITY_ENCLAVE_OVERRIDE"] = "/vigil/velocity_gate"
    proc = spawn("listen_arm.py", 3, env)
    out, _ = proc.communicate(timeout=60)
    assert proc.returncode != 0 and "READY" not in out
    assert "security" in out.lower()


def test_without_a_certificate_a_participant_can_neither_arm_nor_drive(keystore):
    ok, why = security_support()
    if not ok:
        pytest.skip(f"cannot be enforced here: {why}")
    path = keystore[0]
    gate = {
        **clean_env(42),
        **security_env(path),
        "ROS_SECURITY_ENCLAVE_OVERRIDE": "/vigil/velocity_gate",
    }
    listener = spawn("listen_arm.py", 10, gate)
    assert listener.stdout.readline().strip() == "READY"
    intruder = subprocess.run(
        [sys.executable, str(HERE / "publish_arm.py"), "5"], env=clean_env(42),
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    out, _ = listener.communicate(timeout=60)
    assert out.strip().splitlines()[-1] == "RECEIVED arm=0 cmd_vel=0", intruder.stdout
    # the operator's enclave may arm
    listener = spawn("listen_arm.py", 10, gate)
    assert listener.stdout.readline().strip() == "READY"
    operator = {
        **clean_env(42),
        **security_env(path),
        "ROS_SECURITY_ENCLAVE_OVERRIDE": "/vigil/operator",
    }
    subprocess.run([sys.executable, str(HERE / "publish_arm.py"), "5"], env=operator, timeout=60)
    out, _ = listener.communicate(timeout=60)
    last = out.strip().splitlines()[-1]
    assert last.startswith("RECEIVED arm=") and not last.startswith("RECEIVED arm=0 ")

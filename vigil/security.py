"""SROS2 for hardware mode: a keystore, the nodes' environment, and whether DDS can enforce it.

``vigil security keystore DIR --domain N`` writes an SROS2 keystore (the layout of
``ros2 security create_keystore`` + ``create_enclave``, made with the ``openssl``
command instead of Python's ``cryptography``):

    DIR/public/{identity_ca,permissions_ca}.cert.pem   (one CA: ca.cert.pem)
    DIR/private/ca.key.pem
    DIR/enclaves/governance.xml, governance.p7s
    DIR/enclaves/vigil/<enclave>/{cert,key}.pem, permissions.xml, permissions.p7s,
        identity_ca.cert.pem, permissions_ca.cert.pem, governance.p7s

Governance: no unauthenticated participant joins, discovery, liveliness and every
topic's data are encrypted, read and write access are controlled. Permissions
(:data:`ENCLAVES`): only ``/vigil/velocity_gate`` may publish the base's command topic,
only ``/vigil/operator`` may publish ``/arm`` or set the gate's parameters (the other
way to arm), only ``/vigil/base_driver`` (the MBot's driver) may subscribe to the base
topic, only ``/vigil/observations`` may publish ``/observations`` (what the planner
believes); every other node may use any other topic (the sensors' included).

Whether it can be enforced (:func:`security_support`): the ``rmw_fastrtps_cpp`` wheel from
PyPI here ships Fast DDS 2.14.5 built without DDS Security (no
``eprosima::fastrtps::rtps::security`` symbols; the library holds the message "Received
PID_PARTICIPANT_SECURITY_INFO but security is disabled"). With it, ``ROS_SECURITY_*``
would be accepted and silently not enforced, so :func:`require_support` refuses to
start a secured deployment on it (fail safe) and names what is missing.
"""

from __future__ import annotations

import ctypes.util
import os
import secrets
import subprocess
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path

import stack.topics as topic
from stack.cells import ConfigError
from stack.files import PrivateOutput, make_dir, write_text
from vigil.run_folder import check_own_folder

ENCLAVE_ROOT = "/vigil"
BASE_TOPIC = topic.CMD_VEL


@dataclass(frozen=True)
class Grant:
    """What one enclave may do beyond the common rule (topic names without ``rt``)."""

    publish: tuple[str, ...] = ()
    subscribe: tuple[str, ...] = ()
    set_gate_params: bool = False


NODES = (
    "camera_stream",
    "camera_people",
    "localisation",
    "legs",
    "observations",
    "navigation",
    "speech",
    "planner",
    "recorder",
    "markers",
)


def enclaves(base_topic: str = BASE_TOPIC) -> dict[str, Grant]:
    """Every enclave of a hardware deployment and its extra rights."""
    out = {name: Grant() for name in NODES}
    out["velocity_gate"] = Grant(publish=(base_topic, topic.GATE_HEARTBEAT), subscribe=(topic.ARM,))
    out["operator"] = Grant(publish=(topic.ARM,), set_gate_params=True)
    out["base_driver"] = Grant(subscribe=(base_topic,))
    out["observations"] = Grant(publish=(topic.OBSERVATIONS,))  # what the planner believes
    return out


ENCLAVES = enclaves()


class KeystoreError(RuntimeError):
    """The keystore could not be made (openssl missing or failing)."""


def _openssl(*args: str, cwd: Path | None = None) -> None:
    try:
        proc = subprocess.run(
            ["openssl", *args], capture_output=True, text=True, cwd=cwd, timeout=60
        )
    except FileNotFoundError:
        raise KeystoreError("the openssl command is not installed") from None
    if proc.returncode != 0:
        raise KeystoreError(f"openssl {args[0]} failed: {proc.stderr.strip()[:300]}")


def _openssl_to(dst: Path, *args: str, mode: int = 0o644) -> None:
    """``openssl ARGS -out FILE``, where openssl would open ``dst`` by name and follow a
    link there: it writes into a folder of its own (mode 0700) and the file, given
    ``mode`` there (a private key 0600: never readable by others, even for a moment),
    is moved to ``dst`` (a link at ``dst`` is refused)."""
    with PrivateOutput(dst) as out:
        _openssl(*args, "-out", str(out.path))
        os.chmod(out.path, mode)


def governance_xml(domain_id: int) -> str:
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<dds xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance"
    xsi:noNamespaceSchemaLocation="http://www.omg.org/spec/DDS-SECURITY/20170901/omg_shared_ca_governance.xsd">
  <domain_access_rules>
    <domain_rule>
      <domains><id>{domain_id}</id></domains>
      <allow_unauthenticated_participants>false</allow_unauthenticated_participants>
      <enable_join_access_control>true</enable_join_access_control>
      <discovery_protection_kind>ENCRYPT</discovery_protection_kind>
      <liveliness_protection_kind>ENCRYPT</liveliness_protection_kind>
      <rtps_protection_kind>SIGN</rtps_protection_kind>
      <topic_access_rules>
        <topic_rule>
          <topic_expression>*</topic_expression>
          <enable_discovery_protection>true</enable_discovery_protection>
          <enable_liveliness_protection>true</enable_liveliness_protection>
          <enable_read_access_control>true</enable_read_access_control>
          <enable_write_access_control>true</enable_write_access_control>
          <metadata_protection_kind>ENCRYPT</metadata_protection_kind>
          <data_protection_kind>ENCRYPT</data_protection_kind>
        </topic_rule>
      </topic_access_rules>
    </domain_rule>
  </domain_access_rules>
</dds>
"""


def _topics(kind: str, names) -> str:
    inner = "".join(f"<topic>{n}</topic>" for n in names)
    return f"<{kind}><topics>{inner}</topics></{kind}>"


def permissions_xml(enclave: str, grant: Grant, domain_id: int, base_topic: str) -> str:
    """DDS permissions of one enclave: the guarded topics denied unless granted, the
    rest allowed. Rules are read in order; the first that matches decides."""
    now = datetime.now(UTC)
    start = now.strftime("%Y-%m-%dT%H:%M:%S")
    end = (now + timedelta(days=3650)).strftime("%Y-%m-%dT%H:%M:%S")
    # a forged heartbeat hides a dead gate; forged observations steer the planner
    guarded = (base_topic, topic.ARM, topic.GATE_HEARTBEAT, topic.OBSERVATIONS)
    guarded_pub = {f"rt{t}" for t in guarded} - {f"rt{t}" for t in grant.publish}
    guarded_sub = {f"rt{base_topic}"} - {f"rt{t}" for t in grant.subscribe}
    params = {
        "rq/velocity_gate/set_parametersRequest",
        "rq/velocity_gate/set_parameters_atomicallyRequest",
    }
    deny = ""
    if guarded_pub or guarded_sub or not grant.set_gate_params:
        body = _topics(
            "publish", sorted(guarded_pub | (set() if grant.set_gate_params else params))
        )
        if guarded_sub:
            body += _topics("subscribe", sorted(guarded_sub))
        deny = f"<deny_rule><domains><id>{domain_id}</id></domains>{body}</deny_rule>"
    allow = (
        f"<allow_rule><domains><id>{domain_id}</id></domains>"
        f"{_topics('publish', ['*'])}{_topics('subscribe', ['*'])}</allow_rule>"
    )
    name = f"{ENCLAVE_ROOT}/{enclave}"
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<dds xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance"
    xsi:noNamespaceSchemaLocation="http://www.omg.org/spec/DDS-SECURITY/20170901/omg_shared_ca_permissions.xsd">
  <permissions>
    <grant name="{name}">
      <subject_name>CN={name}</subject_name>
      <validity><not_before>{start}</not_before><not_after>{end}</not_after></validity>
      {deny}
      {allow}
      <default>DENY</default>
    </grant>
  </permissions>
</dds>
"""


def create_keystore(
    path: str | Path, domain_id: int, base_topic: str = BASE_TOPIC, days: int = 3650
) -> list[str]:
    """Write a keystore into ``path`` (a new or empty folder); returns the enclave names.

    Raises:
        ConfigError: ``path`` is a non-empty folder or a file, or a bad domain id.
        KeystoreError: openssl failed.
    """
    root = Path(path)
    if os.path.islink(root) and not root.exists():
        raise ConfigError("keystore", str(root), "is a symbolic link to nothing")
    if root.exists() and (not root.is_dir() or any(root.iterdir())):
        raise ConfigError("keystore", str(root), "must be a new or empty folder")
    if not 0 <= domain_id <= 232:
        raise ConfigError("domain_id", domain_id, "must be in [0, 232]")
    root.mkdir(mode=0o755, parents=True, exist_ok=True)
    check_own_folder(root, "keystore")  # no one else may swap what lies in it
    public, private, encl = root / "public", root / "private", root / "enclaves"
    make_dir(public)
    make_dir(private, 0o700)
    make_dir(encl)
    os.chmod(private, 0o700)
    ca_key, ca_cert = private / "ca.key.pem", public / "ca.cert.pem"
    _openssl_to(ca_key, "ecparam", "-name", "prime256v1", "-genkey", "-noout", mode=0o600)
    _openssl_to(
        ca_cert, "req", "-new", "-x509", "-key", str(ca_key),
        "-days", str(days), "-subj", "/CN=vigil_ca", "-sha256",
    )  # fmt: skip
    for name in ("identity_ca", "permissions_ca"):
        (public / f"{name}.cert.pem").symlink_to("ca.cert.pem")
        (private / f"{name}.key.pem").symlink_to("ca.key.pem")

    def sign(src: Path, dst: Path) -> None:
        _openssl_to(
            dst, "smime", "-sign", "-text", "-in", str(src),
            "-signer", str(ca_cert), "-inkey", str(ca_key),
        )  # fmt: skip

    write_text(encl / "governance.xml", governance_xml(domain_id))
    sign(encl / "governance.xml", encl / "governance.p7s")
    names = []
    for enclave, grant in enclaves(base_topic).items():
        d = encl / ENCLAVE_ROOT.strip("/") / enclave
        make_dir(d.parent)
        make_dir(d)
        key, csr, cert = d / "key.pem", d / "req.csr", d / "cert.pem"
        _openssl_to(key, "ecparam", "-name", "prime256v1", "-genkey", "-noout", mode=0o600)
        subj = "/CN=" + f"{ENCLAVE_ROOT}/{enclave}".replace("/", "\\/")  # CN=/vigil/<name>
        _openssl_to(csr, "req", "-new", "-key", str(key), "-subj", subj, "-sha256")
        # a random serial: -CAcreateserial would write ca.cert.srl by name beside the CA
        _openssl_to(
            cert, "x509", "-req", "-in", str(csr), "-CA", str(ca_cert), "-CAkey", str(ca_key),
            "-set_serial", str(secrets.randbits(63) | 1), "-days", str(days), "-sha256",
        )  # fmt: skip
        csr.unlink()
        perms = d / "permissions.xml"
        write_text(perms, permissions_xml(enclave, grant, domain_id, base_topic))
        sign(perms, d / "permissions.p7s")
        for link, target in (
            ("identity_ca.cert.pem", public / "ca.cert.pem"),
            ("permissions_ca.cert.pem", public / "ca.cert.pem"),
            ("governance.p7s", encl / "governance.p7s"),
        ):
            (d / link).symlink_to(os.path.relpath(target, d))
        names.append(f"{ENCLAVE_ROOT}/{enclave}")
    return names


def security_env(keystore: str | Path) -> dict[str, str]:
    """Environment for every node of a secured deployment (the enclave per node is
    set by the launcher: ``ROS_SECURITY_ENCLAVE_OVERRIDE=/vigil/<node>``)."""
    return {
        "ROS_SECURITY_KEYSTORE": str(Path(keystore).resolve()),
        "ROS_SECURITY_ENABLE": "true",
        "ROS_SECURITY_STRATEGY": "Enforce",
    }


def _fastdds_library() -> Path | None:
    import importlib.util

    spec = importlib.util.find_spec("rclpy")  # located, not imported: no ROS here
    if spec is None or spec.origin is None:
        return None
    venv_lib = Path(spec.origin).resolve().parents[3]  # <prefix>/lib beside site-packages
    for folder in (venv_lib, venv_lib.parent, Path("/opt/ros/jazzy/lib")):
        for name in ("libfastrtps.so", "libfastdds.so"):
            if (folder / name).exists():
                return (folder / name).resolve()
    found = ctypes.util.find_library("fastrtps") or ctypes.util.find_library("fastdds")
    return Path(found) if found and Path(found).is_absolute() else None


def security_support() -> tuple[bool, str]:
    """Can the installed Fast DDS enforce DDS Security? (answer, why)"""
    lib = _fastdds_library()
    if lib is None:
        return False, "no Fast DDS library found beside rclpy"
    data = lib.read_bytes()
    if b"security is disabled" in data and b"PKIDH" not in data:
        return False, (
            f"{lib.name} (from the rmw_fastrtps_cpp wheel) is built without DDS Security "
            "(no PKI-DH authentication, no AES-GCM-GMAC cryptography plugin): install a "
            "ROS 2 Jazzy build with Fast DDS security (the Debian/Ubuntu ros-jazzy packages) "
            "to enforce the keystore"
        )
    return True, f"{lib.name} has the DDS Security plugins"


def require_support() -> None:
    """Refuse a secured deployment that DDS would not enforce.

    Raises:
        ConfigError: key ``ros.keystore``, naming what is missing.
    """
    ok, why = security_support()
    if not ok:
        raise ConfigError("ros.keystore", "set", f"cannot be enforced here: {why}")


def main_keystore(path: str, domain_id: int, base_topic: str, say=print) -> int:
    names = create_keystore(path, domain_id, base_topic)
    say(f"keystore {path}: domain {domain_id}, {len(names)} enclaves: {', '.join(names)}")
    ok, why = security_support()
    say(("enforceable here: " if ok else "NOT enforceable here: ") + why)
    return 0


__all__ = [
    "ENCLAVES",
    "Grant",
    "KeystoreError",
    "create_keystore",
    "require_support",
    "security_env",
    "security_support",
]

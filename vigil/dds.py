"""Who can reach the nodes: a Fast DDS XML profile that every node the launcher starts uses.

``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` only narrows discovery: the participants
still bind their UDP ports on 0.0.0.0, and a peer on another interface that sends to
them is heard (it armed the gate). The profile below replaces Fast DDS's built-in
transports by one UDPv4 transport whose interface whitelist holds only the given
addresses (127.0.0.1 in the twin, plus the robot network's address in hardware
mode), and announces and seeks peers on those addresses only. Sockets are then bound
to the whitelisted addresses, so a packet from another host never reaches them.

Shared memory stays (camera frames of 768 kB would otherwise be copied through the
kernel once per subscriber; UDP-only measured a heavier, stalling twin under load): it
only reaches processes of this machine, and only after discovery, which runs over the
whitelisted UDP alone.

Environment set for every node (:func:`dds_env`): ``FASTRTPS_DEFAULT_PROFILES_FILE``
and ``FASTDDS_DEFAULT_PROFILES_FILE`` (both names, old and new releases),
``RMW_IMPLEMENTATION=rmw_fastrtps_cpp`` (the profile is Fast DDS's), and
``ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET``: with ``LOCALHOST`` the rmw layer adds sockets
of its own on 0.0.0.0 and on the host's address (measured with ``ss -ulpn``), with
``SUBNET`` every socket is bound to a whitelisted address; the profile, not the
range, confines discovery.

Measured (tests/test_safety_network.py, a second network namespace over veth): a
publisher in the other namespace that names this host as its peer delivered 34
``/arm`` messages to a subscriber with today's settings, and none with the profile.
"""

from __future__ import annotations

from pathlib import Path
from xml.sax.saxutils import escape

from stack.cells import ConfigError
from stack.config import write_text

PROFILE_FILE = "fastdds.xml"
# participants per host and domain that find each other: Fast DDS sends its unicast
# announcements to participant ids 0..maxInitialPeersRange-1 (default 4, too few for a
# system of nine nodes without multicast: measured, the 6th and later never met)
MAX_PARTICIPANTS = 64
LOOPBACK = "127.0.0.1"
MULTICAST = "239.255.0.1"  # discovery off loopback


def _ipv4(text: str) -> str:
    parts = text.split(".")
    if len(parts) != 4 or not all(p.isdigit() and int(p) <= 255 for p in parts):
        raise ConfigError("ros.interfaces", text, "must be an IPv4 address like 10.0.0.2")
    return ".".join(str(int(p)) for p in parts)


def _locators(addresses: list[str]) -> str:
    return "".join(
        f"<locator><udpv4><address>{escape(a)}</address></udpv4></locator>" for a in addresses
    )


def profile_xml(
    addresses: list[str] | tuple[str, ...] = (), peers: list[str] | tuple[str, ...] = ()
) -> str:
    """The Fast DDS profile restricting every participant to ``addresses`` (+ loopback);
    ``peers``, other hosts' addresses, are asked directly at discovery besides.

    Raises:
        ConfigError: an address that is not IPv4.
    """
    allowed = [LOOPBACK] + [a for a in (_ipv4(x) for x in addresses) if a != LOOPBACK]
    white = "".join(f"<address>{escape(a)}</address>" for a in allowed)
    locators = _locators(allowed)
    asked = _locators([a for a in (_ipv4(x) for x in peers) if a not in allowed])
    # off loopback (the robot network): multicast discovery on the listed addresses too
    multicast = (
        f"<metatrafficMulticastLocatorList>{_locators([MULTICAST])}"
        "</metatrafficMulticastLocatorList>"
        if len(allowed) > 1
        else ""
    )
    return f"""<?xml version="1.0" encoding="UTF-8" ?>
<!-- written by vigil (vigil/dds.py): DDS on {", ".join(allowed)} only -->
<dds xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <profiles>
    <transport_descriptors>
      <transport_descriptor>
        <transport_id>vigil_shm</transport_id>
        <type>SHM</type>
      </transport_descriptor>
      <transport_descriptor>
        <transport_id>vigil_udp</transport_id>
        <type>UDPv4</type>
        <maxInitialPeersRange>{MAX_PARTICIPANTS}</maxInitialPeersRange>
        <interfaceWhiteList>{white}</interfaceWhiteList>
      </transport_descriptor>
    </transport_descriptors>
    <participant profile_name="vigil_participant" is_default_profile="true">
      <rtps>
        <userTransports>
          <transport_id>vigil_shm</transport_id>
          <transport_id>vigil_udp</transport_id>
        </userTransports>
        <useBuiltinTransports>false</useBuiltinTransports>
        <builtin>
          <metatrafficUnicastLocatorList>{locators}</metatrafficUnicastLocatorList>{multicast}
          <initialPeersList>{locators}{asked}</initialPeersList>
        </builtin>
        <defaultUnicastLocatorList>{locators}</defaultUnicastLocatorList>
      </rtps>
    </participant>
  </profiles>
</dds>
"""


def write_profile(
    folder: Path,
    addresses: list[str] | tuple[str, ...] = (),
    peers: list[str] | tuple[str, ...] = (),
) -> Path:
    """Write :func:`profile_xml` into ``folder``; returns its path."""
    path = Path(folder) / PROFILE_FILE
    write_text(path, profile_xml(addresses, peers))
    return path


def deployment_env(
    folder: Path,
    localhost_only: bool,
    interfaces: tuple[str, ...] = (),
    peers: tuple[str, ...] = (),
) -> dict[str, str]:
    """The environment of a deployment's processes (``ros:`` section): its profile
    written into ``folder`` (loopback only, or also ``interfaces`` with ``peers`` asked
    at discovery)."""
    addresses, asked = ((), ()) if localhost_only else (interfaces, peers)
    return dds_env(write_profile(folder, addresses, asked), localhost_only)


def dds_env(profile: Path, localhost_only: bool) -> dict[str, str]:
    """The environment every node gets for the profile."""
    return {
        "FASTRTPS_DEFAULT_PROFILES_FILE": str(profile),
        "FASTDDS_DEFAULT_PROFILES_FILE": str(profile),
        "RMW_IMPLEMENTATION": "rmw_fastrtps_cpp",
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET",  # see the module's note
    }

"""How ROS 2 puts a topic on DDS, as pure data and functions (no DDS library needed).

Each rule is ROS 2's own, cited to the source that implements it:

- Topic names. rmw_cyclonedds (ros2/rmw_cyclonedds, rmw_cyclonedds_cpp/src/rmw_node.cpp,
  make_fqtopic, with ROS_TOPIC_PREFIX "rt" from src/namespace_prefix.hpp) publishes the fully
  qualified ROS topic /scan on the DDS topic "rt/scan": the prefix "rt" followed by the name
  (ROS 2 design, articles/140_topic_and_service_name_mapping.md, "ROS Specific Namespace Prefix").
  A node without a namespace resolves a relative name "scan" to "/scan" (same article,
  "Fully Qualified Names").
- Type names. sensor_msgs/msg/LaserScan is the DDS type "sensor_msgs::msg::dds_::LaserScan_"
  (rmw_cyclonedds_cpp/src/MessageTypeSupport_impl.hpp: the namespace with "::", then "dds_::",
  the message name and "_"); Fast DDS's rmw builds the same name (ros2/rmw_fastrtps,
  _create_type_name: namespace "::", "dds_::", name, "_").
- Encoding. Plain CDR (XCDR1), little endian: a sample starts with the encapsulation header
  00 01 00 00 (rmw_cyclonedds_cpp/src/Serialization.cpp, put_rtps_header: version byte 1 for CDR1,
  then 1 for little endian, two option bytes 0), and rmw_cyclonedds allows only XCDR1
  (serdata.cpp, create_sertype: allowed_data_representation = DDS_DATA_REPRESENTATION_FLAG_XCDR1):
  a writer that offers XCDR2 only would not match its readers.
- QoS profiles: ros2/rmw, rmw/include/rmw/qos_profiles.h. rmw_qos_profile_sensor_data is
  keep-last 5, best effort, volatile; rmw_qos_profile_default keep-last 10, reliable, volatile.
  rmw_cyclonedds maps them onto DDS in rmw_node.cpp, create_readwrite_qos (reliable with an
  infinite max blocking time, best effort, autodispose off). A writer matches a reader when what
  it offers is at least what the reader requests (docs.ros.org, Concepts "Quality of Service
  settings", "QoS compatibilities"; OMG DDS 1.4, 2.2.3, RELIABILITY "requested/offered"): a
  reliable writer serves reliable and best-effort readers, a best-effort writer only best-effort
  ones; a volatile writer serves volatile readers (a transient-local reader does not match it).
  The drivers publish scans reliably (Slamtec/rplidar_ros ros2 branch, src/rplidar_node.cpp:
  QoS(KeepLast(10)); urg_node src/urg_node.cpp: depth 20), so "reliable" is the default.
- Type hash. Since Iron, rmw puts "typehash=RIHS01_<hex>;" in the endpoints' USER_DATA
  (rmw_cyclonedds create_readwrite_qos -> ros2/rmw_dds_common src/qos.cpp,
  encode_type_hash_for_user_data_qos) and reads it back from discovery into the graph
  (rmw_node.cpp handle_builtintopic_endpoint, parse_type_hash_from_user_data; a missing one is
  a zero hash, nothing is refused). It is what `ros2 topic info -v` shows; matching does not use
  it. RIHS01 is the SHA-256 of the type description (REP 2011; rosidl_generator_type_description)
  and is the same for these types in Iron, Jazzy and Kilted; TYPE_HASHES is checked against
  rosbags' implementation of it in the tests.
- Participant. rmw_cyclonedds lists a participant in its graph only if its USER_DATA holds
  "enclave=...;" (rmw_node.cpp, rmw_context_impl_s::init and handle_DCPSParticipant).
- Diagnostics. diagnostic_updater (ros/diagnostics, diagnostic_updater/include/
  diagnostic_updater/diagnostic_updater.hpp, Updater) publishes on "/diagnostics" with depth 1
  (reliable, the default), names each status "<node name>: <task name>" and fills hardware_id.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

LASERSCAN = "sensor_msgs/msg/LaserScan"
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"
DIAGNOSTICS_TOPIC = "/diagnostics"
NODE_NAME = "laserpi"

# REP 2011 RIHS01 hashes (tests/test_ros2.py recomputes them with rosbags, Stores.ROS2_JAZZY).
TYPE_HASHES = {
    LASERSCAN: "RIHS01_64c191398013af96509d518dac71d5164f9382553fce5c1f8cca5be7924bd828",
    DIAGNOSTIC_ARRAY: "RIHS01_5a8a36efb05fb25070fa0fb3810290c0e6cd4862b54a8fb975a1ee8dc55a333e",
}

ENCAPSULATION_CDR_LE = b"\x00\x01\x00\x00"
PARTICIPANT_USER_DATA = b"enclave=/;"

# diagnostic_msgs/msg/DiagnosticStatus level constants (OK, WARN, ERROR, STALE)
DIAGNOSTIC_LEVELS = {"OK": 0, "WARN": 1, "ERROR": 2, "STALE": 3}

# ROS 2 design, 140_topic_and_service_name_mapping.md: tokens of letters, digits and underscores, not
# starting with a digit, separated by single "/", no trailing "/" and no "__".
_TOPIC = re.compile(r"/?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*")


@dataclass(frozen=True)
class QosProfile:
    reliable: bool
    depth: int


QOS_PROFILES = {
    "reliable": QosProfile(reliable=True, depth=10),  # rmw_qos_profile_default
    "sensor": QosProfile(reliable=False, depth=5),  # rmw_qos_profile_sensor_data
}
DIAGNOSTICS_QOS = QosProfile(reliable=True, depth=1)  # diagnostic_updater's publisher


def dds_topic_name(ros_topic: str) -> str:
    """The DDS topic a ROS 2 node without namespace uses for ``ros_topic`` ("/scan" -> "rt/scan")."""
    if not _TOPIC.fullmatch(ros_topic) or "__" in ros_topic:
        raise ValueError(f"{ros_topic!r} is not a valid ROS 2 topic name (letters, digits, '_', "
                         "tokens separated by '/', not starting with a digit, no '__')")
    return "rt" + (ros_topic if ros_topic.startswith("/") else "/" + ros_topic)


def dds_type_name(ros_type: str) -> str:
    """"sensor_msgs/msg/LaserScan" -> "sensor_msgs::msg::dds_::LaserScan_"."""
    package, kind, name = ros_type.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def type_hash_user_data(ros_type: str) -> bytes:
    """The endpoint USER_DATA rmw (Iron and later) sends: b"typehash=RIHS01_...;"."""
    return f"typehash={TYPE_HASHES[ros_type]};".encode()


def ros_time(stamp_s: float, realtime_minus_monotonic_ns: int) -> tuple[int, int]:
    """(sec, nanosec) of builtin_interfaces/Time for a host time.monotonic() stamp.

    ROS time is the system clock, CLOCK_REALTIME (rclcpp::Clock RCL_ROS_TIME without a /clock
    source is RCL_SYSTEM_TIME, rcutils_system_time_now). The caller samples the difference of the
    two clocks when it publishes, so that a step of the system clock (NTP) is followed.
    """
    t_ns = round(stamp_s * 1e9) + realtime_minus_monotonic_ns
    return t_ns // 1_000_000_000, t_ns % 1_000_000_000

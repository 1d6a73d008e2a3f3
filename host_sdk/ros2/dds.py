"""The ROS 2 messages as DDS types and the one DDS participant that publishes them (Cyclone DDS).

Imports ``cyclonedds`` (the ``ros2`` extra): only ``laserpi ros2`` and its tests load this module.
The names, encoding and QoS follow host_sdk/ros2/conventions.py, which cites ROS 2's sources.

The structs are the DDS types of the ROS 2 messages (ROS 2 design, articles/
111_mapping_dds_types.md: float32 -> float, int32 -> long, uint32 -> unsigned long, byte -> octet,
string -> string, T[] -> sequence<T>), with the DDS type names rmw gives them; their fields are
in the .msg files' order, which fixes the CDR layout. Cyclone DDS serialises them as
XCDR1 when the writer's DataRepresentation policy allows only XCDR1.
"""

# no "from __future__ import annotations": cyclonedds reads the field annotations as types
from dataclasses import dataclass

import numpy as np
from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct, types
from cyclonedds.pub import DataWriter
from cyclonedds.topic import Topic

from host_sdk.ros2 import conventions as c
from host_sdk.scan import LaserScan


@dataclass
class Time(IdlStruct, typename=c.dds_type_name("builtin_interfaces/msg/Time")):
    sec: types.int32
    nanosec: types.uint32


@dataclass
class Header(IdlStruct, typename=c.dds_type_name("std_msgs/msg/Header")):
    stamp: Time
    frame_id: str


@dataclass
class LaserScanMsg(IdlStruct, typename=c.dds_type_name(c.LASERSCAN)):
    header: Header
    angle_min: types.float32
    angle_max: types.float32
    angle_increment: types.float32
    time_increment: types.float32
    scan_time: types.float32
    range_min: types.float32
    range_max: types.float32
    ranges: types.sequence[types.float32]
    intensities: types.sequence[types.float32]


@dataclass
class KeyValue(IdlStruct, typename=c.dds_type_name("diagnostic_msgs/msg/KeyValue")):
    key: str
    value: str


@dataclass
class DiagnosticStatus(IdlStruct, typename=c.dds_type_name("diagnostic_msgs/msg/DiagnosticStatus")):
    level: types.byte
    name: str
    message: str
    hardware_id: str
    values: types.sequence[KeyValue]


@dataclass
class DiagnosticArrayMsg(IdlStruct, typename=c.dds_type_name(c.DIAGNOSTIC_ARRAY)):
    header: Header
    status: types.sequence[DiagnosticStatus]


def writer_qos(profile: c.QosProfile, ros_type: str) -> Qos:
    """DDS writer QoS of an rmw_cyclonedds publisher with ``profile`` (conventions.py)."""
    reliability = (Policy.Reliability.Reliable(max_blocking_time=10**18) if profile.reliable
                   else Policy.Reliability.BestEffort)
    return Qos(reliability, Policy.History.KeepLast(profile.depth), Policy.Durability.Volatile,
               Policy.DataRepresentation(use_cdrv0_representation=True),
               Policy.WriterDataLifecycle(autodispose=False), Policy.Userdata(c.type_hash_user_data(ros_type)))


def laserscan_msg(ls: LaserScan, stamp: tuple) -> "LaserScanMsg":
    return LaserScanMsg(Header(Time(*stamp), ls.frame_id), ls.angle_min, ls.angle_max, ls.angle_increment,
                        ls.time_increment, ls.scan_time, ls.range_min, ls.range_max,
                        np.asarray(ls.ranges, np.float32).tolist(), np.asarray(ls.intensities, np.float32).tolist())


def diagnostic_array_msg(statuses, stamp: tuple[int, int], hardware_id: str) -> DiagnosticArrayMsg:
    """DiagnosticArray of (name, level, message, {key: value}) tuples, names prefixed with the
    node name as diagnostic_updater does; values become strings (KeyValue holds strings)."""
    return DiagnosticArrayMsg(Header(Time(*stamp), ""), [
        DiagnosticStatus(level, f"{c.NODE_NAME}: {name}", message, hardware_id,
                         [KeyValue(str(k), str(v)) for k, v in values.items()])
        for name, level, message, values in statuses])


class Ros2Publisher:
    """One DDS participant on ``domain_id`` with the scan and the diagnostics writer."""

    def __init__(self, domain_id: int, topic: str, qos: str):
        if qos not in c.QOS_PROFILES:
            raise ValueError(f"unknown QoS profile {qos!r}; known: {', '.join(c.QOS_PROFILES)}")
        if not 0 <= domain_id <= 232:  # docs.ros.org, Concepts "The ROS_DOMAIN_ID": 0..232 (RTPS ports)
            raise ValueError(f"ROS 2 domain id must be 0..232, got {domain_id}")
        scan_topic = c.dds_topic_name(topic)  # a bad name fails here, before anything goes on the network
        self.participant = DomainParticipant(domain_id, qos=Qos(Policy.Userdata(c.PARTICIPANT_USER_DATA)))
        self._scans = DataWriter(self.participant, Topic(self.participant, scan_topic, LaserScanMsg),
                                 writer_qos(c.QOS_PROFILES[qos], c.LASERSCAN))
        self._diagnostics = DataWriter(
            self.participant, Topic(self.participant, c.dds_topic_name(c.DIAGNOSTICS_TOPIC), DiagnosticArrayMsg),
            writer_qos(c.DIAGNOSTICS_QOS, c.DIAGNOSTIC_ARRAY))

    def publish_scan(self, ls: LaserScan, stamp: tuple[int, int]) -> None:
        self._scans.write(laserscan_msg(ls, stamp))

    def publish_diagnostics(self, statuses, stamp: tuple[int, int], hardware_id: str) -> None:
        self._diagnostics.write(diagnostic_array_msg(statuses, stamp, hardware_id))

    def subscriptions_matched(self) -> int:
        """Readers that match the scan and the diagnostics writer, together."""
        return sum(w.get_publication_matched_status().current_count for w in (self._scans, self._diagnostics))

    def close(self) -> None:
        """Delete the participant and its writers now (their readers see them leave)."""
        self.participant.__del__()  # cyclonedds deletes on __del__; this is idempotent

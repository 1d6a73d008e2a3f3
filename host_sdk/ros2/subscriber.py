"""A DDS subscriber that stands in for a ROS 2 node's subscription (tests and `laserpi bench ros2`).

    python -m host_sdk.ros2.subscriber --topic /scan --type sensor_msgs/msg/LaserScan \
        --reliability best-effort --depth 5 --out samples.bin --count 20

It subscribes as rmw_cyclonedds would (conventions.py): the DDS topic and type names of the ROS
topic and type, the QoS of the chosen profile, XCDR1 only. Its DDS type is not ours
(host_sdk/ros2/dds.py): it is built from the message definitions of rosbags' ROS 2 typestore, so
Cyclone DDS's type matching compares our type with ROS 2's definition. What it writes are the
samples' bytes as they came off the wire, each with the host's CLOCK_MONOTONIC time of
arrival: ``<q t_ns><I length><bytes>`` per sample, for rosbags' CDR decoder to read.
It prints "matched" on stdout when a writer has matched and exits after --count samples or
--seconds.

Needs cyclonedds (extra ``ros2``) and rosbags (extra ``ros``).
"""

from __future__ import annotations

import argparse
import struct
import sys
import time

from host_sdk.ros2 import conventions as c

SAMPLE_HEAD = struct.Struct("<qI")


def idl_struct(typestore, msgtype: str, _made: dict | None = None):
    """A cyclonedds IdlStruct class for ``msgtype`` from the typestore's field definitions, with
    rmw's DDS type name."""
    from cyclonedds.idl import make_idl_struct, types

    made = {} if _made is None else _made
    base = {"float32": types.float32, "float64": types.float64, "int32": types.int32, "uint32": types.uint32,
            "uint8": types.uint8, "byte": types.byte, "string": str}

    def field_type(node):
        kind, detail = node
        if kind.name == "BASE":
            return base[detail[0]]
        if kind.name == "NAME":
            return idl_struct(typestore, detail, made)
        if kind.name == "SEQUENCE":
            return types.sequence[field_type(detail[0])]
        raise ValueError(f"{msgtype}: field kind {kind.name} is not needed by LaserScan or DiagnosticArray")

    if msgtype not in made:
        _, fields = typestore.fielddefs[msgtype]
        made[msgtype] = make_idl_struct(msgtype.replace("/", "_"), c.dds_type_name(msgtype),
                                        {name: field_type(node) for name, node in fields})
    return made[msgtype]


def read_samples(path: str) -> list[tuple[int, bytes]]:
    """[(arrival CLOCK_MONOTONIC ns, serialized sample)] from a file this module wrote."""
    data, out, pos = open(path, "rb").read(), [], 0
    while pos < len(data):
        t_ns, n = SAMPLE_HEAD.unpack_from(data, pos)
        pos += SAMPLE_HEAD.size
        out.append((t_ns, data[pos: pos + n]))
        pos += n
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m host_sdk.ros2.subscriber")
    parser.add_argument("--domain-id", type=int, required=True)
    parser.add_argument("--topic", default="/scan")
    parser.add_argument("--type", default=c.LASERSCAN)
    parser.add_argument("--reliability", choices=("reliable", "best-effort"), required=True)
    parser.add_argument("--depth", type=int, default=10)
    parser.add_argument("--count", type=int, default=10)
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--out", required=True)
    args = parser.parse_args(argv)

    from cyclonedds._clayer import ddspy_take  # the public take() deserialises; we want the bytes
    from cyclonedds.core import InstanceState, Policy, Qos, ReadCondition, SampleState, ViewState, WaitSet
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic
    from rosbags.typesys import Stores, get_typestore

    msg_type = idl_struct(get_typestore(Stores.ROS2_JAZZY), args.type)
    participant = DomainParticipant(args.domain_id, qos=Qos(Policy.Userdata(c.PARTICIPANT_USER_DATA)))
    reliability = (Policy.Reliability.Reliable(max_blocking_time=10**8) if args.reliability == "reliable"
                   else Policy.Reliability.BestEffort)
    reader = DataReader(participant, Topic(participant, c.dds_topic_name(args.topic), msg_type),
                        Qos(reliability, Policy.History.KeepLast(args.depth), Policy.Durability.Volatile,
                            Policy.DataRepresentation(use_cdrv0_representation=True)))
    mask = SampleState.Any | ViewState.Any | InstanceState.Any
    waitset = WaitSet(participant)
    waitset.attach(ReadCondition(reader, mask))
    deadline = time.monotonic() + args.seconds
    matched, n = False, 0
    with open(args.out, "wb") as out:
        while n < args.count and time.monotonic() < deadline:
            if not matched and reader.get_subscription_matched_status().current_count > 0:
                matched = True
                print("matched", flush=True)
            waitset.wait(20_000_000)
            t_ns = time.monotonic_ns()
            for data, info in ddspy_take(reader._ref, mask, 64):
                if info.valid_data and n < args.count:
                    out.write(SAMPLE_HEAD.pack(t_ns, len(data)) + data)
                    n += 1
            out.flush()
    print(f"received {n}", flush=True)
    return 0 if n >= args.count else 1


if __name__ == "__main__":
    sys.exit(main())

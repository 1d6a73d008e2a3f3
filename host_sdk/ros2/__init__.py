"""ROS 2 over DDS without ROS: `laserpi ros2` (host_sdk/commands/ros2.py).

conventions.py: ROS 2's naming, encoding and QoS rules, cited (pure); dds.py: the message types
and the publisher on Cyclone DDS (imports cyclonedds, the ``ros2`` extra); node.py: scans and
diagnostics to samples; subscriber.py: a stand-in ROS 2 subscriber for tests and the bench.
"""

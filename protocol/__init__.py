"""The host link, shared by the device and the host: wire formats (COBS framing, CRC-32,
messages, the co-MCU's messages), the device's link server with the byte ports it runs on, and
the mock device (an analytic wall) that ``sim://`` and ``laserpi serve --mock`` serve.

Imports nothing else of laserpi: the host SDK uses all of it without the device's code.
See protocol/SPEC.md for byte layouts and compatibility rules.
"""

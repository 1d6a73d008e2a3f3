"""Wire formats shared by the device and the host: COBS framing, CRC-32, messages.

See protocol/SPEC.md for byte layouts and compatibility rules.
"""

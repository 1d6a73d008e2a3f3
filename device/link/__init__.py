"""The device end of the host link: the protocol's link server (protocol/server.py) serving the
sensor's scans over the host port, reopened when the host side fails (supervisor.py)."""

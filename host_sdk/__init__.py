"""The robot side of LaserPi: ``host_sdk.LaserPi('/dev/ttyUSB0').scans()``."""

"""Scan assembly: a lit and an unlit frame -> the pipeline's measurements on the scan's uniform
angles (pipeline.py) -> a scan with the host's settings applied, from the camera and the laser
together (source.py: SensorSource, the ScanSource the host link serves)."""

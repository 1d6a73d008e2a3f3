"""Calibration of the camera and the laser plane from the same checkerboard frames (thesis 4.2, 6.3)."""

"""Everything that runs on the Raspberry Pi: sensor model, simulator, camera backends,
synchronisation with the co-MCU, image pipeline, calibration and the device process.

Importing this package is cheap; heavy dependencies (OpenCV, picamera2) are imported lazily.
"""

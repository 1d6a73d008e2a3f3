"""Scene simulator with ground truth: renderer, scenes, sensor noise and timing (thesis ch. 6, app. A),
and the simulated hardware the device process runs on: the camera (camera.py), the Pi's clock and
the co-MCU's firmware in simavr (hardware.py, comcu_emulator.py)."""

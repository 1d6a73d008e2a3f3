"""Camera backends behind one interface: picamera2 on a Pi, the simulator, and replay."""

"""Camera backends behind one interface (base.py): picamera2 on a Pi and replay of recorded
frames; the simulated camera is device/sim/camera.py."""

"""The device process, wired together: the sensor built from its parts on a Pi or on simulated
hardware (assembly.py) for ``laserpi serve``, and ``laserpi serve`` run as a child process behind a
pty for the demo, the soak run and the process benchmark (child.py)."""

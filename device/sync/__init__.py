"""Laser-camera synchronisation: clock mapping, pulse placement and control (thesis ch. 5)."""

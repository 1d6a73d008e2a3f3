"""Benchmarks behind `laserpi bench` (see device/commands/bench.py)."""

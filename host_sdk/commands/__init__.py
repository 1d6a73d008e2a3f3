"""Command-line adapters of the host SDK (no OpenCV needed)."""

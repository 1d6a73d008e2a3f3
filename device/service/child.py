"""Start `laserpi serve` as a child process behind a pty and stop it again (demo and soak)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def start_serve(link: Path, serve_args: list[str], *, log_path: Path | None = None,
                timeout_s: float = 60.0) -> subprocess.Popen:
    """Run ``laserpi serve --link LINK *serve_args`` and wait until LINK points at a live pty.

    Its output (stdout and stderr: its messages and the device's log) goes to ``log_path`` if
    given, else to a temporary file. Raises RuntimeError ending in the last line of that output
    (serve's reason) if it does not come up within ``timeout_s``.
    """
    with open(log_path, "w+") if log_path else tempfile.TemporaryFile("w+") as out:
        proc = subprocess.Popen([sys.executable, "-m", "device.cli", "-v", "serve", "--link", str(link), *serve_args],
                                cwd=ROOT, stdout=out, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + timeout_s
        while not (link.is_symlink() and Path(os.readlink(link)).exists()):
            if proc.poll() is not None or time.monotonic() > deadline:
                stop_serve(proc)
                out.seek(0)
                reason = (out.read().splitlines() or ["no output"])[-1]
                raise RuntimeError(f"laserpi serve did not come up (exit {proc.returncode}): {reason}")
            time.sleep(0.05)
    return proc


def stop_serve(proc: subprocess.Popen, timeout_s: float = 10.0) -> int:
    """SIGTERM, wait for a clean exit (kill after ``timeout_s``); returns the exit code."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return proc.returncode


def rss_bytes(pid: int) -> int:
    """Resident set size of a process (Linux /proc), bytes."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    raise OSError(f"no VmRSS for pid {pid}")

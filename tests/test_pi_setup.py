"""tools/pi-setup.sh against a scratch root made from a real Raspberry Pi OS bookworm image's boot
files (tests/data/bookworm/SOURCE.md): what it edits, that a second run changes nothing, and
that --dry-run changes nothing."""

import os
import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "tools" / "pi-setup.sh"
BOOKWORM = REPO / "tests" / "data" / "bookworm"


def scratch_root(tmp_path: Path) -> Path:
    root = tmp_path / "root"
    (root / "boot" / "firmware").mkdir(parents=True)
    for name in ("config.txt", "cmdline.txt"):
        shutil.copy(BOOKWORM / name, root / "boot" / "firmware" / name)
    return root


def setup(root: Path, *args: str) -> str:
    done = subprocess.run(["bash", str(SCRIPT), "--root", str(root), *args], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    return done.stdout


def tree(root: Path) -> dict[str, str]:
    """Every file's content and every link's target under ``root``."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in filenames + [d for d in dirnames if os.path.islink(os.path.join(dirpath, d))]:
            p = Path(dirpath) / name
            rel = str(p.relative_to(root))
            out[rel] = f"-> {os.readlink(p)}" if p.is_symlink() else p.read_text()
    return out


def test_it_sets_up_the_boot_files_service_and_udev(tmp_path):
    root = scratch_root(tmp_path)
    setup(root)
    t = tree(root)
    cmdline = t["boot/firmware/cmdline.txt"]
    assert cmdline.count("\n") == 1 and cmdline.endswith("\n")  # still one line
    words = cmdline.split()
    assert not any(w.startswith("console=serial0") for w in words)
    assert "console=tty1" in words and "root=PARTUUID=4e639091-02" in words and "rootwait" in words
    assert "modules-load=dwc2,g_serial" in words
    config = t["boot/firmware/config.txt"]
    original = (BOOKWORM / "config.txt").read_text()
    assert config.startswith(original.rstrip("\n"))  # the image's settings stay as they were
    ours = config[config.index("# --- LaserPi"):].splitlines()
    assert ours[1] == "[all]" and {"enable_uart=1", "dtoverlay=disable-bt", "dtoverlay=dwc2"} <= set(ours)
    assert "camera_auto_detect=1" in config.splitlines()
    service = t["etc/systemd/system/laserpi.service"]
    for line in ("User=laserpi", "SupplementaryGroups=video dialout gpio", "Restart=on-failure", "StandardOutput=journal",
                 "ExecStart=/opt/laserpi/venv/bin/laserpi serve $LASERPI_ARGS", "WantedBy=multi-user.target",
                 "RuntimeDirectory=laserpi"):
        assert line in service.splitlines()
    assert t["etc/systemd/system/multi-user.target.wants/laserpi.service"] == "-> /etc/systemd/system/laserpi.service"
    assert "m laserpi gpio" in t["etc/sysusers.d/laserpi.conf"]
    assert "--gpio-edge gpiochip0:17" in t["etc/default/laserpi"]
    for unit in ("serial-getty@ttyAMA0.service", "serial-getty@ttyS0.service", "hciuart.service"):
        assert t[f"etc/systemd/system/{unit}"] == "-> /dev/null"
    rules = t["etc/udev/rules.d/99-laserpi.rules"]
    assert 'KERNEL=="ttyGS0"' in rules and 'KERNEL=="gpiochip*", GROUP="gpio"' in rules and 'GROUP="dialout"' in rules


def test_a_second_run_changes_nothing(tmp_path):
    root = scratch_root(tmp_path)
    setup(root)
    first = tree(root)
    assert setup(root).strip() == "pi-setup: nothing to change"
    assert tree(root) == first


def test_dry_run_changes_nothing_and_says_what_it_would(tmp_path):
    root = scratch_root(tmp_path)
    before = tree(root)
    out = setup(root, "--dry-run")
    assert tree(root) == before
    assert "would write /boot/firmware/cmdline.txt" in out and "-console=serial0,115200 console=tty1" in out
    assert "would link /etc/systemd/system/hciuart.service -> /dev/null" in out


def test_edits_of_its_own_kind_are_merged_not_duplicated(tmp_path):
    root = scratch_root(tmp_path)
    boot = root / "boot" / "firmware"
    (boot / "cmdline.txt").write_text("console=ttyAMA0,115200 console=tty1 root=/dev/mmcblk0p2 modules-load=i2c-dev,dwc2\n")
    (boot / "config.txt").write_text((BOOKWORM / "config.txt").read_text().replace("camera_auto_detect=1", "camera_auto_detect=0"))
    (root / "etc" / "default").mkdir(parents=True)
    (root / "etc" / "default" / "laserpi").write_text('LASERPI_ARGS="--port /dev/ttyAMA1"\n')
    setup(root)
    assert (boot / "cmdline.txt").read_text() == "console=tty1 root=/dev/mmcblk0p2 modules-load=i2c-dev,dwc2,g_serial\n"
    config = (boot / "config.txt").read_text().splitlines()
    assert "camera_auto_detect=0" not in config and config.count("camera_auto_detect=1") == 1
    assert (root / "etc" / "default" / "laserpi").read_text() == 'LASERPI_ARGS="--port /dev/ttyAMA1"\n'  # the user's


def test_a_root_without_boot_files_is_refused(tmp_path):
    done = subprocess.run(["bash", str(SCRIPT), "--root", str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 1 and f"no {tmp_path}/boot/firmware/config.txt" in done.stderr
    bad = subprocess.run(["bash", str(SCRIPT), "--frobnicate"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "unknown argument" in bad.stderr

#!/usr/bin/env bash
# Sets up Raspberry Pi OS bookworm for LaserPi (README "On the Pi"). Idempotent: a second run
# changes nothing. Reboot afterwards for the boot-file changes to apply.
#
#   sudo tools/pi-setup.sh                       # this Pi
#   tools/pi-setup.sh --root /mnt/sdcard         # an SD card's root file system (its boot
#                                                # partition mounted at DIR/boot/firmware)
#   tools/pi-setup.sh --dry-run                  # say what would change, change nothing
#
# What it does, each with the Raspberry Pi documentation (raspberrypi/documentation,
# documentation/asciidoc/computers/) or source it follows:
# * boot/firmware/config.txt, a block of its own at the end under [all]:
#   - enable_uart=1: the primary UART on GPIO 14/15 for the co-MCU (configuration/uart.adoc,
#     "Mini-UART and CPU Core Frequency": on a Zero 2 W / Pi 3 / Pi 4 the mini UART is primary
#     and enable_uart=1 enables it with a fixed core clock);
#   - dtoverlay=disable-bt: the first PL011 (UART0) becomes the primary UART instead of the
#     mini UART, whose baud rate follows the VPU clock and which has no framing-error
#     detection (uart.adoc, "UARTs and Device Tree", "PL011 and mini-UART"); hciuart, which
#     would otherwise open that UART for Bluetooth, is masked, as uart.adoc says to disable it;
#   - dtoverlay=dwc2: the USB controller in device (OTG) mode, for the host link as a USB serial
#     gadget on a Zero 2 W, whose only header UART goes to the co-MCU (overlay "dwc2",
#     raspberrypi/linux arch/arm/boot/dts/overlays/README: dr_mode default "otg");
#   - camera_auto_detect=1 (already the image's default): the IMX219's overlay is loaded when the
#     camera is found (configuration/config_txt: camera_auto_detect);
# * boot/firmware/cmdline.txt, kept one line ("Put all parameters in cmdline.txt on the same
#   line. Do not use newlines.", configuration/kernel-command-line-config.adoc):
#   - the serial console removed (console=serial0,115200 and its ttyAMA0/ttyS0 spellings): the
#     UART is the co-MCU's (uart.adoc, "Disabling the Linux Serial Console"); the serial gettys
#     are masked too;
#   - modules-load=dwc2,g_serial: the gadget serial driver, whose port is /dev/ttyGS0, CDC ACM
#     by default (linux drivers/usb/gadget/legacy/serial.c: use_acm, "default=yes");
# * etc/systemd/system/laserpi.service (enabled): `laserpi serve` as the system user laserpi in
#   the video, dialout and gpio groups (etc/sysusers.d/laserpi.conf, made by systemd-sysusers),
#   restarted on failure, logging to journald; its arguments in etc/default/laserpi (installed
#   once, then yours to edit);
# * etc/udev/rules.d/99-laserpi.rules: the co-MCU's UART, the host link's gadget port and the
#   GPIO chips for the groups above.
set -euo pipefail

ROOT=/
DRY=0
LASERPI=/opt/laserpi/venv/bin/laserpi
usage() { echo "usage: $0 [--root DIR] [--dry-run] [--laserpi PATH]   (PATH: the laserpi command, default $LASERPI)"; }
while [ $# -gt 0 ]; do
  case "$1" in
    --root) ROOT=${2:?--root needs a directory}; shift 2 ;;
    --dry-run) DRY=1; shift ;;
    --laserpi) LASERPI=${2:?--laserpi needs a path}; shift 2 ;;
    -h|--help) usage; exit 0 ;;
    *) usage >&2; echo "pi-setup: unknown argument: $1" >&2; exit 2 ;;
  esac
done
ROOT=${ROOT%/}
BOOT=$ROOT/boot/firmware
for f in config.txt cmdline.txt; do
  [ -f "$BOOT/$f" ] || { echo "pi-setup: no $BOOT/$f (is this Raspberry Pi OS bookworm? --root DIR for an SD card)" >&2; exit 1; }
done
TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT
CHANGED=0

# put FILE NEW: make FILE's content NEW's (a file in $TMP), or say that it would.
put() {
  local file=$1 new=$2
  if [ -f "$file" ] && cmp -s "$file" "$new"; then return 0; fi
  CHANGED=1
  if [ $DRY -eq 1 ]; then
    echo "would write ${file#"$ROOT"}:"
    if [ -f "$file" ]; then
      diff -u "$file" "$new" | sed '1,2d; s/^/    /' || true
    else
      sed 's/^/    +/' "$new"
    fi
    return 0
  fi
  mkdir -p "$(dirname "$file")"
  cp "$new" "$file.laserpi-new" && chmod 644 "$file.laserpi-new" && mv "$file.laserpi-new" "$file"
  echo "wrote ${file#"$ROOT"}"
}

# link LINK TARGET: a symbolic link (systemd's enable and mask are links).
link() {
  local l=$1 target=$2
  if [ -L "$l" ] && [ "$(readlink "$l")" = "$target" ]; then return 0; fi
  CHANGED=1
  if [ $DRY -eq 1 ]; then echo "would link ${l#"$ROOT"} -> $target"; return 0; fi
  mkdir -p "$(dirname "$l")"
  ln -sfn "$target" "$l"
  echo "linked ${l#"$ROOT"} -> $target"
}

# --- config.txt: everything between the markers is ours, rewritten whole -------------------
BEGIN="# --- LaserPi (tools/pi-setup.sh): edits here are replaced on the next run ---"
END="# --- end LaserPi ---"
awk -v b="$BEGIN" -v e="$END" '$0 == b {skip = 1} !skip {print} $0 == e {skip = 0}' "$BOOT/config.txt" \
  | sed 's/^camera_auto_detect=.*/camera_auto_detect=1/' > "$TMP/config.txt"
# drop the blank lines our block left at the end, then append it
sed -i -e :a -e '/^\n*$/{$d;N;ba' -e '}' "$TMP/config.txt"
{
  echo
  echo "$BEGIN"
  echo "[all]"
  echo "enable_uart=1"
  echo "dtoverlay=disable-bt"
  echo "dtoverlay=dwc2"
  grep -q '^camera_auto_detect=' "$TMP/config.txt" || echo "camera_auto_detect=1"
  echo "$END"
} >> "$TMP/config.txt"
put "$BOOT/config.txt" "$TMP/config.txt"

# --- cmdline.txt: one line; no serial console; the gadget modules loaded --------------------
line=$(tr '\n' ' ' < "$BOOT/cmdline.txt")
out=()
modules=""
for word in $line; do
  case "$word" in
    console=serial0*|console=serial1*|console=ttyAMA*|console=ttyS*) ;;
    modules-load=*) modules=${word#modules-load=} ;;
    *) out+=("$word") ;;
  esac
done
for m in dwc2 g_serial; do
  case ",$modules," in *",$m,"*) ;; *) modules=${modules:+$modules,}$m ;; esac
done
out+=("modules-load=$modules")
printf '%s\n' "${out[*]}" > "$TMP/cmdline.txt"
put "$BOOT/cmdline.txt" "$TMP/cmdline.txt"

# --- the service, its user and its settings ------------------------------------------------
cat > "$TMP/laserpi.conf" <<'EOF'
# the LaserPi device process's user (tools/pi-setup.sh); systemd-sysusers creates it
u laserpi - "LaserPi sensor" /var/lib/laserpi
m laserpi video
m laserpi dialout
m laserpi gpio
EOF
put "$ROOT/etc/sysusers.d/laserpi.conf" "$TMP/laserpi.conf"

cat > "$TMP/laserpi.service" <<EOF
[Unit]
Description=LaserPi line-laser distance sensor (laserpi serve)
Documentation=file:///opt/laserpi/README.md
After=systemd-udev-settle.service

[Service]
User=laserpi
Group=laserpi
SupplementaryGroups=video dialout gpio
EnvironmentFile=/etc/default/laserpi
RuntimeDirectory=laserpi
ExecStart=$LASERPI serve \$LASERPI_ARGS
Restart=on-failure
RestartSec=2
StandardOutput=journal
StandardError=journal

[Install]
WantedBy=multi-user.target
EOF
put "$ROOT/etc/systemd/system/laserpi.service" "$TMP/laserpi.service"
link "$ROOT/etc/systemd/system/multi-user.target.wants/laserpi.service" /etc/systemd/system/laserpi.service

if [ ! -f "$ROOT/etc/default/laserpi" ]; then  # yours once installed: never overwritten
  cat > "$TMP/default" <<'EOF'
# Arguments of `laserpi serve` for laserpi.service (tools/pi-setup.sh installed this once; edit it).
# --port: the host link (USB gadget serial); --comcu: the co-MCU's UART; --gpio-edge: the laser
# trigger's GPIO line (BCM number) for edge-timestamp sync; --config: your calibrated sensor.
LASERPI_ARGS="--port /dev/ttyGS0 --comcu /dev/serial0 --gpio-edge gpiochip0:17 --preset thesis-calibrated"
EOF
  put "$ROOT/etc/default/laserpi" "$TMP/default"
fi

# --- serial gettys and hciuart off (masked: a link to /dev/null) ----------------------------
for unit in serial-getty@ttyAMA0.service serial-getty@ttyS0.service serial-getty@serial0.service hciuart.service; do
  link "$ROOT/etc/systemd/system/$unit" /dev/null
done

# --- udev: the devices for the groups the service runs in -----------------------------------
cat > "$TMP/99-laserpi.rules" <<'EOF'
# LaserPi (tools/pi-setup.sh): the co-MCU's UART, the host link's USB gadget port and the GPIO
# chips (laser trigger line) for the laserpi user's groups.
KERNEL=="ttyAMA0|ttyS0", GROUP="dialout", MODE="0660"
KERNEL=="ttyGS0", GROUP="dialout", MODE="0660", SYMLINK+="laserpi-host"
SUBSYSTEM=="gpio", KERNEL=="gpiochip*", GROUP="gpio", MODE="0660"
EOF
put "$ROOT/etc/udev/rules.d/99-laserpi.rules" "$TMP/99-laserpi.rules"

# --- on this Pi itself: let systemd and udev see it now ------------------------------------
if [ -z "$ROOT" ] && [ $DRY -eq 0 ] && [ $CHANGED -eq 1 ]; then
  command -v systemd-sysusers >/dev/null && systemd-sysusers
  command -v systemctl >/dev/null && systemctl daemon-reload
  command -v udevadm >/dev/null && udevadm control --reload
fi
if [ $CHANGED -eq 0 ]; then
  echo "pi-setup: nothing to change"
elif [ $DRY -eq 1 ]; then
  echo "pi-setup: dry run, nothing changed"
else
  echo "pi-setup: done; reboot for config.txt and cmdline.txt to apply"
fi

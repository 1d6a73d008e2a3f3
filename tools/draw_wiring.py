"""The co-MCU wiring drawing of firmware_pwm/README.md ("Wiring"), as a PNG.

    .venv/bin/python tools/draw_wiring.py docs/wiring.png

Top: the recommended board, an ATmega328P at 3.3 V with an 8 MHz crystal (`make F_CPU=8000000`),
powered from the Pi and wired straight to it.  Bottom: the 16 MHz board at 5 V, with a buffer on
every line between the two (README.md "Board variants").  The laser driver is enabled by the
pulse pin D9 (PB1/OC1A) with a 10 kOhm pull-down; the same net goes to the Pi's GPIO17 (pin 11),
the laser trigger line the sync timestamps (device/sync/gpio_edges.py).
"""

from __future__ import annotations

import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import FancyBboxPatch, Polygon, Rectangle  # noqa: E402

#: wire colours by net
POWER_3V3, POWER_5V, GROUND = "#d62728", "#8c1b13", "#222222"
TO_MCU, TO_PI, LASER = "#1f77b4", "#2ca02c", "#ff7f0e"
PIN_GAP = 0.55  # vertical distance between two pins of a box


def box(ax, x: float, y_top: float, w: float, title: str, left=(), right=(), note: str = "",
        color: str = "#f2f2f2") -> dict[str, tuple[float, float]]:
    """A part with pins on its left and right edges (top to bottom, "" leaves a row empty);
    returns each pin's end point."""
    rows = max(len(left), len(right), 1)
    h = 0.9 + rows * PIN_GAP + (0.25 + 0.32 * note.count("\n") + 0.32 if note else 0.0)
    ax.add_patch(FancyBboxPatch((x, y_top - h), w, h, boxstyle="round,pad=0.02,rounding_size=0.12",
                                fc=color, ec="#444444", lw=1.4))
    ax.text(x + w / 2, y_top - 0.32, title, ha="center", va="center", fontsize=11.5, weight="bold")
    pins = {}
    for side, names in (("L", left), ("R", right)):
        for k, name in enumerate(names):
            if not name:
                continue
            py = y_top - 0.95 - k * PIN_GAP
            px = x if side == "L" else x + w
            ax.plot([px], [py], "o", ms=4.5, color="#444444", zorder=5)
            ax.text(px + (0.12 if side == "L" else -0.12), py, name, ha="left" if side == "L" else "right",
                    va="center", fontsize=10)
            pins[name] = (px, py)
    if note:
        ax.text(x + w / 2, y_top - h + 0.18, note, ha="center", va="bottom", fontsize=9, color="#333333",
                linespacing=1.35)
    return pins


def wire(ax, points, color: str, label: str = "", label_at: int = 0, dashed: bool = False) -> None:
    """A wire through ``points``; ``label`` above its segment number ``label_at``."""
    xs, ys = zip(*points)
    ax.plot(xs, ys, color=color, lw=2.2, ls="--" if dashed else "-", solid_capstyle="round", zorder=3)
    if label:
        (x0, y0), (x1, y1) = points[label_at], points[label_at + 1]
        ax.text((x0 + x1) / 2, (y0 + y1) / 2 + 0.1, label, ha="center", va="bottom", fontsize=9, color=color,
                weight="bold")


def dot(ax, x: float, y: float, color: str) -> None:
    """A junction."""
    ax.plot([x], [y], "o", ms=7, color=color, zorder=6)


def ground(ax, x: float, y: float) -> None:
    """A ground symbol hanging from (x, y)."""
    ax.plot([x, x], [y, y - 0.25], color=GROUND, lw=2.2, zorder=3)
    for k, half in enumerate((0.22, 0.14, 0.06)):
        ax.plot([x - half, x + half], [y - 0.25 - 0.09 * k] * 2, color=GROUND, lw=1.8)


def resistor(ax, x: float, y_top: float, y_bottom: float, label: str) -> None:
    """A vertical resistor between two heights, its value to the right."""
    mid = (y_top + y_bottom) / 2
    ax.plot([x, x], [y_top, y_bottom], color="#444444", lw=2.0, zorder=3)
    ax.add_patch(Rectangle((x - 0.13, mid - 0.35), 0.26, 0.7, fc="white", ec="#444444", lw=1.4, zorder=4))
    ax.text(x + 0.25, mid, label, ha="left", va="center", fontsize=9.5)


def buffer(ax, x: float, y: float, direction: int, tag: str) -> None:
    """A buffer (triangle) on a wire at (x, y) pointing left (-1) or right (+1), tagged to its right."""
    tip, back = x + 0.3 * direction, x - 0.3 * direction
    ax.add_patch(Polygon([(back, y + 0.22), (back, y - 0.22), (tip, y)], closed=True, fc="white", ec="#222222",
                         lw=1.6, zorder=4))
    ax.text(x + 0.45, y + 0.08, tag, ha="left", va="bottom", fontsize=10, weight="bold")


def pi_and_mcu(ax, title: str, lanes, pi_note: str, mcu_x: float, mcu_title: str, mcu_note: str):
    """A panel: its title, the Pi's header on the left and the MCU at ``mcu_x``, with a straight
    wire for each lane (Pi pin, MCU pin, colour, ...) in order; returns both boxes' pins."""
    ax.set_title(title, fontsize=13, weight="bold", loc="left")
    pi = box(ax, 0.3, 7.6, 3.7, "Raspberry Pi header", right=[lane[0] for lane in lanes], note=pi_note)
    mcu = box(ax, mcu_x, 7.6, 4.3, mcu_title, left=[lane[1] for lane in lanes], note=mcu_note)
    for lane in lanes:
        wire(ax, [pi[lane[0]], mcu[lane[1]]], lane[2])
    return pi, mcu


def panel_3v3(ax) -> None:
    lanes = (("1  3V3", "VCC, AVCC (7, 20)", POWER_3V3, "3.3 V, a few mA"),
             ("6  GND", "GND (8, 22)", GROUND, "GND"),
             ("8  GPIO14 TXD", "PD0 RXD  D0 (2)", TO_MCU, "Pi TX -> MCU RX"),
             ("10  GPIO15 RXD", "PD1 TXD  D1 (3)", TO_PI, "MCU TX -> Pi RX"),
             ("11  GPIO17", "PB1 OC1A  D9 (15)", LASER, "laser trigger (edges) -> Pi"))
    pi, mcu = pi_and_mcu(ax, "Recommended: ATmega328P at 3.3 V, 8 MHz crystal (make F_CPU=8000000), wired straight "
                             "to the Pi", lanes, "/dev/serial0 = PL011:\nenable_uart=1, dtoverlay=disable-bt",
                         8.6, "ATmega328P  3.3 V / 8 MHz", "8 MHz crystal on XTAL1/2 (9, 10), 2 x 22 pF\n100 nF at "
                         "each VCC pin\nISP header: MOSI D11, MISO D12,\nSCK D13, RESET (1), VCC, GND")
    for a, _, color, label in lanes:
        ax.text(6.25, pi[a][1] + 0.1, label, ha="center", va="bottom", fontsize=9, color=color, weight="bold")
    drv = box(ax, 15.9, 7.6, 3.8, "Laser driver",
              left=["V+", "EN (TTL) / MOSFET gate", "GND"],
              note="constant-current driver with a TTL\nenable, or a logic-level MOSFET\n"
                   "(RDS(on) given at VGS = 2.5 V)\nswitching a laser module")
    # the D9 net, under the MCU, to the driver's enable, with its pull-down
    d9, en = mcu["PB1 OC1A  D9 (15)"], drv["EN (TTL) / MOSFET gate"]
    jx, low = 7.6, 1.6
    dot(ax, jx, d9[1], LASER)
    wire(ax, [(jx, d9[1]), (jx, low), (14.9, low), (14.9, en[1]), en], LASER, "pulse: OC1A -> laser enable", 1)
    dot(ax, 13.6, low, LASER)
    resistor(ax, 13.6, low, 0.55, "10 kOhm pull-down: laser off\nin reset, bootloader and ISP")
    ground(ax, 13.6, 0.55)
    gnd = drv["GND"]
    wire(ax, [gnd, (15.4, gnd[1]), (15.4, 4.3)], GROUND, "", 0)
    ground(ax, 15.4, 4.3)
    ax.text(15.25, 4.0, "common\nground", ha="right", va="top", fontsize=9, color=GROUND)
    vp = drv["V+"]
    wire(ax, [vp, (13.3, vp[1])], POWER_5V, "5 V: Pi pin 2/4 or own supply", 0, dashed=True)
    ax.text(13.25, vp[1] - 0.05, "(never the 3V3 pin)", ha="left", va="top", fontsize=8.5, color=POWER_5V)


def panel_5v(ax) -> None:
    lanes = (("10  GPIO15 RXD", "PD1 TXD  D1 (3)", TO_PI, "MCU TX (5 V) -> Pi RX (3.3 V)", -1, "A1"),
             ("11  GPIO17", "PB1 OC1A  D9 (15)", LASER, "laser trigger (5 V) -> Pi (3.3 V)", -1, "A2"),
             ("8  GPIO14 TXD", "PD0 RXD  D0 (2)", TO_MCU, "Pi TX (3.3 V) -> MCU RX (5 V)", +1, "B"),
             ("2  5V", "VCC, AVCC (7, 20)", POWER_5V, "5 V (or the board's own supply)", 0, ""),
             ("6  GND", "GND (8, 22)", GROUND, "common ground", 0, ""))
    pi, _ = pi_and_mcu(ax, "Alternative: ATmega328P at 5 V, 16 MHz (make F_CPU=16000000): a buffer on every signal "
                           "line", lanes, "3.3 V only: every MCU -> Pi line\nthrough a 3.3 V buffer",
                       12.6, "ATmega328P  5 V / 16 MHz", "16 MHz crystal, brown-out 4.3 V\nD9 also drives the laser "
                       "driver's\nEN with the 10 kOhm pull-down")
    for a, _, color, label, direction, tag in lanes:
        ax.text(6.6, pi[a][1] + 0.08, label, ha="center", va="bottom", fontsize=9, color=color, weight="bold")
        if direction:
            buffer(ax, 10.0, pi[a][1], direction, tag)
    ax.text(4.6, 3.0, "A1, A2: 74LVC2G125 (dual buffer) at VCC = 3.3 V from Pi pin 1, OE1/OE2 to GND: its inputs\n"
                      "tolerate 5 V (no clamp to VCC), its outputs swing 3.3 V, and a powered MCU cannot feed\n"
                      "the Pi through it while the Pi is off.\n"
                      "B: 74AHCT1G125 at VCC = 5 V, OE to GND: TTL input (high from 2.0 V), 5 V output. The AVR\n"
                      "at 5 V reads high from 0.6 VCC = 3.0 V; the Pi's 3.3 V is only 0.3 V above it, so shift it too.",
            ha="left", va="top", fontsize=9.5, color="#222222", linespacing=1.4)


def draw(path: str) -> None:
    fig, axes = plt.subplots(2, 1, figsize=(20, 16.5), dpi=100)
    for ax, panel in zip(axes, (panel_3v3, panel_5v)):
        ax.set_xlim(0, 20)
        ax.set_ylim(0, 8)
        ax.set_aspect("equal")
        ax.axis("off")
        panel(ax)
    fig.tight_layout(h_pad=2.0)
    fig.savefig(path, facecolor="white")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit(__doc__.splitlines()[2].strip())
    draw(sys.argv[1])

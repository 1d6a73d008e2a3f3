"""MCU time -> Pi CLOCK_MONOTONIC: robust linear maps (offset and drift) with their uncertainty.

Thesis 7.2.3 names the two faults of the thesis's synchronisation: the start of the PWM was only
known to within the ~185 us interval of Algorithm 1, and there was no drift correction ("an open
loop"). Here the MCU's timer is mapped onto the Pi's clock continuously, from two sources:

(a) **GPIO edges** (primary). The laser trigger is wired to a Pi GPIO; the kernel timestamps each
    edge on CLOCK_MONOTONIC in its interrupt handler (libgpiod edge events), and the MCU reports
    the tick of the same edge. An interrupt timestamp is never early: its error is a fixed latency
    plus a one-sided, heavy-tailed excess. So the map is the *lower envelope* of the pairs, not a
    least-squares line through them (which the tail would bias and outliers would drag):
    a Theil-Sen slope on block medians, then per block the pair with the smallest residual, then a
    least-squares line through those block minima (the minimum of m exponential excesses of mean
    J has mean and spread J/m, so the estimate tightens like 1/m, not 1/sqrt(m)). The expected
    excess of the minima is subtracted, with J estimated from the median residual (J ln 2 for an
    exponential). Late outliers (an interrupt held off) never reach the envelope; pairs that lie
    far *below* the bulk are physically impossible (a spurious edge paired by mistake) and are
    removed first (``impossibly_early``: median-based line and MAD).
    The fixed part of the latency cannot be seen from the data: it is a calibration constant
    (``gpio_latency_min_s``, measured once with a scope or a loop-back), subtracted here.
    The fit is windowed (last ``window`` pairs) so that it follows drift that changes with
    temperature.

(b) **PING round trips** over serial (fallback when the wire is absent). Bounded delays with a
    minimum-delay filter (NTP/TICSync style): the MCU stamped its tick between the Pi's send time
    plus the PING's minimum time on the line and the receive time minus the PONG's (the two
    frames differ in length, so the plain midpoint would be biased by half the difference); per
    block of the window the exchange with the narrowest bounds is kept, placed in the middle of
    them, and a line is fitted through those. The reported sigma takes the position as uniform
    within the bounds. Expect tens to hundreds of microseconds instead of a few: lower accuracy,
    hence a wider guard and a longer pulse.

Public units: MCU time in ticks (int), Pi time in nanoseconds (int), uncertainties in seconds.
"""

from __future__ import annotations

import bisect
import functools
import logging
import math
from dataclasses import dataclass

import numpy as np

log = logging.getLogger(__name__)

LN2 = math.log(2.0)
#: The windowed line fits (GpioClockMap, control.CameraTimeline) refit at every new point while
#: they hold fewer than REFIT_FROM, then once the points since the last fit are REFIT_SHARE of the
#: window (at least REFIT_EVERY): a line through n points moves by about that share of its spread
#: when they are replaced, and its sigma grows with the extrapolation meanwhile, so nothing is
#: claimed that was not fitted. A full window of 256 (SyncConfig's) refits every 32nd point, 0.8 s
#: at 40 frames a second; each fit is ~25 numpy calls (~80 us here with warm caches), the largest
#: part of the controller's step per frame (BENCHMARKS.md "Device process").
REFIT_EVERY, REFIT_FROM, REFIT_SHARE = 8, 64, 1 / 8


def refit_due(points: int, since_fit: int) -> bool:
    """Whether a window of ``points`` that got ``since_fit`` points since its last fit refits now."""
    return points < REFIT_FROM or since_fit >= max(REFIT_EVERY, points * REFIT_SHARE)


@dataclass(frozen=True)
class LineFit:
    """``y = a + b x`` fitted through ``n_points`` block minima; ``x`` and ``y`` relative to a reference."""

    a: float
    b: float
    x_mean: float
    sxx: float
    n_points: int
    point_sigma: float  # spread of one block minimum about the line

    def predict(self, x: np.ndarray | float) -> np.ndarray | float:
        return self.a + self.b * x

    def sigma(self, x: np.ndarray | float) -> np.ndarray | float:
        """1-sigma uncertainty of ``predict(x)`` (the line's own uncertainty, extrapolation included).
        ``** 0.5``, not np.sqrt: a float stays a Python float (the controller's per-frame arithmetic)."""
        lever = (x - self.x_mean) ** 2 / self.sxx if self.sxx > 0 else 0.0
        return self.point_sigma * (1.0 / self.n_points + lever) ** 0.5


@functools.lru_cache(maxsize=64)
def _pairs(n: int) -> tuple[np.ndarray, np.ndarray]:
    return np.triu_indices(n, 1)


def _median(a: np.ndarray) -> float:
    return float(np.partition(a, a.size // 2)[a.size // 2])


def _median_slope(xs: np.ndarray, ys: np.ndarray) -> float:
    """Theil-Sen slope through the medians of the rows of (blocks, m) arrays (x increasing)."""
    nb, m = xs.shape
    xm = xs[:, m // 2]
    ymed = np.partition(ys, m // 2, axis=1)[:, m // 2]
    i, j = _pairs(nb)
    dx = xm[j] - xm[i]
    ok = dx > 0
    return _median((ymed[j] - ymed[i])[ok] / dx[ok]) if ok.any() else 1.0


def impossibly_early(x: np.ndarray, y: np.ndarray, floor_s: float = 20e-6, k: float = 8.0) -> np.ndarray:
    """Mask of points far below the bulk: a latency cannot be negative, so they were mispaired.

    Reference: Theil-Sen line through block medians, offset by the median residual; a point is
    rejected if it lies more than ``max(k * MAD, floor_s)`` below it. (The lowest genuine points
    sit about 1.4 MAD below the median of an exponential latency.)
    """
    n = x.size
    nb = min(16, n // 4)
    if nb < 3:
        return np.zeros(n, bool)
    m = n // nb
    slope = _median_slope(x[n - nb * m:].reshape(nb, m), y[n - nb * m:].reshape(nb, m))
    r = y - slope * x
    r -= _median(r)
    mad = _median(np.abs(r))
    return r < -max(k * mad, floor_s)


def lower_envelope_fit(x: np.ndarray, y: np.ndarray, blocks: int = 16, prior_sigma: float = 0.0) -> LineFit:
    """Line under points whose error is a one-sided latency (see module docstring, method (a)).

    x, y: 1-D arrays of equal length >= 2, x increasing. ``prior_sigma`` is the spread assumed for a
    single point when there are too few points to measure it. Returns the lower-envelope line with
    the expected excess of the block minima removed.
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    if x.ndim != 1 or x.shape != y.shape:
        raise ValueError(f"x and y must be 1-D of one length, got {x.shape} and {y.shape}")
    n = x.size
    if n < 2:
        raise ValueError(f"need at least 2 points, got {n}")
    if n < 2 * 3:  # too few for blocks: every point is its own block
        nb, m = n, 1
    else:
        nb = min(blocks, n // 3)
        m = n // nb
    xs = x[n - nb * m:].reshape(nb, m)
    ys = y[n - nb * m:].reshape(nb, m)
    slope0 = _median_slope(xs, ys)
    r = ys - slope0 * xs
    k = np.argmin(r, axis=1)
    rows = np.arange(nb)
    bx, by = xs[rows, k], ys[rows, k]
    xbar = float(bx.sum()) / nb
    sxx = float(((bx - xbar) ** 2).sum())
    # The minima's slope has the spread J/m / sqrt(sxx); the block medians' slope that of one
    # point, J / sqrt(sxx of their x) (within a block y follows x, so its median is its middle
    # point, not a median of m). The minima's is the surer unless they cluster in x (few blocks:
    # with three pulses' rise and fall pairs in two blocks of three, the two minima can be one
    # pulse's rise and the next block's fall, 8.6 ms apart, the slope then off by thousands of
    # ppm). Then the medians' slope is kept, and the line's lever below is theirs. By those spreads
    # the break-even is sxx = sxx_middles / m^2; the minima of so few points stray further than
    # the model says, so the middles take over from sxx_middles / m (3-4 pulses, 200 us jitter,
    # 50 us prior, 3000 draws: |error| < 3 sigma 0.96 / 0.87 of the time, against 0.88 / 0.86 at
    # m^2 and 0.93 / 0.86 with the middles' lever taken as theirs over m).
    xm = xs[:, m // 2]
    sxx_middles = float(((xm - xm.mean()) ** 2).sum())
    by_middles = not (sxx > 0 and sxx * m >= sxx_middles)
    if not by_middles:
        ybar = float(by.sum()) / nb
        b = float(((bx - xbar) * (by - ybar)).sum()) / sxx
        a = ybar - b * xbar
    else:
        b, a = slope0, float(np.mean(by - slope0 * bx))
    resid = by - (a + b * bx)
    excess_all = (ys - (a + b * xs)).ravel()
    half = excess_all.size // 2
    jitter = float(np.partition(excess_all, half)[half]) / LN2 if m > 1 else prior_sigma  # mean excess of one point
    min_spread = jitter / m  # mean (= spread) of the minimum of m exponential excesses
    # The spread of a block minimum is min_spread by the latency model; the scatter of the minima
    # about the line is taken instead when larger (the model is wrong, or the drift is changing).
    emp = float(np.sqrt(np.sum(resid**2) / (nb - 2))) if nb > 2 else 0.0
    point_sigma = max(emp, min_spread, prior_sigma / m if nb <= 3 else 0.0, 1e-9)
    if by_middles:  # the slope's spread is one point's (J, or the prior while J is unmeasured) over the middles' lever
        one_point = max(jitter, prior_sigma, point_sigma)
        sxx = sxx_middles * (point_sigma / one_point) ** 2
    if m > 1:
        a -= min_spread
    return LineFit(a=float(a), b=float(b), x_mean=xbar, sxx=sxx, n_points=nb, point_sigma=point_sigma)


class Window:
    """The last ``size`` rows of int64 columns, as contiguous numpy views (cheaper than deques per
    fit), and the newest row as Python ints (read every frame)."""

    def __init__(self, size: int, columns: int = 2) -> None:
        self.size = size
        self._buf = np.zeros((2 * size, columns), np.int64)
        self._lo = 0
        self._hi = 0
        self._last: tuple[int, ...] | None = None

    def __len__(self) -> int:
        return self._hi - self._lo

    def clear(self) -> None:
        self._lo = self._hi = 0
        self._last = None

    def append(self, *row: int) -> None:
        last = tuple(int(v) for v in row)
        if self._hi == self._buf.shape[0]:
            n = len(self)
            self._buf[:n] = self._buf[self._lo:self._hi]
            self._lo, self._hi = 0, n
        self._buf[self._hi] = row
        self._hi += 1
        if self._hi - self._lo > self.size:
            self._lo += 1
        self._last = last

    def keep(self, mask: np.ndarray) -> None:
        rows = self._buf[self._lo:self._hi][mask]
        self._buf[:rows.shape[0]] = rows
        self._lo, self._hi = 0, rows.shape[0]
        self._last = tuple(int(v) for v in rows[-1]) if len(rows) else None

    def column(self, i: int) -> np.ndarray:
        return self._buf[self._lo:self._hi, i]

    @property
    def a(self) -> np.ndarray:
        return self.column(0)

    @property
    def b(self) -> np.ndarray:
        return self.column(1)

    def last(self) -> tuple[int, ...] | None:
        return self._last


@dataclass(frozen=True)
class ClockEstimate:
    """A fitted MCU->Pi map: ``pi_ns = ref_ns + 1e9 * fit(seconds of MCU ticks since ref_tick)``."""

    source: str  # "gpio" or "ping"
    ref_tick: int
    ref_ns: int
    tick_hz: float
    fit: LineFit
    n_samples: int

    @property
    def drift_ppm(self) -> float:
        """How fast the MCU clock runs against the Pi's, in ppm (positive: MCU fast)."""
        return (1.0 / self.fit.b - 1.0) * 1e6

    def mcu_to_pi_ns(self, tick: np.ndarray | float) -> np.ndarray | float:
        x = (tick - self.ref_tick) / self.tick_hz
        return self.ref_ns + 1e9 * self.fit.predict(x)

    def pi_to_mcu_tick(self, pi_ns: np.ndarray | float) -> np.ndarray | float:
        y = (pi_ns - self.ref_ns) * 1e-9
        return self.ref_tick + (y - self.fit.a) / self.fit.b * self.tick_hz

    def sigma_s(self, tick: np.ndarray | float) -> np.ndarray | float:
        """1-sigma uncertainty (s) of ``mcu_to_pi_ns(tick)`` (for the ping source: asymmetry taken as uniform)."""
        return self.fit.sigma((tick - self.ref_tick) / self.tick_hz)


class GpioClockMap:
    """Windowed lower-envelope map from (MCU tick, GPIO timestamp ns) pairs of the same laser edges."""

    def __init__(self, tick_hz: float, gpio_latency_min_s: float = 3e-6, window: int = 512,
                 prior_jitter_s: float = 50e-6, min_pairs: int = 4) -> None:
        if window < 8 or min_pairs < 2:
            raise ValueError(f"window must be >= 8 and min_pairs >= 2, got {window}, {min_pairs}")
        self.tick_hz = tick_hz
        self.latency_ns = gpio_latency_min_s * 1e9
        self.prior_jitter_s = prior_jitter_s
        self.min_pairs = min_pairs
        self._w = Window(window)
        self._est: ClockEstimate | None = None
        self._dirty = False
        self._since_fit = 0
        self.rejected = 0

    def __len__(self) -> int:
        return len(self._w)

    def clear(self) -> None:
        self._w.clear()
        self._est = None

    def add(self, tick: int, gpio_ns: int) -> None:
        last = self._w.last()
        if last is not None and tick <= last[0]:
            return  # out of order or repeated: the pairing hands pairs in tick order
        self._w.append(tick, gpio_ns)
        self._since_fit += 1
        if self._est is None or refit_due(len(self._w), self._since_fit):
            self._dirty = True

    def estimate(self) -> ClockEstimate | None:
        if not self._dirty:
            return self._est
        self._dirty = False
        self._since_fit = 0
        if len(self._w) < self.min_pairs:
            self._est = None
            return None
        t, ns = self._w.a, self._w.b
        ref_tick, ref_ns = int(t[-1]), int(ns[-1])
        x = (t - ref_tick) / self.tick_hz
        y = (ns - ref_ns) * 1e-9
        bad = impossibly_early(x, y)
        nbad = int(bad.sum())
        if nbad and len(self._w) - nbad >= self.min_pairs:
            self.rejected += nbad
            log.debug("rejecting %d GPIO pairs below the envelope", nbad)
            self._w.keep(~bad)
            t, ns = self._w.a, self._w.b
            x, y = (t - ref_tick) / self.tick_hz, (ns - ref_ns) * 1e-9
        fit = lower_envelope_fit(x, y, prior_sigma=self.prior_jitter_s)
        fit = LineFit(a=fit.a - self.latency_ns * 1e-9, b=fit.b, x_mean=fit.x_mean, sxx=fit.sxx,
                      n_points=fit.n_points, point_sigma=fit.point_sigma)
        self._est = ClockEstimate("gpio", ref_tick, ref_ns, self.tick_hz, fit, len(self._w))
        return self._est


class PingClockMap:
    """Windowed minimum-delay (NTP-style) map from PING exchanges; lower accuracy than the GPIO map."""

    def __init__(self, tick_hz: float, up_min_s: float = 0.0, down_min_s: float = 0.0, window: int = 1024,
                 blocks: int = 16, min_samples: int = 3) -> None:
        """``up_min_s``: shortest time from the Pi's send stamp to the MCU's tick stamp (the PING's
        bytes on the line); ``down_min_s``: shortest time from there to the Pi's receive stamp (the
        PONG's bytes). 0 when unknown: the bounds are then the whole round trip, and still hold."""
        if up_min_s < 0 or down_min_s < 0:
            raise ValueError(f"link minimum delays must be >= 0, got {up_min_s}, {down_min_s}")
        self.tick_hz = tick_hz
        self.up_min_ns = up_min_s * 1e9
        self.down_min_ns = down_min_s * 1e9
        self.contradicted = 0  # exchanges faster than the configured minima (then ignored for them)
        self.blocks = blocks
        self.min_samples = min_samples
        self._w = Window(window, columns=3)
        self._est: ClockEstimate | None = None
        self._dirty = False

    def __len__(self) -> int:
        return len(self._w)

    def clear(self) -> None:
        self._w.clear()
        self._est = None

    @property
    def last_tick(self) -> int | None:
        last = self._w.last()
        return None if last is None else last[1]

    def add(self, send_ns: int, tick: int, recv_ns: int) -> None:
        if recv_ns < send_ns:
            raise ValueError(f"ping received ({recv_ns}) before it was sent ({send_ns})")
        if recv_ns - send_ns < self.up_min_ns + self.down_min_ns:
            if not self.contradicted:
                log.warning("a PING round trip of %d ns is shorter than the configured link minima: "
                            "those exchanges use the whole round trip as their bounds", recv_ns - send_ns)
            self.contradicted += 1
        self._w.append(send_ns, tick, recv_ns)
        self._dirty = True

    def estimate(self) -> ClockEstimate | None:
        if not self._dirty:
            return self._est
        self._dirty = False
        if len(self._w) < self.min_samples:
            self._est = None
            return None
        a = self._w.column(slice(None))
        # The MCU stamped its tick within [send + up_min, recv - down_min] (bounded delays); an
        # exchange faster than the two minima says they are wrong, and only [send, recv] holds.
        lo = a[:, 0] + self.up_min_ns
        hi = a[:, 2] - self.down_min_ns
        bad = hi < lo
        if bad.any():
            lo = np.where(bad, a[:, 0], lo)
            hi = np.where(bad, a[:, 2], hi)
        width = (hi - lo) * 1e-9
        n = len(a)
        nb = min(self.blocks, max(1, n // 4))
        m = n // nb
        sel = (n - nb * m) + np.arange(nb) * m + np.argmin(width[n - nb * m:].reshape(nb, m), axis=1)
        ref_tick = int(a[-1, 1])
        ref_ns = int((lo[-1] + hi[-1]) // 2)
        x = (a[sel, 1] - ref_tick) / self.tick_hz
        y = ((lo[sel] + hi[sel]) / 2 - ref_ns) * 1e-9
        xbar = float(x.sum()) / nb
        sxx = float(((x - xbar) ** 2).sum())
        if sxx > 0:
            ybar = float(y.sum()) / nb
            b = float(((x - xbar) * (y - ybar)).sum()) / sxx
            c = ybar - b * xbar
        else:
            b, c = 1.0, float(np.mean(y - x))
        # Each kept exchange places the tick within +-width/2 of the middle of its bounds; taken
        # as uniform there, its spread is width / (2 sqrt 3).
        point = float(np.sqrt(np.mean(width[sel] ** 2))) / (2 * math.sqrt(3))
        spread = float(np.sqrt(np.sum((y - (c + b * x)) ** 2) / (nb - 2))) if nb > 2 else 0.0
        fit = LineFit(a=float(c), b=float(b), x_mean=xbar, sxx=sxx, n_points=nb, point_sigma=max(point, spread, 1e-6))
        self._est = ClockEstimate("ping", ref_tick, ref_ns, self.tick_hz, fit, n)
        return self._est


class EdgePairing:
    """Pairs each reported pulse (rise tick, fall tick) with a GPIO rising and falling edge.

    A pulse is paired only if a rising edge lies near the predicted time and a falling edge
    follows it after the pulse's width (within ``width_tol_s``; of several candidates the pair
    whose spacing is closest to the width): a glitch on the line or an edge of another pulse
    cannot fake that, so spurious edges do not enter the fit. The window around
    the prediction is 10 sigma of the current map (at least 100 us, or 2 ms while the map comes
    from pings: its error may exceed its bounds if the link's minima are wrong) and allows
    ``max_late_s`` of interrupt latency.
    """

    def __init__(self, max_late_s: float = 3e-3, width_tol_s: float = 300e-6, horizon_s: float = 2.0) -> None:
        self.max_late_ns = max_late_s * 1e9
        self.width_tol_ns = width_tol_s * 1e9
        self.horizon_ns = int(horizon_s * 1e9)
        self._mcu: list[tuple[int, int]] = []  # (rise tick, fall tick)
        self._gpio: dict[bool, list[int]] = {True: [], False: []}
        self.unpaired_pulses = 0

    def clear(self) -> None:
        self._mcu.clear()
        self._gpio = {True: [], False: []}

    def add_mcu(self, rise_tick: int, fall_tick: int) -> None:
        self._mcu.append((int(rise_tick), int(fall_tick)))

    def add_gpio(self, ns: int, rising: bool) -> None:
        lst = self._gpio[bool(rising)]
        if lst and ns < lst[-1]:
            bisect.insort(lst, int(ns))
        else:
            lst.append(int(ns))

    def pair(self, est: ClockEstimate, now_ns: int, max_window_s: float) -> list[tuple[int, int]]:
        """Pairs (tick, gpio ns), two per matched pulse, in tick order."""
        out = []
        keep = []
        ups, downs = self._gpio[True], self._gpio[False]
        for rise, fall in self._mcu:
            pred = float(est.mcu_to_pi_ns(rise))
            width_ns = (fall - rise) / est.tick_hz * 1e9
            floor = 100e-6 if est.source == "gpio" else 2e-3  # a ping map may be off by more than it knows
            tol = min(max(10 * float(est.sigma_s(rise)), floor), max_window_s) * 1e9
            lo = bisect.bisect_left(ups, pred - tol)
            hi = bisect.bisect_right(ups, pred + tol + self.max_late_ns)
            match, best = None, self.width_tol_ns
            for r_ns in ups[lo:hi]:  # the (rise, fall) whose spacing is closest to the pulse's width
                f_lo = bisect.bisect_left(downs, r_ns + width_ns - self.width_tol_ns)
                f_hi = bisect.bisect_right(downs, r_ns + width_ns + self.width_tol_ns)
                for f_ns in downs[f_lo:f_hi]:
                    miss = abs(f_ns - r_ns - width_ns)
                    if miss <= best:
                        match, best = (r_ns, f_ns), miss
            if match is not None:
                out += [(rise, match[0]), (fall, match[1])]
                ups.remove(match[0])
                downs.remove(match[1])
            elif pred + width_ns + tol + self.max_late_ns > now_ns:
                keep.append((rise, fall))  # its GPIO events may not be read yet
            else:
                self.unpaired_pulses += 1
        self._mcu = keep
        for lst in (ups, downs):
            del lst[:bisect.bisect_left(lst, now_ns - self.horizon_ns)]
        out.sort()
        return out

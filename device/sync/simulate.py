"""Closed-loop simulation of laser-camera synchronisation, scored against ground truth.

Runs a controller (``ours`` or ``thesis``) against the simulated IMX219 clock
(``device.sim.timing``) and the simulated co-MCU (``device.sim.mcu``). Per delivered frame the
device process would: read the GPIO edge events and the MCU's edge reports that have arrived,
send a heartbeat PING, and run one control step when the frame's metadata reaches user space
(readout of the frame plus an ISP/DMA delay of 4-8 ms). Afterwards every frame's true ROI
exposure window is compared with the true pulses (vectorised):

- error of a frame = max(|pulse start - window start|, |pulse end - window end|) for the pulse
  nearest the window (the guard counts as error: it is light outside the window);
- a frame labelled lit is *partly unlit* unless one pulse covers its whole window;
- a frame labelled unlit is *leaked* if any pulse overlaps its window.

Figures are simulated; the noise model is the one documented in the two simulator modules.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from device.sim.mcu import McuConfig, SimulatedMcu
from device.sim.timing import CameraClock, CameraTimingConfig
from device.sync.control import FrameInfo, SyncConfig, SyncController, SyncState, ThesisController, algorithm1_start_estimate
from device.sync.placement import roi_exposure_window

ISP_DELAY_S = (4e-3, 8e-3)
SETTLE_S = 10.0  # "settled": frames from this long after the first lock on (the guard has converged)
THESIS_INTERVAL_MAX_S = 189e-6  # thesis 5.3.1: interval_max 300 us less the 111 us start delay


@dataclass(frozen=True)
class SimParams:
    seconds: float = 60.0
    controller: str = "ours"
    seed: int = 0
    camera: CameraTimingConfig = CameraTimingConfig(clock_ppm=30.0)
    mcu: McuConfig = McuConfig()
    row_min: int = 300
    row_max: int = 700
    pattern: tuple[bool, ...] = (True, False)
    camera_restart_s: tuple[float, ...] = ()
    mcu_reset_s: tuple[float, ...] = ()
    drop_bursts: tuple[tuple[float, int], ...] = ()  # (time, number of consecutive frames lost)
    sync: dict = field(default_factory=dict)  # SyncConfig overrides


@dataclass
class SimResult:
    metrics: dict
    frames: dict  # per frame arrays (truth and labels)
    events: list


def _sync_config(p: SimParams) -> SyncConfig:
    c = p.camera
    return SyncConfig(row_min=p.row_min, row_max=p.row_max, frame_duration_s=c.frame_duration_s, pattern=p.pattern,
                      tick_hz=p.mcu.tick_hz, gpio_latency_min_s=p.mcu.gpio_latency_min_s,
                      link_up_min_s=p.mcu.link_up_min_s, link_down_min_s=p.mcu.link_down_min_s, **p.sync)


def run(p: SimParams) -> SimResult:
    if p.controller not in ("ours", "thesis"):
        raise ValueError(f"controller must be 'ours' or 'thesis', got {p.controller!r}")
    rng = np.random.default_rng(p.seed)
    cam = CameraClock(p.camera, np.random.default_rng(rng.integers(2**63)))
    mcu = SimulatedMcu(p.mcu, np.random.default_rng(rng.integers(2**63)))
    for t in p.mcu_reset_s:
        mcu.reset_at(t)
    cfg = _sync_config(p)
    t_start = p.camera.start_time_s
    if p.controller == "ours":
        ctrl = SyncController(cfg, mcu)
        t = 0.05
        while t < t_start - 0.2:  # the co-MCU link (heartbeats) is up before the camera starts
            mcu.advance_to(t)
            ctrl.on_ping(*mcu.ping(t))
            t += 0.05
    else:
        ctrl = _thesis_controller(p, cfg, cam, mcu, rng, t_start - 0.3)
    restarts = sorted(p.camera_restart_s)
    bursts = sorted(p.drop_bursts)
    n_max = int(p.seconds / p.camera.frame_duration_s * 1.2) + 64
    T = np.empty(n_max)
    E = np.empty(n_max)
    LT = np.empty(n_max)
    seq = np.empty(n_max, np.int64)
    delivered = np.zeros(n_max, bool)
    label = np.full(n_max, -1, np.int8)  # 1 lit, 0 unlit, -1 unknown
    locked = np.zeros(n_max, bool)
    state_err = np.zeros(n_max, bool)
    t_end = t_start + p.seconds
    readout = p.camera.active_rows * p.camera.line_time_s
    drop_left = 0
    n = 0
    while n < n_max:
        fr = cam.next_frame()
        if restarts and fr.true_start_s >= restarts[0]:
            cam.restart(restarts.pop(0))
            fr = cam.next_frame()
        if fr.true_start_s > t_end:
            break
        if bursts and fr.true_start_s >= bursts[0][0]:
            drop_left = bursts.pop(0)[1]
        T[n], E[n], LT[n], seq[n] = fr.true_start_s, fr.exposure_s, fr.line_time_s, fr.sequence
        lost = fr.dropped or drop_left > 0
        drop_left = max(drop_left - 1, 0)
        if not lost:
            now = fr.true_start_s + readout + rng.uniform(*ISP_DELAY_S)
            mcu.advance_to(now)
            now_ns = int(now * 1e9)
            scale = 1.0 + p.camera.clock_ppm * 1e-6  # metadata counts in the sensor's own lines
            info = FrameInfo(fr.sequence, fr.sensor_timestamp_ns, fr.exposure_s / scale, p.camera.line_time_s,
                             fr.frame_duration_s / scale)
            if p.controller == "ours":
                ctrl.on_gpio_edges(mcu.take_gpio_events(now))
                ctrl.on_mcu_edges(mcu.take_edge_reports(now))
                ctrl.on_ping(*mcu.ping(now))
            mcu.now_s = now
            lab = ctrl.on_frame(info, now_ns)
            delivered[n] = True
            label[n] = -1 if lab.lit is None else int(lab.lit)
            locked[n] = lab.state is SyncState.LOCKED
            state_err[n] = lab.state is SyncState.ERROR
        n += 1
    mcu.advance_to(t_end + 1.0)
    frames = {"T": T[:n], "E": E[:n], "line_time": LT[:n], "sequence": seq[:n], "delivered": delivered[:n],
              "label": label[:n], "locked": locked[:n], "error_state": state_err[:n]}
    metrics = evaluate(frames, mcu, p)
    metrics["controller"] = p.controller
    if p.controller == "ours":
        metrics["final_state"] = ctrl.state.value
        metrics["final_reason"] = ctrl.reason
        metrics["gpio_pairs_rejected"] = ctrl.gpio_map.rejected
        est = ctrl.clock()
        metrics["clock_source"] = est.source if est is not None else None
        metrics["drift_ppm_estimated"] = round(est.drift_ppm, 3) if est is not None else None
        events = ctrl.events
    else:
        metrics["final_state"] = ctrl.state.value
        events = []
    return SimResult(metrics, frames, events)


class _ThesisCpuClock:
    """Time as Algorithm 1 sees it on the simulated Pi: each call costs a little, START_PWM ~111 us+."""

    def __init__(self, t0: float, mcu: SimulatedMcu, rng: np.random.Generator, period: int, width: int,
                 pattern: tuple[bool, ...]) -> None:
        self.t, self.mcu, self.rng = t0, mcu, rng
        self.args = (period, width, pattern)

    def time_ns(self) -> int:
        self.t += self.rng.uniform(1e-6, 3e-6)
        return int(self.t * 1e9)

    def start_pwm(self) -> None:
        work = 111e-6 + self.rng.exponential(60e-6)  # thesis 5.3.1: 111 us before the PWM starts, plus OS noise
        self.mcu.now_s = self.t
        self.mcu.start_now(*self.args, delay_s=self.rng.uniform(0, work))
        self.t += work


def _thesis_controller(p: SimParams, cfg: SyncConfig, cam: CameraClock, mcu: SimulatedMcu,
                       rng: np.random.Generator, t0: float) -> ThesisController:
    c = p.camera
    period = int(round(c.frame_duration_s * p.mcu.tick_hz))
    start, end = roi_exposure_window(0.0, c.exposure_s, c.line_time_s, p.row_min, p.row_max)
    guard = THESIS_INTERVAL_MAX_S / 2  # the thesis's system error: the start is only known to +-interval/2
    width = int(math.ceil((float(end - start) + 2 * guard) * p.mcu.tick_hz))
    clock = _ThesisCpuClock(t0, mcu, rng, period, width, p.pattern)
    t_pwm, interval = algorithm1_start_estimate(clock.start_pwm, clock.time_ns, clock.time_ns,
                                                int(THESIS_INTERVAL_MAX_S * 1e9))
    mcu.advance_to(clock.t)
    delta = float(start) - guard  # pulse start relative to T: the user-defined offset of eq. 5.3
    return ThesisController(cfg, cam, t_pwm, interval, delta, p.pattern)


def evaluate(frames: dict, mcu: SimulatedMcu, p: SimParams) -> dict:
    """Score labelled frames against the true pulses (see module docstring)."""
    rise = np.asarray(mcu.pulses.rise_s)
    fall = np.asarray(mcu.pulses.fall_s)
    ws, we = roi_exposure_window(frames["T"], frames["E"], frames["line_time"], p.row_min, p.row_max)
    delivered = frames["delivered"]
    label = frames["label"]
    n = ws.size
    if rise.size:
        i = np.clip(np.searchsorted(rise, ws), 1, rise.size - 1) if rise.size > 1 else np.zeros(n, int)
        j = i - 1 if rise.size > 1 else i
        near = np.where(np.abs(rise[j] - ws) < np.abs(rise[i] - ws), j, i)
        err = np.maximum(np.abs(rise[near] - ws), np.abs(fall[near] - we))
        full = (rise[near] <= ws) & (fall[near] >= we)
        k = np.searchsorted(rise, we)  # pulses starting before the window ends
        overlap = np.zeros(n, bool)
        for back in (1, 2):
            kk = k - back
            ok = kk >= 0
            overlap[ok] |= fall[kk[ok]] > ws[ok]
        width = fall[near] - rise[near]
    else:
        err = np.full(n, np.inf)
        full = overlap = np.zeros(n, bool)
        width = np.full(n, np.nan)
    first_lock = int(np.argmax(frames["locked"])) if frames["locked"].any() else None
    after = np.zeros(n, bool)
    if first_lock is not None:
        after[first_lock:] = True
    lit = after & delivered & (label == 1)
    unlit = after & delivered & (label == 0)
    e = err[lit] * 1e6
    settled = lit & (frames["T"] >= frames["T"][first_lock] + SETTLE_S) if first_lock is not None else lit
    es = err[settled] * 1e6
    first_delivered = int(np.argmax(delivered)) if delivered.any() else 0
    return {
        "seconds": p.seconds,
        "frames": int(n),
        "frames_delivered": int(delivered.sum()),
        "lock_frames": None if first_lock is None else int(first_lock - first_delivered + 1),
        "p99_error_us": round(float(np.percentile(e, 99)), 2) if e.size else None,
        "max_error_us": round(float(e.max()), 2) if e.size else None,
        "median_error_us": round(float(np.median(e)), 2) if e.size else None,
        "p99_error_us_settled": round(float(np.percentile(es, 99)), 2) if es.size else None,
        "pulse_us": round(float(np.median(width[lit])) * 1e6, 2) if lit.any() else None,
        "frames_lit_after_lock": int(lit.sum()),
        "frames_partly_unlit_after_lock": int((lit & ~full).sum()),
        "frames_leaked_after_lock": int((unlit & overlap).sum()),
        "frames_unknown_after_lock": int((after & delivered & (label == -1)).sum()),
        "frames_in_error_state": int((frames["error_state"] & delivered).sum()),
        "laser_pulses": int(rise.size),
    }

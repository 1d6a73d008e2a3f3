"""The image sensor: expected electrons per pixel -> an 8-bit luminance frame (thesis appendix A.1).

A pure function on arrays, shared by the scene renderer and the calibration renders:
:func:`sensor_frame` adds photon shot noise (eq. A.1-A.4) and temporal dark / read noise
(eq. A.6), clips at the saturation capacity (eq. A.5), applies the analog gain, the 10-bit ADC
with its black level, and the ISP's conversion of the 10-bit value to the 8-bit Y plane.

Numbers of the IMX219 in mode 5 (2x2 binned, one output pixel = 4 photosites of 1.12 um, i.e.
an effective 2.24 um pixel as ``[optics] pixel_pitch_m``). Sony does not publish QE, full well
or read noise for the IMX219; where a value is an assumption it says so:

* ``qe`` 0.12 at 808 nm: ASSUMPTION. Small-pixel BSI silicon with the Bayer dyes (which all pass
  NIR about equally) and no IR-cut filter (NoIR module) is typically 10-15 % at 800-850 nm.
* ``full_well_e`` 4 x 4500 e-: ASSUMPTION, a typical value for a 1.12 um BSI photosite, summed
  over the 2x2 bin.
* ``read_noise_e`` 5 e- per binned pixel: ASSUMPTION (about 2.5 e- per photosite, summed in
  quadrature over 4 sites), at analog gain 1.
* ``black_level_dn`` 64 (10-bit): from the Raspberry Pi IMX219 tuning file
  (``rpi.black_level: 4096`` in 16-bit units = 64 in 10 bits).
* ``analog_gain`` 1 .. 10.67: the IMX219 analog gain register range (gain = 256 / (256 - code),
  code 0..232), as libcamera's IMX219 helper computes it.
* ``e_per_dn`` at gain 1 = full well / (1023 - black): the ADC is assumed to span the full well
  at unity analog gain (ASSUMPTION, the usual design point).
* The ISP's Y output is linear in the 10-bit signal above black (gamma and contrast curves,
  sharpening and noise reduction off, full range, as LaserPi sets the camera up:
  device/camera/picamera2_camera.py): ``Y = (DN - black) * 255 / (1023 - black) * digital_gain``.
  ``isp = "default"`` instead models the ISP as picamera2 sets it up by default (denoise, the
  tuning's gamma curve, sharpening, limited range 16-235: device/sim/isp.py).

Shot noise is drawn as a Gaussian of variance N_e (the Poisson limit, eq. A.4) added to the read
noise, ``n = sqrt(TDN^2 + N_e)`` (eq. A.6). Below ~10 e- this is not Poisson-shaped, but at
those levels read noise and the 8-bit quantisation (~19 e- per Y code at gain 1) dominate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SensorParams:
    """Photometric constants of one output pixel (see the module docstring for their sources)."""

    qe: float = 0.12
    full_well_e: float = 4 * 4500.0
    read_noise_e: float = 5.0
    black_level_dn: float = 64.0
    adc_bits: int = 10
    analog_gain: float = 1.0
    digital_gain: float = 1.0
    isp: str = "linear"  # "linear" (LaserPi's camera set-up) or "default" (device/sim/isp.py)

    def __post_init__(self) -> None:
        if self.isp not in ("linear", "default"):
            raise ValueError(f"sensor: isp must be 'linear' or 'default', got {self.isp!r}")
        if not 0 < self.qe <= 1:
            raise ValueError(f"sensor: qe must be in (0, 1], got {self.qe}")
        for name in ("full_well_e", "analog_gain", "digital_gain"):
            if not getattr(self, name) > 0:
                raise ValueError(f"sensor: {name} must be positive, got {getattr(self, name)}")
        if not 1.0 <= self.analog_gain <= 10.67:
            raise ValueError(f"sensor: analog_gain {self.analog_gain} outside the IMX219 range 1..10.67")
        if self.read_noise_e < 0:
            raise ValueError(f"sensor: read_noise_e must be >= 0, got {self.read_noise_e}")
        if not 0 <= self.black_level_dn < self.max_dn:
            raise ValueError(f"sensor: black_level_dn must be in [0, {self.max_dn}), got {self.black_level_dn}")

    @property
    def max_dn(self) -> int:
        return (1 << self.adc_bits) - 1

    @property
    def e_per_dn(self) -> float:
        """Electrons per ADC step at the current analog gain."""
        return self.full_well_e / (self.max_dn - self.black_level_dn) / self.analog_gain

    @property
    def e_per_y(self) -> float:
        """Electrons per 8-bit Y code (the signal scale a pipeline sees)."""
        return self.e_per_dn * (self.max_dn - self.black_level_dn) / 255.0 / self.digital_gain


#: The IMX219 in sensor mode 5 with the module-level defaults.
IMX219_MODE5 = SensorParams()
#: The settings the simulator uses by default: analogue gain 10, the fixed gain that, with the
#: rest of the photometry, reproduces the thesis's measurements (device/sim/render.py, anchoring).
SIMULATOR_DEFAULT = SensorParams(analog_gain=10.0)


def sensor_frame(
    electrons: np.ndarray,
    rng: np.random.Generator | None,
    params: SensorParams = IMX219_MODE5,
    *,
    normals: np.ndarray | None = None,
) -> np.ndarray:
    """Expected electrons (H, W) -> 8-bit luminance frame (H, W) uint8.

    ``rng``: draws the temporal noise (shot + read); None and no ``normals`` = noise-free.
    ``normals``: optional pre-drawn standard normals of the image's shape, used instead of
    drawing from ``rng`` (the simulator passes slices of a cached table to stay real-time).
    The input is not modified. Negative or non-finite expected electrons are an error.
    """
    e = np.asarray(electrons)
    if e.ndim != 2:
        raise ValueError(f"electrons must be an (H, W) image, got shape {e.shape}")
    if normals is not None and normals.shape != e.shape:
        raise ValueError(f"normals must have the image's shape {e.shape}, got {normals.shape}")
    x = e.astype(np.float32, copy=True)
    lo = float(x.min()) if x.size else 0.0
    if not lo >= 0 or not np.isfinite(x.max() if x.size else 0.0):
        raise ValueError("expected electrons must be finite and >= 0")
    if normals is None and rng is not None:
        normals = rng.standard_normal(x.shape, dtype=np.float32)
    if normals is not None:
        # n = sqrt(TDN^2 + N_e) (eq. A.6), drawn as one Gaussian
        sigma = x + np.float32(params.read_noise_e**2)
        np.sqrt(sigma, out=sigma)
        sigma *= normals
        x += sigma
    np.clip(x, 0.0, params.full_well_e, out=x)  # saturation capacity (eq. A.5)
    # 10-bit ADC: black level + signal, rounded and clipped to the code range
    x *= np.float32(1.0 / params.e_per_dn)
    x += np.float32(params.black_level_dn)
    np.rint(x, out=x)
    np.clip(x, 0.0, params.max_dn, out=x)
    # ISP: linear Y above black, 8 bits
    x -= np.float32(params.black_level_dn)
    x *= np.float32(255.0 / (params.max_dn - params.black_level_dn) * params.digital_gain)
    if params.isp == "default":
        from .isp import isp_default_y

        return isp_default_y(x)
    np.rint(x, out=x)
    np.clip(x, 0.0, 255.0, out=x)
    return x.astype(np.uint8)

"""The Raspberry Pi ISP's default luminance transfer, as an option of the simulated sensor
(``SensorParams.isp = "default"``, device/sim/sensor.py): what a pipeline would see if the camera
ran with picamera2's defaults instead of LaserPi's linear set-up
(device/camera/picamera2_camera.py). A pure function on arrays.

Stages in the ISP's order, each from libcamera's IMX219 NoIR tuning
(raspberrypi/libcamera src/ipa/rpi/vc4/data/imx219_noir.json at 26bfadc6) and the algorithm that
reads it (src/ipa/rpi/controller/rpi/):

1. Spatial denoise (``rpi.sdn``, empty in the tuning, so sdn.cpp's defaults: ``deviation`` 3.2,
   ``strength`` 0.75; picamera2's video configuration asks for NoiseReductionMode Fast). Noise
   sigma from ``rpi.noise`` (``reference_constant`` 0, ``reference_slope`` 3.67 on 16-bit
   values: sigma = 3.67 sqrt(value)). MODEL: each pixel moves ``strength`` of the way to its 3x3
   mean where it differs from it by less than ``deviation`` sigmas; the VC4 hardware filter
   itself is not documented.
2. Gamma (``rpi.contrast`` ``gamma_curve``, 16-bit in and out, piecewise linear): the curve of the
   tuning, :data:`GAMMA_CURVE`. Its adaptive contrast enhancement (``ce_enable``: a histogram
   stretch that follows the scene) is not modelled.
3. Sharpening (``rpi.sharpen``: ``threshold`` 0.75, ``strength`` 1.0, ``limit`` 0.5). MODEL: an
   unsharp mask (Gaussian sigma 1 px) of amount ``strength``, the detail ignored below
   ``threshold`` noise sigmas and clipped to ``limit`` x 32 codes (8-bit); the hardware's filter
   is not documented.
4. Limited range: picamera2 picks the Rec709 colour space for video of 1280x720 and more
   (picamera2.py ``create_video_configuration``), whose range is limited (libcamera
   color_space.cpp ``ColorSpace::Rec709``): Y = 16 + 219 x value.
"""

from __future__ import annotations

import numpy as np

#: rpi.contrast gamma_curve of imx219_noir.json: (input, output) pairs on 0..65535.
GAMMA_CURVE = np.array([
    0, 0, 1024, 5040, 2048, 9338, 3072, 12356, 4096, 15312, 5120, 18051, 6144, 20790, 7168, 23193, 8192, 25744,
    9216, 27942, 10240, 30035, 11264, 32005, 12288, 33975, 13312, 35815, 14336, 37600, 15360, 39168, 16384, 40642,
    18432, 43379, 20480, 45749, 22528, 47753, 24576, 49621, 26624, 51253, 28672, 52698, 30720, 53796, 32768, 54876,
    36864, 57012, 40960, 58656, 45056, 59954, 49152, 61183, 53248, 62355, 57344, 63419, 61440, 64476, 65535, 65535,
], dtype=np.float64).reshape(-1, 2)
NOISE_SLOPE = 3.67  # rpi.noise reference_slope (16-bit values)
SDN_DEVIATION, SDN_STRENGTH = 3.2, 0.75  # sdn.cpp defaults
SHARPEN_THRESHOLD, SHARPEN_STRENGTH, SHARPEN_LIMIT = 0.75, 1.0, 0.5  # rpi.sharpen
SHARPEN_LIMIT_CODES = 32.0  # MODEL: what a limit of 1.0 is in 8-bit codes


def _noise_sigma(y: np.ndarray) -> np.ndarray:
    """rpi.noise's sigma of a linear 8-bit value, in 8-bit codes: 3.67 sqrt(256 y) / 256."""
    return NOISE_SLOPE * np.sqrt(np.maximum(y, 0.0) * 256.0) / 256.0


def isp_default_y(linear: np.ndarray) -> np.ndarray:
    """Linear luminance (float, 0..255, the sensor's signal above black) -> the ISP's default
    8-bit Y plane (uint8), by the stages of the module docstring."""
    import cv2

    y = np.asarray(linear, dtype=np.float32)
    if y.ndim != 2:
        raise ValueError(f"luminance must be an (H, W) image, got shape {y.shape}")
    # 1. spatial denoise
    mean = cv2.blur(y, (3, 3), borderType=cv2.BORDER_REFLECT)
    flat = np.abs(mean - y) < SDN_DEVIATION * _noise_sigma(y)
    y = np.where(flat, y + np.float32(SDN_STRENGTH) * (mean - y), y)
    # 2. gamma, on 16 bits
    g = np.interp(np.clip(y, 0.0, 255.0) * (65535.0 / 255.0), GAMMA_CURVE[:, 0], GAMMA_CURVE[:, 1]) * (255.0 / 65535.0)
    g = g.astype(np.float32)
    # 3. sharpening
    detail = g - cv2.GaussianBlur(g, (0, 0), 1.0, borderType=cv2.BORDER_REFLECT)
    detail[np.abs(detail) < SHARPEN_THRESHOLD * _noise_sigma(y)] = 0.0
    limit = SHARPEN_LIMIT * SHARPEN_LIMIT_CODES
    g = g + np.float32(SHARPEN_STRENGTH) * np.clip(detail, -limit, limit)
    # 4. limited range
    out = 16.0 + np.clip(g, 0.0, 255.0) * (219.0 / 255.0)
    return np.rint(out).astype(np.uint8)

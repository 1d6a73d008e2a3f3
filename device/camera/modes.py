"""The IMX219's sensor modes (Raspberry Pi Camera Module v2) and the configured image as a crop of
one: the one place for the sensor's sizes, readout timing and frame-rate limits.

Source: the Raspberry Pi kernel's driver, raspberrypi/linux ``drivers/media/i2c/imx219.c`` at
commit 55931d0a9f6132c07c31ae5a232b47823ddf897b: its mode table ``supported_modes[]`` (per mode
``.width``/``.height``, the analogue crop ``.crop`` in native-array coordinates, ``.binning``,
``.rate_factor``) and the constants named below. Its timing, as the driver sets it:

* pixel rate ``IMX219_PIXEL_RATE`` = 182.4 MHz ("fixed ... for all the modes"), times the mode's
  ``rate_factor`` (imx219_set_pad_format: ``IMX219_PIXEL_RATE * mode->rate_factor``);
* line length (HTS, register ``IMX219_REG_HTS``) ``IMX219_PPL_MIN`` = 3448 pixel clocks: the
  HBLANK control's minimum and default, ``IMX219_PPL_MIN - mode->width``;
* line time = line length / pixel rate = 18903.5 ns;
* frame length (VTS) = output height + VBLANK lines, VBLANK from ``IMX219_VBLANK_MIN`` = 32 to
  ``IMX219_VTS_MAX`` (0xffff) - height; so a frame lasts at least (height + 32) line times;
* exposure from ``IMX219_EXPOSURE_MIN`` = 4 lines to VTS - 4 lines (imx219_set_ctrl, V4L2_CID_VBLANK);
* analogue gain code ``IMX219_ANA_GAIN_MIN`` 0 .. ``IMX219_ANA_GAIN_MAX`` 232; libcamera's IMX219
  helper (src/ipa/rpi/cam_helper/cam_helper_imx219.cpp) maps code c to gain 256 / (256 - c).

The active pixel array is ``IMX219_PIXEL_ARRAY_WIDTH`` x ``_HEIGHT`` = 3280 x 2464, starting
``IMX219_PIXEL_ARRAY_LEFT``/``_TOP`` = 8 columns/rows into the native array; crops here are in
active-array pixels, as libcamera reports them. Cross-checks: ``libcamera-hello --list-cameras``
on this driver lists 640x480 [206.65 fps - (1000, 752)/1280x960 crop], 1640x1232 [41.85 fps -
(0, 0)/3280x2464 crop], 1920x1080 [47.57 fps - (680, 692)/1920x1080 crop], 3280x2464 [21.19 fps -
(0, 0)/3280x2464 crop] (raspberrypi/linux issue #5438), which tests/test_sensor_modes.py checks
the table against. The later mainline-style driver (same file at commit 01a8e801cd93) computes
the same centred crops and has the same pixel rate, line length and VBLANK minimum for two
lanes, but no ``rate_factor``: there the 640x480 mode reads at the normal pixel rate (103.33 fps,
as issue #5438 reports after an update). LaserPi does not use that mode.

How the configured image relates (thesis B.1.4, Table B.3, "mode 5"): picamera2 runs the
1640x1232 2x2-binned mode (the whole active array binned) and the ISP crops its centre 922 rows
(``ScalerCrop`` (0, 310, 3280, 1844) in active-array pixels: 155 binned rows above and below) to
a 1640x922 image, which sits at the top left of the 1664x928 frame buffer of the configuration
(``[image]``: width/height the buffer, active_width/active_height the image, sensor_mode,
mode_left and mode_top this crop). The sensor reads all 1232 rows of the mode, so image row r is
read (155 + r) line times after the mode's first row, and a frame lasts at least 1232 + 32 lines.
"""

from __future__ import annotations

from dataclasses import dataclass

#: Pixel rate of every mode with rate_factor 1, Hz (IMX219_PIXEL_RATE, two CSI-2 lanes).
IMX219_PIXEL_RATE_HZ = 182_400_000
#: Line length (HTS) in pixel clocks: the HBLANK control's minimum and default (IMX219_PPL_MIN).
IMX219_LINE_LENGTH_PIXELS = 3448
#: Minimum vertical blanking, lines (IMX219_VBLANK_MIN).
IMX219_VBLANK_MIN_LINES = 32
#: Longest frame, lines (IMX219_VTS_MAX).
IMX219_VTS_MAX_LINES = 0xFFFF
#: Shortest exposure, lines (IMX219_EXPOSURE_MIN), and the lines an exposure stays below the
#: frame length (imx219_set_ctrl: exposure_max = height + vblank - 4).
IMX219_EXPOSURE_MIN_LINES = 4
IMX219_EXPOSURE_MARGIN_LINES = 4
#: Largest analogue gain: code IMX219_ANA_GAIN_MAX = 232 as gain 256 / (256 - code) (libcamera).
IMX219_ANALOG_GAIN_MAX = 256 / (256 - 232)
#: The active pixel array (IMX219_PIXEL_ARRAY_WIDTH/_HEIGHT) and where it starts in the native
#: array (IMX219_PIXEL_ARRAY_LEFT/_TOP); the driver's crops are in native coordinates.
IMX219_ARRAY_WIDTH, IMX219_ARRAY_HEIGHT = 3280, 2464
IMX219_ARRAY_LEFT, IMX219_ARRAY_TOP = 8, 8


@dataclass(frozen=True)
class SensorMode:
    """One row of ``supported_modes[]``: output ``width`` x ``height``, each output pixel the
    sum of ``binning`` x ``binning`` array pixels, read from the active-array rectangle starting
    ``crop_left`` columns and ``crop_top`` rows in (the rows/columns skipped before the mode's
    first output row/column; ``width * binning`` x ``height * binning`` in size)."""

    width: int
    height: int
    binning: int
    crop_left: int
    crop_top: int
    vts_default: int  # frame length the driver starts with (vts_def), lines
    rate_factor: int = 1  # pixel clock multiple: 2 in the 640x480 mode's special binning

    def __post_init__(self) -> None:
        if self.binning not in (1, 2) or self.rate_factor not in (1, 2):
            raise ValueError(f"mode {self.name}: binning and rate_factor are 1 or 2, got {self.binning}, {self.rate_factor}")
        if not (0 <= self.crop_left and self.crop_left + self.width * self.binning <= IMX219_ARRAY_WIDTH
                and 0 <= self.crop_top and self.crop_top + self.height * self.binning <= IMX219_ARRAY_HEIGHT):
            raise ValueError(f"mode {self.name}: crop ({self.crop_left}, {self.crop_top}) leaves the {IMX219_ARRAY_WIDTH}x"
                             f"{IMX219_ARRAY_HEIGHT} array")

    @property
    def name(self) -> str:
        """``"WIDTHxHEIGHT"``, the key of :data:`SENSOR_MODES` and of the configuration's ``sensor_mode``."""
        return f"{self.width}x{self.height}"

    @property
    def pixel_rate_hz(self) -> int:
        return IMX219_PIXEL_RATE_HZ * self.rate_factor

    @property
    def line_time_ns(self) -> float:
        """Time between the readouts of consecutive output rows, ns, to the whole nanosecond:
        line length / pixel rate = 18903.5 ns -> 18904 ns (thesis Table B.3), 26 ppm long."""
        return float(round(1e9 * IMX219_LINE_LENGTH_PIXELS / self.pixel_rate_hz))

    @property
    def line_time_s(self) -> float:
        return self.line_time_ns / 1e9

    @property
    def min_frame_lines(self) -> int:
        """Shortest frame: every output row plus the minimum vertical blanking."""
        return self.height + IMX219_VBLANK_MIN_LINES

    @property
    def min_frame_duration_s(self) -> float:
        """(height + VBLANK min) x line length / pixel rate (exact, not the rounded line time)."""
        return self.min_frame_lines * IMX219_LINE_LENGTH_PIXELS / self.pixel_rate_hz

    @property
    def max_frame_duration_s(self) -> float:
        return IMX219_VTS_MAX_LINES * IMX219_LINE_LENGTH_PIXELS / self.pixel_rate_hz

    @property
    def max_frame_rate_hz(self) -> float:
        return 1.0 / self.min_frame_duration_s


#: The driver's modes by name (supported_modes[] in order; crops from its .crop, native
#: coordinates minus IMX219_PIXEL_ARRAY_LEFT/_TOP).
SENSOR_MODES: dict[str, SensorMode] = {m.name: m for m in (
    SensorMode(3280, 2464, 1, 8 - IMX219_ARRAY_LEFT, 8 - IMX219_ARRAY_TOP, vts_default=0x0DC6),  # IMX219_VTS_15FPS
    SensorMode(1920, 1080, 1, 688 - IMX219_ARRAY_LEFT, 700 - IMX219_ARRAY_TOP, vts_default=0x06E3),  # IMX219_VTS_30FPS_1080P
    SensorMode(1640, 1232, 2, 8 - IMX219_ARRAY_LEFT, 8 - IMX219_ARRAY_TOP, vts_default=0x06E3),  # IMX219_VTS_30FPS_BINNED
    SensorMode(640, 480, 2, 1008 - IMX219_ARRAY_LEFT, 760 - IMX219_ARRAY_TOP, vts_default=0x06E3, rate_factor=2),
)}


def sensor_mode_named(name: str) -> SensorMode:
    """The mode called ``name``; ValueError naming the known ones otherwise."""
    try:
        return SENSOR_MODES[name]
    except KeyError:
        raise ValueError(f"sensor mode must be one of {', '.join(map(repr, SENSOR_MODES))}, got {name!r}") from None


@dataclass(frozen=True)
class ImageWindow:
    """The image as a crop of a sensor mode's output (the ISP's ScalerCrop; the sensor still
    reads the whole mode): image pixel (c, r) is the mode's output pixel (left + c, top + r), so
    image row r is read (top + r) line times after the mode's first row."""

    mode: SensorMode
    left: int
    top: int
    width: int
    height: int

    def __post_init__(self) -> None:
        if not (0 <= self.left and self.left + self.width <= self.mode.width
                and 0 <= self.top and self.top + self.height <= self.mode.height and self.width > 0 and self.height > 0):
            raise ValueError(f"a {self.width}x{self.height} image at ({self.left}, {self.top}) does not fit the "
                             f"{self.mode.name} sensor mode")

    @property
    def scaler_crop(self) -> tuple[int, int, int, int]:
        """libcamera's ScalerCrop of this window: (x, y, width, height) in active-array pixels."""
        b = self.mode.binning
        return (self.mode.crop_left + self.left * b, self.mode.crop_top + self.top * b, self.width * b, self.height * b)


#: The thesis's mode 5 (B.1.4, Table B.3) as picamera2 gets it: the centre 922 rows of the
#: 1640x1232 binned mode, (1232 - 922) / 2 = 155 above.
MODE5 = ImageWindow(SENSOR_MODES["1640x1232"], left=0, top=155, width=1640, height=922)


@dataclass(frozen=True)
class ReadoutGeometry:
    """Where the delivered image sits in the sensor's readout, as libcamera reports it for the
    configured mode: image row r is read ``first_row + r`` line times after the frame start."""

    first_row: int  # sensor-mode rows read before image row 0 (the ScalerCrop's top, in mode rows)
    line_time_ns: float  # time between consecutive mode rows


def readout_geometry(sensor_size: tuple[int, int], crop_limits: tuple[int, int, int, int],
                     min_frame_duration_us: float, scaler_crop: tuple[int, int, int, int],
                     vblank_min_lines: int = IMX219_VBLANK_MIN_LINES) -> ReadoutGeometry:
    """The readout geometry from what picamera2 reports after ``configure`` (no mode table).

    * ``sensor_size``: the configured sensor mode's output size (``camera_configuration()["sensor"]
      ["output_size"]``);
    * ``crop_limits``: the mode's rectangle on the active array, ``camera_controls["ScalerCrop"]``'s
      maximum (picamera2.py ``sensor_modes``: ``crop_limits = scaler_crop_max``); its height over
      the mode's height is the vertical binning;
    * ``min_frame_duration_us``: ``camera_controls["FrameDurationLimits"]``'s minimum, which
      libcamera's Raspberry Pi IPA sets to the mode's ``minFrameLength * minLineLength``
      (raspberrypi/libcamera src/ipa/rpi/common/ipa_base.cpp, ``mode_.minFrameDuration``), the
      frame length being the mode's height plus the sensor's minimum vertical blanking
      (``vblank_min_lines``, IMX219_VBLANK_MIN in imx219.c; libcamera's ``minFrameLength`` is
      the driver's height + VBLANK minimum). So the line time includes any line-length
      adjustment the IPA made for the ISP ("Adjusting mode minimum line length", same file);
    * ``scaler_crop``: the request metadata's ``ScalerCrop`` (x, y, w, h) on the active array.

    ValueError names a crop outside the mode or a binning that is not whole.
    """
    w, h = sensor_size
    cx, cy, cw, ch = crop_limits
    if h <= 0 or ch <= 0 or ch % h or cw % w:
        raise ValueError(f"sensor mode {w}x{h} does not bin evenly from its crop {crop_limits}")
    binning = ch // h
    sx, sy, sw, sh = scaler_crop
    if not (cy <= sy and sy + sh <= cy + ch and cx <= sx and sx + sw <= cx + cw):
        raise ValueError(f"ScalerCrop {scaler_crop} is not inside the sensor mode's crop {crop_limits}")
    if not min_frame_duration_us > 0:
        raise ValueError(f"the shortest frame duration must be positive, got {min_frame_duration_us} us")
    return ReadoutGeometry(first_row=(sy - cy) // binning,
                           line_time_ns=min_frame_duration_us * 1e3 / (h + vblank_min_lines))

"""Laser-camera synchronisation: clock mapping, pulse placement and control (thesis ch. 5, 7.2.3).

Wiring in the device process (one ``SyncController`` per sensor; all times CLOCK_MONOTONIC ns)::

    sched = CoMcuScheduler(CoMcu(serial_port))           # LaserScheduler on the firmware's protocol
    ctrl = SyncController(SyncConfig(row_min, row_max, frame_duration_s), sched)
    gpio = GpioEdgeSource("/dev/gpiochip0", LINE)        # the laser trigger, wired to a Pi GPIO
    every ~50 ms (beside CoMcu.heartbeat()): ctrl.on_ping(*sched.ping_sample())
    every frame, before on_frame:   ctrl.on_mcu_edges(sched.edge_reports())
    on each frame (after reading):  ctrl.on_gpio_edges(gpio.read())
                                    label = ctrl.on_frame(FrameInfo(seq, SensorTimestamp, exposure_s,
                                                          line_time_s, frame_duration_s), time.monotonic_ns())
                                    frame metadata "lit" = label.lit (None: unknown, not locked)

Modules: ``clock_map`` (MCU ticks -> Pi ns), ``placement`` (ROI exposure window -> pulse, Class 1
power), ``control`` (our controller and the thesis's baseline), ``gpio_edges`` (libgpiod),
``comcu_scheduler`` (the controller's LaserScheduler on device.comcu.CoMcu),
``simulate`` (the closed loop against device/sim/timing.py and device/sim/mcu.py).
"""

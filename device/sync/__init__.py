"""Laser-camera synchronisation: clock mapping, pulse placement and control (thesis ch. 5, 7.2.3).

Wiring in the device process (one ``SyncController`` per sensor; all times CLOCK_MONOTONIC ns)::

    comcu = CoMcu(serial_port)
    ctrl = SyncController(SyncConfig(row_min, row_max, frame_duration_s), CoMcuTrain(comcu))
    gpio = GpioEdgeSource("/dev/gpiochip0", LINE)        # the laser trigger, wired to a Pi GPIO
    every ~50 ms (beside comcu.heartbeat()):
        r = comcu.ping(); ctrl.on_ping(r.host_send_ns, r.mcu_rx_ticks, r.host_recv_ns)
    every frame, before on_frame:   ctrl.on_mcu_edges([(e.rise_ticks, e.fall_ticks) for e in comcu.edges()
                                                       if not e.flags])   # skip cut / late-fall pulses
    on each frame (after reading):  ctrl.on_gpio_edges(gpio.read())
                                    label = ctrl.on_frame(FrameInfo(seq, SensorTimestamp, exposure_s,
                                                          line_time_s, frame_duration_s), time.monotonic_ns())
                                    frame metadata "lit" = label.lit (None: unknown, not locked)

``CoMcu`` and ``CoMcuTrain`` (the LaserScheduler on the firmware) are in device/laser/comcu.py.
Modules: ``clock_map`` (MCU ticks -> Pi ns), ``placement`` (ROI exposure window -> pulse, Class 1
power), ``control`` (our controller and the thesis's baseline), ``gpio_edges`` (libgpiod),
``simulate`` (the closed loop against device/sim/timing.py and device/sim/mcu.py).
"""

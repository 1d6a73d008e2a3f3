/* Message set of the Pi <-> co-MCU link (types 0x40-0x7F).  Must match protocol/mcu.py;
 * tests/test_mcu_protocol.py checks the numbers and sizes against this file.
 * Every multi-byte field is little-endian; times are MCU ticks (0.5 us). */
#ifndef LASERPI_MSG_H
#define LASERPI_MSG_H

#define PROTOCOL_VERSION 1
#define MAX_PAYLOAD_MCU 48

/* Pi -> MCU */
#define MSG_PING 0x40       /* empty */
#define MSG_SCHEDULE 0x41   /* <QIIIBB first_rise, period, width, mask, n, flags  (22) */
#define MSG_TRIM 0x42       /* <ii phase_delta, period_delta                      (8) */
#define MSG_STOP 0x43       /* empty */
#define MSG_STATUS_REQ 0x44 /* empty */
#define MSG_HEARTBEAT 0x45  /* empty */
#define MSG_INFO_REQ 0x46   /* empty */
/* MCU -> Pi */
#define MSG_PONG 0x60   /* <QQ rx_tick, tx_tick                                   (16) */
#define MSG_ACK 0x61    /* <BI acked_type, info                                   (5) */
#define MSG_NACK 0x62   /* <BBI acked_type, reason, detail                        (6) */
#define MSG_STATUS 0x63 /* <BBBBIHHHHHIIQQ see README                             (42) */
#define MSG_EDGE 0x64   /* <IQQB index, rise, fall, flags                         (21) */
#define MSG_INFO 0x65   /* <BBHIIII version, reset_cause, hb_ms, max_pulse, max_duty_ppm, ticks/s, min_period (20) */

#define LEN_SCHEDULE 22
#define LEN_TRIM 8
#define LEN_PONG 16
#define LEN_ACK 5
#define LEN_NACK 6
#define LEN_STATUS 42
#define LEN_EDGE 21
#define LEN_INFO 20

#define SCHEDULE_FLAG_STREAM_EDGES 0x01

/* NACK reasons */
#define NACK_MALFORMED 1       /* COBS, length, version or payload size wrong */
#define NACK_CRC 2             /* CRC-32 mismatch */
#define NACK_UNKNOWN_TYPE 3
#define NACK_ENVELOPE_WIDTH 4  /* detail = MAX_PULSE_TICKS */
#define NACK_ENVELOPE_DUTY 5   /* detail = smallest allowed gap between pulses, ticks */
#define NACK_BUSY 6            /* detail = current state */
#define NACK_BAD_TIME 7        /* start too close, in the past or too far ahead */
#define NACK_BAD_PATTERN 8     /* n outside 1..32, no lit frame, or mask bits beyond n */
#define NACK_BAD_VALUE 9       /* width or period below the minimum the firmware can place */
#define NACK_NOT_RUNNING 10    /* TRIM without a running schedule */
#define NACK_ENVELOPE_RATE 11  /* pulses closer than MIN_PERIOD_TICKS (rise to rise or fall to fall); detail = it */

/* states */
#define STATE_IDLE 0
#define STATE_RUNNING 1
#define STATE_FAULT 2

/* fault flags (latched until STOP) */
#define FAULT_HEARTBEAT 0x01   /* heartbeats stopped */
#define FAULT_WIDTH 0x02       /* run-time guard: pulse exceeded MAX_PULSE_TICKS */
#define FAULT_DUTY 0x04        /* run-time guard: next pulse would violate the duty envelope */
#define FAULT_LATE 0x08        /* a rise could not be armed in time */
#define FAULT_RATE 0x10        /* run-time guard: next pulse would come closer than MIN_PERIOD_TICKS */

/* edge flags */
#define EDGE_FALL_FORCED 0x01  /* the fall could not be armed in time: software ended the pulse, late */
#define EDGE_CUT 0x02          /* the pulse was cut by STOP or a fault */

#endif

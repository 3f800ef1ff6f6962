/* fw_config.h: compile-time configuration of the reference firmware (one motor, one timer). */
#ifndef FW_CONFIG_H
#define FW_CONFIG_H

#include <stdint.h>

/* --- capture/compare timer: one free-running counter, HALL_TIMER_BITS wide, at TIMER_HZ ------- */
#ifndef HALL_TIMER_BITS
#define HALL_TIMER_BITS 32
#endif
#if HALL_TIMER_BITS == 32
#define TIMER_MASK 0xFFFFFFFFu
#elif HALL_TIMER_BITS == 16
#define TIMER_MASK 0xFFFFu
#else
#error "HALL_TIMER_BITS must be 16 or 32"
#endif
/* 10 MHz: 0.1 us per tick (the edge-message resolution of the framework's own links). At 16 bits
   the counter wraps every 6.55 ms; every interrupt extends it to a 64-bit tick count (timebase.c),
   and the 20 kHz control interrupt guarantees one look at it every 500 ticks. */
#ifndef TIMER_HZ
#define TIMER_HZ 10000000u
#endif
/* The compare interrupt's latency, in ticks: from the match to its gates taking effect (exception
   entry and the interrupt's work up to its gate write). The firmware cannot read the counter when it
   writes the gates, so it arms each command this much before its instant: the gates then change at
   the instant the firmware records for the commutation (the ADC's transient model of the current at
   a Hall edge, hence the armature correction, is anchored there). 0 on a PC build (sil: runs an
   interrupt in zero time); a target's build sets it (sil.toml's [target] flags). */
#ifndef COMPARE_LATENCY_TICKS
#define COMPARE_LATENCY_TICKS 0
#endif
#define TIMER_HALF ((TIMER_MASK >> 1) + 1u)   /* the farthest ahead a compare can be armed */
#define SECONDS_PER_TICK (1.0f / (float)TIMER_HZ)

/* --- control (PWM) interrupt with its synchronous phase-current conversion ------------------- */
#ifndef CONTROL_HZ
#define CONTROL_HZ 20000u
#endif
#ifndef AMPS_PER_COUNT
#define AMPS_PER_COUNT 0.01f                    /* +-327 A over the I16 range */
#endif

/* --- the motor (paper pump: bldc/motor.py MotorParameters()) ----------------------------------- */
#ifndef POLE_PAIRS
#define POLE_PAIRS 2
#endif
#define N_POLES (2 * POLE_PAIRS)
#define EDGES_PER_TURN (6 * POLE_PAIRS)
#define MOTOR_R_OHM 0.0655f
#define MOTOR_L_H 60e-6f                         /* phase inductance */
#define MOTOR_KE_V_S 0.0216f                     /* flat-top phase BEMF per mechanical rad/s */
#define MOTOR_J_KG_M2 0.0039f
#define MOTOR_FRICTION 1e-5f                     /* N m s/rad */
#define MOTOR_FAN 1.5e-7f                        /* N m s^2 */
#define MOTOR_SUPPLY_V 80.0f
/* the speed loop, as tuned on the paper pump (times speed_loop_gain_scale, 1 for it) */
#define SPEED_KP_PER_RPM 1e-4f
#define SPEED_KI_PER_RPM_S 2e-3f
#define SPEED_INTEGRATE_WITHIN 0.10f
#define CURRENT_LIMIT_A 15.0f
#define SPEED_SETPOINT_DEFAULT_RPM 5000.0f
#define SPEED_SETPOINT_MAX_RPM 30000.0f

/* --- lost-edge detection (hil/controller/virtual.py) -------------------------------------------- */
#define MISSING_EDGE_RATIO 1.8f
#define SAME_SECTOR_RATIO 1.3f

/* --- calibration bounds (bldc/contract.py, validate_corrections) -------------------------------- */
#define CAL_MAX_INSTALLATION_DEG_E 30.0
#define CAL_MAX_POLE_DEG_E 20.0
#define CAL_MAX_DELAY_S 500e-6
#define CAL_MAX_ARMATURE_DEG_E_PER_A 5.0
#define CAL_N_VALUES (3 + N_POLES + 3)           /* installation[3], pole[2p], rise, fall, armature */

/* --- strategies ---------------------------------------------------------------------------------- */
#define STRATEGY_RAW 0u
#define STRATEGY_CORRECTED 1u
#define STRATEGY_KF 2u
#define STRATEGY_SAGE_HUSA 3u

/* --- fault codes (CiA 301 EMCY error codes) ---------------------------------------------------- */
#define FAULT_ILLEGAL_HALL_CODE 0xFF01u
#define FAULT_MISSING_EDGE 0xFF02u
#define FAULT_FILTER_GUARD_TRIP 0xFF03u
#define FAULT_INVALID_CALIBRATION 0xFF04u
#define FAULT_CAPTURE_TIMING 0xFF05u
#define FAULT_INTERNAL 0x6100u

#define FW_PI_F 3.14159265358979f
#define FW_SECTOR_RAD (FW_PI_F / 3.0f)

#endif /* FW_CONFIG_H */

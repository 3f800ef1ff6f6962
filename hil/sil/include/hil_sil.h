/* hil_sil.h: the firmware-in-the-loop interface (hil-sil/1) of bldc-hil.
 *
 * A firmware under test exports these functions with C linkage, compiled for the PC as a shared
 * library (or as sources a sil.toml lists, which the framework compiles). The framework emulates
 * the peripherals around it: a free-running capture/compare timer, the Hall pins' capture
 * channels, the phase-current ADC, the compare unit, the control (PWM) interrupt and the
 * inverter driven by the gates and duty the firmware leaves in force. docs/firmware-in-the-loop.md
 * says what each does. The framework adds this header's folder to every build's include path.
 */
#ifndef HIL_SIL_H
#define HIL_SIL_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define HIL_SIL_ABI 1u

#if defined(_WIN32)
#define HIL_SIL_EXPORT __declspec(dllexport)
#else
#define HIL_SIL_EXPORT __attribute__((visibility("default")))
#endif

typedef struct {
    uint32_t abi;            /* HIL_SIL_ABI */
    const char *name;        /* e.g. "acme-p3 fw 2.4.1" (shown in the report) */
    uint32_t timer_hz;       /* free-running capture/compare timer clock, e.g. 1000000 */
    uint8_t timer_bits;      /* 16 or 32: the counter wraps at 2^bits */
    uint32_t control_hz;     /* control (PWM) interrupt rate, e.g. 20000 */
    float amps_per_count;    /* phase-current ADC scale: amps = counts * amps_per_count */
    uint8_t pole_pairs;      /* the motor it is configured for */
} hil_sil_info;

/* gate bits of hil_sil_gates() */
#define HIL_SIL_AH (1u << 0)
#define HIL_SIL_AL (1u << 1)
#define HIL_SIL_BH (1u << 2)
#define HIL_SIL_BL (1u << 3)
#define HIL_SIL_CH (1u << 4)
#define HIL_SIL_CL (1u << 5)

HIL_SIL_EXPORT void hil_sil_describe(hil_sil_info *info);  /* may be called before reset */
HIL_SIL_EXPORT void hil_sil_reset(uint8_t levels);         /* power-on reset; levels: Hall pins at start */

/* interrupts: each runs to completion, in zero time, never nested */
HIL_SIL_EXPORT void hil_sil_hall_isr(uint32_t count, uint8_t pin, uint8_t levels, const int16_t adc[3]);
HIL_SIL_EXPORT void hil_sil_control_isr(uint32_t count, const int16_t adc[3]);
HIL_SIL_EXPORT void hil_sil_compare_isr(uint32_t count);   /* optional */

/* outputs, read by the framework after every interrupt; in force until they change */
HIL_SIL_EXPORT uint8_t hil_sil_gates(void);                /* bit 0 AH, 1 AL, 2 BH, 3 BL, 4 CH, 5 CL */
HIL_SIL_EXPORT uint16_t hil_sil_duty(void);                /* high-side PWM duty, 0..65535 */
HIL_SIL_EXPORT int hil_sil_compare(uint32_t *count);       /* optional: 1 = a compare is armed at *count */

/* object dictionary, CiA 301 semantics: little-endian bytes; size is the buffer's capacity (read)
   or the data's length (write); returns the byte count (read), 0 (write), or a negative SDO
   abort code, e.g. -0x06020000 (object does not exist), -0x06070010 (length mismatch) */
HIL_SIL_EXPORT int32_t hil_sil_od_read(uint16_t index, uint8_t sub, uint8_t *buf, uint32_t size);
HIL_SIL_EXPORT int32_t hil_sil_od_write(uint16_t index, uint8_t sub, const uint8_t *buf, uint32_t size);
HIL_SIL_EXPORT int hil_sil_emcy(uint16_t *code);           /* optional: 1 = an EMCY code was popped */

#ifdef __cplusplus
}
#endif

#endif /* HIL_SIL_H */

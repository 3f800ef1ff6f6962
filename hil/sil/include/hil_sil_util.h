/* hil_sil_util.h: header-only helpers for a firmware under test of bldc-hil (beside hil_sil.h).
 *
 * What every pump firmware on the bench repeats, written once: the six-step table the framework's
 * plant and gate decoder use, the CiA 301 error-register bits and SDO abort codes a device profile
 * names, and a small EMCY queue as a CAN controller's transmit buffer holds it. C99 and C++; no
 * allocation, no library call, the same on the PC (sil:) and on the part (pil:). Include it where
 * you need it; nothing here is required by the hil-sil/1 interface.
 */
#ifndef HIL_SIL_UTIL_H
#define HIL_SIL_UTIL_H

#include <stdint.h>

#include "hil_sil.h"

#ifdef __cplusplus
extern "C" {
#endif

/* ---- six-step commutation (bldc/hall.py) -------------------------------------------------------
 * A Hall code is A*4 + B*2 + C; its sector 0..5, or -1 for the two illegal codes (000, 111). In
 * sector s the phase HIL_SECTOR_HIGH_PHASE[s] is switched high (chopped at the duty) and
 * HIL_SECTOR_LOW_PHASE[s] low; the third floats. Phases 0, 1, 2 are A, B, C. */
static const int8_t HIL_SECTOR_OF_CODE[8] = {-1, 5, 3, 4, 1, 0, 2, -1};
static const uint8_t HIL_SECTOR_HIGH_PHASE[6] = {2, 2, 0, 0, 1, 1};
static const uint8_t HIL_SECTOR_LOW_PHASE[6] = {0, 1, 1, 2, 2, 0};

/* the sector of three pin levels (bit 0 A, bit 1 B, bit 2 C, as hil_sil_hall_isr passes them) */
static inline int hil_sector_of_levels(uint8_t levels)
{
    return HIL_SECTOR_OF_CODE[((levels & 1u) << 2) | (levels & 2u) | ((levels >> 2) & 1u)];
}

/* the gate bits (HIL_SIL_AH ... HIL_SIL_CL) of a sector; 0 (all open) for a sector outside 0..5 */
static inline uint8_t hil_gates_of_sector(int s)
{
    if (s < 0 || s > 5) return 0u;
    return (uint8_t)((1u << (2u * HIL_SECTOR_HIGH_PHASE[s])) | (1u << (2u * HIL_SECTOR_LOW_PHASE[s] + 1u)));
}

/* ---- CiA 301: error register (object 0x1001) bits ---------------------------------------------- */
#define HIL_ERR_REG_GENERIC 0x01u
#define HIL_ERR_REG_CURRENT 0x02u
#define HIL_ERR_REG_VOLTAGE 0x04u
#define HIL_ERR_REG_TEMPERATURE 0x08u
#define HIL_ERR_REG_COMMUNICATION 0x10u
#define HIL_ERR_REG_PROFILE 0x20u
#define HIL_ERR_REG_MANUFACTURER 0x80u

/* ---- CiA 301: SDO abort codes, as hil_sil_od_read / _od_write return them (negated) ----------- */
#define HIL_SDO_UNSUPPORTED_ACCESS 0x06010000L
#define HIL_SDO_WRITE_ONLY 0x06010001L
#define HIL_SDO_READ_ONLY 0x06010002L
#define HIL_SDO_NO_OBJECT 0x06020000L
#define HIL_SDO_LENGTH 0x06070010L
#define HIL_SDO_NO_SUBINDEX 0x06090011L
#define HIL_SDO_VALUE_INVALID 0x06090030L /* value range of parameter exceeded */
#define HIL_SDO_VALUE_TOO_HIGH 0x06090031L
#define HIL_SDO_VALUE_TOO_LOW 0x06090032L
#define HIL_SDO_GENERAL 0x08000000L
#define HIL_SDO_DEVICE_STATE 0x08000022L /* data cannot be stored because of the present device state */

/* ---- EMCY: the codes a device queued for transmission, oldest first ---------------------------
 * A full queue drops the new frame, as a CAN controller whose transmit buffer is full does; the
 * framework reads the queue with hil_sil_emcy (hil_emcy_pop). */
#ifndef HIL_EMCY_SLOTS
#define HIL_EMCY_SLOTS 16u
#endif

typedef struct {
    uint16_t code[HIL_EMCY_SLOTS];
    uint8_t head;
    uint8_t n;
} hil_emcy_queue;

static inline void hil_emcy_clear(hil_emcy_queue *q)
{
    q->head = 0u;
    q->n = 0u;
}

/* 1 if queued, 0 if the queue was full (the frame is lost) */
static inline int hil_emcy_push(hil_emcy_queue *q, uint16_t code)
{
    if (q->n >= HIL_EMCY_SLOTS) return 0;
    q->code[(q->head + q->n) % HIL_EMCY_SLOTS] = code;
    q->n++;
    return 1;
}

/* 1 and the oldest code in *code, or 0 if the queue is empty */
static inline int hil_emcy_pop(hil_emcy_queue *q, uint16_t *code)
{
    if (q->n == 0u) return 0;
    *code = q->code[q->head];
    q->head = (uint8_t)((q->head + 1u) % HIL_EMCY_SLOTS);
    q->n--;
    return 1;
}

#ifdef __cplusplus
}
#endif

#endif /* HIL_SIL_UTIL_H */

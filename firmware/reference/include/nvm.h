/* nvm.h: the configuration the firmware keeps across a power cycle (its non-volatile memory), as
   the virtual controller keeps its configuration across its reset: strategy, speed set point,
   the staged and the applied calibration, the Sage-Husa settings and the heartbeat period. */
#ifndef NVM_H
#define NVM_H

#include <stdint.h>

#include "calib.h"
#include "filter.h"

typedef struct {
    uint32_t magic;             /* NVM_MAGIC once initialised (first power-on) */
    uint8_t strategy;
    float speed_setpoint_rpm;
    cal_table_t staged;
    cal_table_t applied;
    filter_vector_t sage_husa;  /* 0x2020 (the Sage-Husa strategy's filter) */
    uint16_t heartbeat_ms;
} nvm_t;

#define NVM_MAGIC 0x4E564D31u

extern nvm_t nvm;
void nvm_load(void);            /* defaults on the first power-on, kept after */

#endif /* NVM_H */

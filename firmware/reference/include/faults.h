/* faults.h: latched faults as a CiA 301 device reports them: error code (EMCY, once per code until
   cleared), error register (0x1001) and the pre-defined error field (0x1003, newest first). */
#ifndef FAULTS_H
#define FAULTS_H

#include <stdint.h>

#define FAULT_HISTORY 8

void faults_power_on(void);
void fault_raise(uint16_t code);
void faults_clear(void);            /* clear_faults: faults, error register and history; EMCY 0x0000 */
void faults_clear_history(void);    /* 0x1003 sub 0 written 0 */
uint8_t faults_error_register(void);
uint8_t faults_history_count(void);
uint32_t faults_history(uint8_t i); /* i = 0 newest */

#endif /* FAULTS_H */

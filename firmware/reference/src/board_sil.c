/* board_sil.c: the port layer on the PC (hil-sil/1). The only file that sees hil_sil_*: the
   interrupts and the object dictionary are handed to the control logic, and what the logic drives
   through board.h is held here for the framework's getters. */
#include "hil_sil.h"
#include "hil_sil_util.h"

#include "board.h"
#include "control.h"
#include "defects.h"
#include "faults.h"
#include "fw_config.h"
#include "nvm.h"
#include "od.h"

#define STR_(x) #x
#define STR(x) STR_(x)
#if HALL_TIMER_BITS == 16
#define TIMER_VARIANT ", 16-bit timer"
#else
#define TIMER_VARIANT ""
#endif
#if defined(DEFECT_NAME)
#define DEFECT_VARIANT ", seeded defect " DEFECT_NAME
#else
#define DEFECT_VARIANT ""
#endif

static uint8_t gates;
static uint16_t duty;
static uint8_t compare_armed;
static uint32_t compare_count;
static hil_emcy_queue emcy; /* the CAN controller's transmit queue */

/* ---- board.h ------------------------------------------------------------------------------- */
void board_set_gates(uint8_t g) { gates = (uint8_t)(g & 0x3Fu); }
void board_set_duty(uint16_t d) { duty = d; }
void board_compare_arm(uint32_t count)
{
    compare_armed = 1u;
    compare_count = count & TIMER_MASK;
}
void board_compare_disarm(void) { compare_armed = 0u; }
void board_emcy_send(uint16_t code)
{
    (void)hil_emcy_push(&emcy, code); /* a full queue loses the frame */
}

/* ---- hil-sil/1 ----------------------------------------------------------------------------- */
void hil_sil_describe(hil_sil_info *info)
{
    info->abi = HIL_SIL_ABI;
    info->name = "bldc-hil reference firmware 1.0 (C)" TIMER_VARIANT DEFECT_VARIANT;
    info->timer_hz = TIMER_HZ;
    info->timer_bits = (uint8_t)HALL_TIMER_BITS;
    info->control_hz = CONTROL_HZ;
    info->amps_per_count = AMPS_PER_COUNT;
    info->pole_pairs = (uint8_t)POLE_PAIRS;
}

void hil_sil_reset(uint8_t levels)
{
    nvm_load();
    gates = 0u;
    duty = 0u;
    compare_armed = 0u;
    hil_emcy_clear(&emcy);
    faults_power_on();
    ctl_power_on(levels);
}

void hil_sil_hall_isr(uint32_t count, uint8_t pin, uint8_t levels, const int16_t adc[3])
{
    ctl_hall_isr(count, pin, levels, adc);
}

void hil_sil_control_isr(uint32_t count, const int16_t adc[3])
{
    ctl_control_isr(count, adc);
}

void hil_sil_compare_isr(uint32_t count)
{
    ctl_compare_isr(count);
}

uint8_t hil_sil_gates(void) { return gates; }
uint16_t hil_sil_duty(void) { return duty; }

int hil_sil_compare(uint32_t *count)
{
    if (!compare_armed) return 0;
    *count = compare_count;
    return 1;
}

int32_t hil_sil_od_read(uint16_t index, uint8_t sub, uint8_t *buf, uint32_t size)
{
    nvm_load();
    return od_read(index, sub, buf, size);
}

int32_t hil_sil_od_write(uint16_t index, uint8_t sub, const uint8_t *buf, uint32_t size)
{
    nvm_load();
    return od_write(index, sub, buf, size);
}

int hil_sil_emcy(uint16_t *code)
{
    return hil_emcy_pop(&emcy, code);
}

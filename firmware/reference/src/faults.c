/* faults.c: fault latch, error register, history and EMCY (hil/controller/virtual.py raise_fault). */
#include "faults.h"
#include "board.h"
#include "fw_config.h"
#include "defects.h"
#include "hil_sil_util.h"

#define MAX_LATCHED 8

static uint16_t latched[MAX_LATCHED];
static uint8_t n_latched;
static uint8_t error_register;
static uint32_t history[FAULT_HISTORY];
static uint8_t n_history;

void faults_power_on(void)
{
    n_latched = 0u;
    error_register = 0u;
    n_history = 0u;
}

void fault_raise(uint16_t code)
{
    uint8_t i;
#if defined(HIL_DEFECT_NO_MISSING_EDGE_FAULT)
    if (code == FAULT_MISSING_EDGE) return;
#endif
    for (i = 0u; i < n_latched; i++)
        if (latched[i] == code) return; /* reported once per code until the faults are cleared */
    if (n_latched < MAX_LATCHED) latched[n_latched++] = code;
    error_register |= HIL_ERR_REG_GENERIC | HIL_ERR_REG_MANUFACTURER;
    for (i = (uint8_t)(FAULT_HISTORY - 1u); i > 0u; i--) history[i] = history[i - 1u];
    history[0] = code;
    if (n_history < FAULT_HISTORY) n_history++;
    board_emcy_send(code);
}

void faults_clear(void)
{
    n_latched = 0u;
    error_register = 0u;
    n_history = 0u;
    board_emcy_send(0x0000u);
}

void faults_clear_history(void)
{
    n_history = 0u;
}

uint8_t faults_error_register(void)
{
    return error_register;
}

uint8_t faults_history_count(void)
{
    return n_history;
}

uint32_t faults_history(uint8_t i)
{
    return i < n_history ? history[i] : 0u;
}

/* nvm.c: the non-volatile configuration. On a chip nvm_load reads it from flash; here it is a
   static the power cycle (hil_sil_reset) does not clear. */
#include "nvm.h"

nvm_t nvm;

void nvm_load(void)
{
    if (nvm.magic == NVM_MAGIC) return;
    nvm.magic = NVM_MAGIC;
    nvm.strategy = STRATEGY_SAGE_HUSA;
    nvm.speed_setpoint_rpm = SPEED_SETPOINT_DEFAULT_RPM;
    cal_zero(&nvm.staged);
    cal_zero(&nvm.applied);
    nvm.sage_husa = FILTER_SH_DEFAULT;
    nvm.heartbeat_ms = 100u;
}

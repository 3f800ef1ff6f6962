/* od.h: the object dictionary (CiA 301 semantics), the map of hil/dut/profiles/virtual-canopen.toml
   plus the CiA 301 objects and the clear-faults action 0x2002. */
#ifndef OD_H
#define OD_H

#include <stdint.h>

#include "hil_sil_util.h"

/* the CiA 301 abort codes of hil_sil_util.h, by this firmware's short names */
#define SDO_NO_OBJECT HIL_SDO_NO_OBJECT
#define SDO_NO_SUBINDEX HIL_SDO_NO_SUBINDEX
#define SDO_READ_ONLY HIL_SDO_READ_ONLY
#define SDO_WRITE_ONLY HIL_SDO_WRITE_ONLY
#define SDO_LENGTH HIL_SDO_LENGTH
#define SDO_RANGE HIL_SDO_VALUE_INVALID

int32_t od_read(uint16_t index, uint8_t sub, uint8_t *buf, uint32_t size);
int32_t od_write(uint16_t index, uint8_t sub, const uint8_t *buf, uint32_t size);

#endif /* OD_H */

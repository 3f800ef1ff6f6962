/* od.h: the object dictionary (CiA 301 semantics), the map of hil/dut/profiles/virtual-canopen.toml
   plus the CiA 301 objects and the clear-faults action 0x2002. */
#ifndef OD_H
#define OD_H

#include <stdint.h>

#define SDO_NO_OBJECT 0x06020000L
#define SDO_NO_SUBINDEX 0x06090011L
#define SDO_READ_ONLY 0x06010002L
#define SDO_WRITE_ONLY 0x06010001L
#define SDO_LENGTH 0x06070010L
#define SDO_RANGE 0x06090030L

int32_t od_read(uint16_t index, uint8_t sub, uint8_t *buf, uint32_t size);
int32_t od_write(uint16_t index, uint8_t sub, const uint8_t *buf, uint32_t size);

#endif /* OD_H */

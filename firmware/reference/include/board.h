/* board.h: the port layer. The control logic calls only these to reach hardware; on a chip they
   write the timer's output-compare, the gate driver's outputs and the CAN controller. On SIL
   (board_sil.c) they hold what the hil_sil_* getters report. */
#ifndef BOARD_H
#define BOARD_H

#include <stdint.h>

void board_set_gates(uint8_t gates);     /* bit 0 AH, 1 AL, 2 BH, 3 BL, 4 CH, 5 CL */
void board_set_duty(uint16_t duty);      /* high-side PWM duty, 0..65535 */
void board_compare_arm(uint32_t count);  /* the compare fires when the counter next equals count */
void board_compare_disarm(void);
void board_emcy_send(uint16_t code);     /* queue one EMCY frame (0x0000: error reset) */

#endif /* BOARD_H */

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

/* Interrupts off for a few lines, around what interrupts of different priorities share (the
   command queue and the compare unit, the time base, the ADC ring, the cycle accumulators): on the
   part the compare and control interrupts preempt the Hall interrupt (and compare preempts control),
   so an update one of them makes part-way through another's is a data race. PRIMASK is saved and
   restored, so sections nest. A PC build (sil:) runs its interrupts one at a time: nothing to do. */
static inline uint32_t board_irq_lock(void)
{
#if defined(__ARM_ARCH)
    uint32_t primask;
    __asm volatile("mrs %0, primask\n\tcpsid i" : "=r"(primask) : : "memory");
    return primask;
#else
    return 0u;
#endif
}

static inline void board_irq_unlock(uint32_t primask)
{
#if defined(__ARM_ARCH)
    __asm volatile("msr primask, %0" : : "r"(primask) : "memory");
#else
    (void)primask;
#endif
}

#endif /* BOARD_H */

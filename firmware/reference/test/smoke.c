/* smoke.c: a standalone check of the reference firmware without the framework: the interface's
   description, the object dictionary's CiA 301 answers, a refused table, and six-step commutation
   on an ideal Hall sequence through a counter wrap (raw and sage_husa: the compare unit).

   cc -std=c99 -I ../../hil/sil/include -I include src/[a-z]*.c test/smoke.c -lm -o /tmp/smoke && /tmp/smoke
   (from firmware/reference; add -DHALL_TIMER_BITS=16 for the 16-bit build) */
#include <stdio.h>
#include <string.h>

#include "hil_sil.h"
#include "fw_config.h"

static int failures;
#define CHECK(cond, what) do { if (!(cond)) { printf("FAIL %s\n", what); failures++; } } while (0)

static const uint8_t SECTOR_GATES[6] = {
    HIL_SIL_CH | HIL_SIL_AL, HIL_SIL_CH | HIL_SIL_BL, HIL_SIL_AH | HIL_SIL_BL,
    HIL_SIL_AH | HIL_SIL_CL, HIL_SIL_BH | HIL_SIL_CL, HIL_SIL_BH | HIL_SIL_AL};
/* levels (bit 0 A, 1 B, 2 C) in sector s: A high in 0..2, B in 2..4, C in 4..5 and 0 */
static const uint8_t SECTOR_LEVELS[6] = {0x5, 0x1, 0x3, 0x2, 0x6, 0x4};

static int32_t wr_u8(uint16_t i, uint8_t s, uint8_t v) { return hil_sil_od_write(i, s, &v, 1); }

static int32_t wr_f32(uint16_t i, uint8_t s, float v)
{
    uint8_t b[4];
    uint32_t u;
    memcpy(&u, &v, 4);
    b[0] = (uint8_t)u; b[1] = (uint8_t)(u >> 8); b[2] = (uint8_t)(u >> 16); b[3] = (uint8_t)(u >> 24);
    return hil_sil_od_write(i, s, b, 4);
}

/* an ideal rotor at constant speed: an edge every sector_ticks; returns commutations seen */
static int spin(uint32_t start, uint32_t sector_ticks, int edges, int *late)
{
    uint32_t t = start, next_ctl = start, armed = 0;
    int s = 0, k, commutations = 0, have_arm = 0;
    int16_t adc[3] = {100, -100, 0};
    hil_sil_reset(SECTOR_LEVELS[0]);
    CHECK(hil_sil_gates() == SECTOR_GATES[0], "gates from the reset levels");
    *late = 0;
    for (k = 1; k <= edges; k++) {
        uint32_t edge_t = start + (uint32_t)k * sector_ticks;
        int nxt = (s + 1) % 6;
        uint8_t changed = (uint8_t)(SECTOR_LEVELS[s] ^ SECTOR_LEVELS[nxt]);
        uint8_t pin = changed == 1 ? 0 : (changed == 2 ? 1 : 2);
        while ((uint32_t)(edge_t - next_ctl) < 0x80000000u) { /* control interrupts, compares before the edge */
            t = next_ctl;
            if (have_arm && (uint32_t)(armed - (t & TIMER_MASK)) <= (uint32_t)(TIMER_HZ / CONTROL_HZ) &&
                (uint32_t)((armed - t) & TIMER_MASK) < (uint32_t)(TIMER_HZ / CONTROL_HZ)) {
                hil_sil_compare_isr(armed);
                if (hil_sil_gates() == SECTOR_GATES[nxt]) commutations++;
            }
            hil_sil_control_isr(t & TIMER_MASK, adc);
            have_arm = hil_sil_compare(&armed);
            next_ctl += TIMER_HZ / CONTROL_HZ;
        }
        hil_sil_hall_isr(edge_t & TIMER_MASK, pin, SECTOR_LEVELS[nxt], adc);
        have_arm = hil_sil_compare(&armed);
        if (hil_sil_gates() != SECTOR_GATES[nxt]) (*late)++;
        s = nxt;
    }
    return commutations;
}

int main(void)
{
    hil_sil_info info;
    uint8_t buf[16];
    uint16_t code;
    int late, n;
    uint32_t start = (uint32_t)(TIMER_MASK - (uint32_t)(TIMER_HZ / 100u) + 1u); /* wraps after 10 ms */

    hil_sil_describe(&info);
    CHECK(info.abi == 1 && info.pole_pairs == POLE_PAIRS && info.timer_bits == HALL_TIMER_BITS, "describe");
    printf("%s: %u Hz x %u bit\n", info.name, (unsigned)info.timer_hz, (unsigned)info.timer_bits);
    hil_sil_reset(0x1);
    CHECK(hil_sil_od_read(0x1018, 1, buf, 4) == 4 && buf[0] == 0x1D && buf[1] == 0x0B, "0x1018:1 vendor");
    CHECK(hil_sil_od_read(0x2000, 0, buf, 1) == 1 && buf[0] == 3, "strategy default sage_husa");
    CHECK(hil_sil_od_read(0x3000, 0, buf, 4) == -0x06020000, "no object");
    CHECK(hil_sil_od_read(0x2010, 42, buf, 4) == -0x06090011, "no sub-index");
    CHECK(hil_sil_od_read(0x2011, 0, buf, 1) == -0x06010001, "write-only");
    CHECK(wr_u8(0x1001, 0, 1) == -0x06010002, "read-only");
    CHECK(hil_sil_od_write(0x2001, 0, buf, 2) == -0x06070010, "length");
    CHECK(wr_u8(0x2000, 0, 9) == -0x06090030, "strategy range");
    CHECK(wr_f32(0x2010, 4, 25.0f) == 0, "stage a pole offset beyond its bound");
    CHECK(wr_u8(0x2011, 0, 1) == -0x06090030, "apply refused");
    CHECK(hil_sil_emcy(&code) == 1 && code == 0xFF04, "EMCY 0xFF04");
    CHECK(hil_sil_od_read(0x1001, 0, buf, 1) == 1 && buf[0] == 0x81, "error register");
    CHECK(hil_sil_od_read(0x1003, 1, buf, 4) == 4 && buf[0] == 0x04 && buf[1] == 0xFF, "0x1003:1");
    CHECK(wr_u8(0x2002, 0, 1) == 0 && hil_sil_emcy(&code) == 1 && code == 0, "clear faults, EMCY 0x0000");
    CHECK(wr_f32(0x2010, 4, 0.0f) == 0 && wr_u8(0x2011, 0, 1) == 0, "apply a valid table");

    CHECK(wr_u8(0x2000, 0, 0) == 0, "strategy raw");
    n = spin(start, 6250u * (TIMER_HZ / 10000000u), 600, &late);
    CHECK(late == 0, "raw: every edge commutates at once");
    printf("raw: %d edges late\n", late);
    CHECK(wr_u8(0x2000, 0, 3) == 0, "strategy sage_husa");
    n = spin(start, 6250u * (TIMER_HZ / 10000000u), 600, &late);
    printf("sage_husa: %d commutations on the compare unit, %d edges before their commutation\n", n, late);
    CHECK(n > 500, "sage_husa: commutations from the compare unit");
    CHECK(hil_sil_emcy(&code) == 0, "no fault on an ideal rotor");
    printf(failures ? "%d FAILED\n" : "ok\n", failures);
    return failures != 0;
}

/* defects.h: seeded defects of the reference firmware, each a compile-time switch
   (-D HIL_DEFECT_<NAME>, e.g. defines = { HIL_DEFECT_TIMER_WRAP = "" } in a sil.toml). None is
   on by default. The first group ports the Python catalogue (hil/qualify/defects.py, same names
   in upper case); the second are firmware-only bugs. defects.toml says which requirement should
   catch each. One line each:

   HIL_DEFECT_POLE_TABLE_ONE_POLE_OFF        pole offsets applied one magnet pole late (index off by one)
   HIL_DEFECT_RISE_FALL_DELAYS_SWAPPED       rising edges corrected with the falling delay and vice versa
   HIL_DEFECT_INSTALLATION_ON_WRONG_SENSOR   A's installation offset applied to B, B's to C, C's to A
   HIL_DEFECT_ARMATURE_SIGN_INVERTED         armature-reaction correction applied with the wrong sign
   HIL_DEFECT_DELAY_APPLIED_AT_90_PERCENT    conditioning delays applied at 90 % (a prescaler rounded)
   HIL_DEFECT_TABLE_NEVER_APPLIED            table accepted and read back, commutation runs on an empty one
   HIL_DEFECT_CURRENT_SAMPLED_AT_CAPTURE     edge current read at the capture, not one delay before it
   HIL_DEFECT_PREDICTOR_FED_MILLIAMPERES     the predictor's current input in mA where Eq. 8 wants A
   HIL_DEFECT_PREDICTOR_CURRENT_SIGNED_SUM   the predictor's cycle current |a + b + c| (about 0 A), not |a| + |b| + |c|
   HIL_DEFECT_GATE_LATENCY_5US               5 us of gate-driver latency not compensated
   HIL_DEFECT_GATE_LATENCY_25US              25 us of gate-driver latency not compensated
   HIL_DEFECT_SAGE_HUSA_RUNS_KF              the Sage-Husa strategy runs the fixed-noise Kalman filter
   HIL_DEFECT_SAGE_HUSA_WITHOUT_ADAPTATION   Sage-Husa with its noise adaptation (Eq. 12) switched off
   HIL_DEFECT_NO_MISSING_EDGE_FAULT          a lost edge is handled but never reported (no 0xFF02)
   HIL_DEFECT_NO_TABLE_VALIDATION            a calibration table is applied without any check
   HIL_DEFECT_CURRENT_LIMIT_NOT_ENFORCED     the speed loop's duty clamped to 0..1 only, no current limit
   HIL_DEFECT_NEVER_RESYNCHRONISES           after lost edges the edge count / pole table never resynchronised
   HIL_DEFECT_LOST_EDGE_AGAINST_LAST_SECTOR  a lost edge told from the last sector's interval (x1.8)
   HIL_DEFECT_SAGE_HUSA_NOISE_WITHOUT_MEMORY R and Q forgetting factors 1e-3, R interval 2, Q interval 1
   HIL_DEFECT_SAGE_HUSA_R_FROZEN             R_theta set once (its first estimate), later updates dropped
   HIL_DEFECT_SAGE_HUSA_R_UPDATE_WRONG_SIGN  R_theta's update step subtracted (floored at 0)
   HIL_DEFECT_SAGE_HUSA_R_UPDATE_WRONG_SCALE R_theta stored at a quarter of each update (fixed point 2 bits off)

   HIL_DEFECT_TIMER_WRAP      intervals from a signed difference of raw counts: wrong across a counter wrap
   HIL_DEFECT_FLOAT_SECONDS   time kept as float32 seconds since the timer started: resolution lost as it runs
   HIL_DEFECT_LATE_COMPARE    a commutation already due is armed on the compare (fires a wrap late), not made now
   HIL_DEFECT_TORN_TABLE      apply hands the table to the 1 kHz background task, which copies one value per tick into
                              the table the ISRs read (torn reads for 10 ms)

   The third group passes on a PC (sil:) and shows only on the part (pil:; defects.toml's kinds = ["pil"]):
   HIL_DEFECT_TIME_PRODUCT_OVERFLOW   the conditioning delay to ticks as unsigned long ns x TIMER_HZ: wraps at 32 bits
   HIL_DEFECT_DOUBLE_IN_CONTROL_ISR   a double-precision low pass (exp of the measured interval every period) in the
                                      20 kHz control interrupt
   HIL_DEFECT_STACK_HUNGRY_ISR        a 4.4 kB local buffer in the Hall interrupt
   HIL_DEFECT_UNALIGNED_64BIT_ACCESS  the capture time stored through an int64_t pointer one byte into a record (STRD)
*/
#ifndef DEFECTS_H
#define DEFECTS_H

#if defined(HIL_DEFECT_GATE_LATENCY_25US)
#define DEFECT_GATE_LATENCY_TICKS ((uint64_t)(25e-6 * TIMER_HZ + 0.5))
#elif defined(HIL_DEFECT_GATE_LATENCY_5US)
#define DEFECT_GATE_LATENCY_TICKS ((uint64_t)(5e-6 * TIMER_HZ + 0.5))
#else
#define DEFECT_GATE_LATENCY_TICKS 0u
#endif

/* the variant named by hil_sil_describe */
#if defined(HIL_DEFECT_POLE_TABLE_ONE_POLE_OFF)
#define DEFECT_NAME "pole-table-one-pole-off"
#elif defined(HIL_DEFECT_RISE_FALL_DELAYS_SWAPPED)
#define DEFECT_NAME "rise-fall-delays-swapped"
#elif defined(HIL_DEFECT_INSTALLATION_ON_WRONG_SENSOR)
#define DEFECT_NAME "installation-on-wrong-sensor"
#elif defined(HIL_DEFECT_ARMATURE_SIGN_INVERTED)
#define DEFECT_NAME "armature-sign-inverted"
#elif defined(HIL_DEFECT_DELAY_APPLIED_AT_90_PERCENT)
#define DEFECT_NAME "delay-applied-at-90-percent"
#elif defined(HIL_DEFECT_TABLE_NEVER_APPLIED)
#define DEFECT_NAME "table-never-applied"
#elif defined(HIL_DEFECT_CURRENT_SAMPLED_AT_CAPTURE)
#define DEFECT_NAME "current-sampled-at-capture"
#elif defined(HIL_DEFECT_PREDICTOR_FED_MILLIAMPERES)
#define DEFECT_NAME "predictor-fed-milliamperes"
#elif defined(HIL_DEFECT_PREDICTOR_CURRENT_SIGNED_SUM)
#define DEFECT_NAME "predictor-current-signed-sum"
#elif defined(HIL_DEFECT_GATE_LATENCY_25US)
#define DEFECT_NAME "gate-latency-25us"
#elif defined(HIL_DEFECT_GATE_LATENCY_5US)
#define DEFECT_NAME "gate-latency-5us"
#elif defined(HIL_DEFECT_SAGE_HUSA_RUNS_KF)
#define DEFECT_NAME "sage-husa-runs-kf"
#elif defined(HIL_DEFECT_SAGE_HUSA_WITHOUT_ADAPTATION)
#define DEFECT_NAME "sage-husa-without-adaptation"
#elif defined(HIL_DEFECT_NO_MISSING_EDGE_FAULT)
#define DEFECT_NAME "no-missing-edge-fault"
#elif defined(HIL_DEFECT_NO_TABLE_VALIDATION)
#define DEFECT_NAME "no-table-validation"
#elif defined(HIL_DEFECT_CURRENT_LIMIT_NOT_ENFORCED)
#define DEFECT_NAME "current-limit-not-enforced"
#elif defined(HIL_DEFECT_NEVER_RESYNCHRONISES)
#define DEFECT_NAME "never-resynchronises"
#elif defined(HIL_DEFECT_LOST_EDGE_AGAINST_LAST_SECTOR)
#define DEFECT_NAME "lost-edge-against-last-sector"
#elif defined(HIL_DEFECT_SAGE_HUSA_NOISE_WITHOUT_MEMORY)
#define DEFECT_NAME "sage-husa-noise-without-memory"
#elif defined(HIL_DEFECT_SAGE_HUSA_R_FROZEN)
#define DEFECT_NAME "sage-husa-r-frozen"
#elif defined(HIL_DEFECT_SAGE_HUSA_R_UPDATE_WRONG_SIGN)
#define DEFECT_NAME "sage-husa-r-update-wrong-sign"
#elif defined(HIL_DEFECT_SAGE_HUSA_R_UPDATE_WRONG_SCALE)
#define DEFECT_NAME "sage-husa-r-update-wrong-scale"
#elif defined(HIL_DEFECT_TIMER_WRAP)
#define DEFECT_NAME "timer-wrap"
#elif defined(HIL_DEFECT_FLOAT_SECONDS)
#define DEFECT_NAME "float-seconds"
#elif defined(HIL_DEFECT_LATE_COMPARE)
#define DEFECT_NAME "late-compare"
#elif defined(HIL_DEFECT_TORN_TABLE)
#define DEFECT_NAME "torn-table"
#elif defined(HIL_DEFECT_TIME_PRODUCT_OVERFLOW)
#define DEFECT_NAME "time-product-overflow"
#elif defined(HIL_DEFECT_DOUBLE_IN_CONTROL_ISR)
#define DEFECT_NAME "double-in-control-isr"
#elif defined(HIL_DEFECT_STACK_HUNGRY_ISR)
#define DEFECT_NAME "stack-hungry-isr"
#elif defined(HIL_DEFECT_UNALIGNED_64BIT_ACCESS)
#define DEFECT_NAME "unaligned-64bit-access"
#endif

#endif /* DEFECTS_H */

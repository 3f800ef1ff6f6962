// The board under SimpleFOC's Hall sensor on the firmware-in-the-loop interface: the Hall pins,
// the interrupts Arduino's attachInterrupt() hooks onto them, and the microsecond clock micros()
// reads. Arduino.h (the shim SimpleFOC's sources include) declares the Arduino side of it.
#ifndef SIMPLEFOC_HALL_SIL_BOARD_H
#define SIMPLEFOC_HALL_SIL_BOARD_H

#include <cstdint>

namespace sil_board {

// a 32-bit capture timer at 1 MHz: one count is one of Arduino's microseconds
constexpr uint32_t kTimerHz = 1000000u;
constexpr uint8_t kTimerBits = 32;
constexpr uint8_t kHallPins = 3;

// a power-on reset: pins as the GPIO reads them, no interrupt attached, the clock at zero
void power_on(uint8_t levels);
// the counter an interrupt received: from here on micros() reads this instant
void clock_at(uint32_t count);
// the Hall pin `pin` changed (levels: bit 0 A, 1 B, 2 C): what attachInterrupt() hooked to it runs
void pin_changed(uint8_t pin, uint8_t levels);

}  // namespace sil_board

#endif

// The Arduino functions SimpleFOC's Hall sensor calls, on the firmware-in-the-loop peripherals.
#include "sil_board.h"

#include <array>
#include <cstdlib>

#include "Arduino.h"

namespace {

struct Board {
  uint8_t levels = 0;
  std::array<void (*)(), sil_board::kHallPins> on_change{};
  bool clock_started = false;
  uint32_t last_count = 0;
  unsigned long micros_since_power_on = 0;  // 64 bits on the PC: it does not wrap in any run
} board;

}  // namespace

namespace sil_board {

void power_on(uint8_t levels) {
  board = Board{};
  board.levels = levels;
}

void clock_at(uint32_t count) {
  // the first interrupt after power-on is the clock's zero (hil_sil_reset carries no count); every
  // later one advances it by the counter's difference modulo 2^32, however often the counter wraps
  // between power-on and now, since the control interrupt comes far more often than once a wrap
  if (board.clock_started) board.micros_since_power_on += static_cast<uint32_t>(count - board.last_count);
  board.clock_started = true;
  board.last_count = count;
}

void pin_changed(uint8_t pin, uint8_t levels) {
  board.levels = levels;
  if (pin < kHallPins && board.on_change[pin] != nullptr) board.on_change[pin]();
}

}  // namespace sil_board

static_assert(sil_board::kTimerHz == 1000000u, "micros() is the count: one count must be one microsecond");
static_assert(sil_board::kTimerBits == 32, "clock_at() takes the interval modulo 2^32");

int digitalRead(uint8_t pin) { return pin < sil_board::kHallPins ? (board.levels >> pin) & 1 : LOW; }

void pinMode(uint8_t, uint8_t) {}  // the Hall inputs are inputs already; their pull-ups are the plant's

void attachInterrupt(uint8_t interrupt, void (*handler)(void), int mode) {
  // the capture channels interrupt on either edge: CHANGE is the only mode they implement
  if (interrupt >= sil_board::kHallPins || mode != CHANGE) std::abort();
  board.on_change[interrupt] = handler;
}

unsigned long micros() { return board.micros_since_power_on; }

void delay(unsigned long) { std::abort(); }
void delayMicroseconds(unsigned int) { std::abort(); }

// Arduino.h for SimpleFOC's Hall sensor on the PC: the few Arduino core functions its sources
// (fetched by sil.toml's [fetch], never copied here) need, provided by the firmware-in-the-loop
// port (sil_board.cc), so that none of them is edited. The pins are the Hall capture channels
// (0 A, 1 B, 2 C); micros() is the SIL capture timer's count at the running interrupt, in
// microseconds since power-on.
#ifndef SIMPLEFOC_HALL_SIL_ARDUINO_H
#define SIMPLEFOC_HALL_SIL_ARDUINO_H

#include <math.h>    // fabsf, fmod; with stdlib.h the float overload of abs() Sensor.cpp calls
#include <stdint.h>
#include <stdlib.h>

#define LOW 0x0
#define HIGH 0x1
#define INPUT 0x0
#define OUTPUT 0x1
#define INPUT_PULLUP 0x2
#define CHANGE 0x1
#define digitalPinToInterrupt(pin) (pin)

int digitalRead(uint8_t pin);
void pinMode(uint8_t pin, uint8_t mode);
void attachInterrupt(uint8_t interrupt, void (*handler)(void), int mode);
// every interrupt of a firmware in the loop runs to completion and none nests: masking them is
// a no-op, as it is on a single-core MCU between two of its interrupts
inline void noInterrupts() {}
inline void interrupts() {}
// unsigned long is 64 bits on the PC (LP64), 32 on the MCUs SimpleFOC targets: a 32-bit count
// here would make SimpleFOC's `long` interval arithmetic see every wrap as a negative interval,
// so the port extends the capture count to 64 bits (sil_board.cc)
unsigned long micros();
// a blocking wait cannot pass simulated time inside an interrupt that runs in zero time; nothing
// the port calls reaches these (Sensor::init and _delay only), and they abort if anything does
void delay(unsigned long ms);
void delayMicroseconds(unsigned int us);

// Arduino's min/max, as templates rather than its macros so that the C++ headers stay usable
template <typename T> constexpr T min(T a, T b) { return b < a ? b : a; }
template <typename T> constexpr T max(T a, T b) { return a < b ? b : a; }

#endif

// Six-step commutation on the raw Hall state with a speed PI: a foreign firmware for the
// framework's tests of hil-sil/1 (C++17; no calibration, no prediction).
#include <cstdint>
#include <cstring>
#include <array>
#include "hil_sil.h"

namespace {

#ifndef SIXSTEP_TIMER_BITS
#define SIXSTEP_TIMER_BITS 32
#endif
constexpr uint32_t kTimerHz = SIXSTEP_TIMER_BITS == 16 ? 1000000u : 10000000u;
constexpr uint32_t kMask = SIXSTEP_TIMER_BITS == 16 ? 0xFFFFu : 0xFFFFFFFFu;
constexpr uint32_t kControlHz = 20000u;
constexpr uint8_t kPolePairs = 2;
// sector of the Hall code A<<2 | B<<1 | C, and the phases each sector drives (high, low)
constexpr std::array<int, 8> kSectorOfCode{-1, 5, 3, 4, 1, 0, 2, -1};
constexpr std::array<int, 6> kHigh{2, 2, 0, 0, 1, 1};
constexpr std::array<int, 6> kLow{0, 1, 1, 2, 2, 0};

struct Nvm { float setpoint_rpm = 5000.0f; } nvm;  // survives hil_sil_reset
struct Ram {
  uint8_t gates = 0;
  float duty = 0.0f, integral = 0.0f, speed_rpm = 0.0f;
  uint32_t last_edge = 0, edges = 0, ticks_since_edge = 0, sector_ticks = 0;
  int hall_sector = 0;
  uint32_t faults[4] = {0, 0, 0, 0};
  uint8_t fault_count = 0, error_register = 0;
  uint16_t emcy[8] = {0};
  uint8_t emcy_n = 0;
  uint32_t isr_calls = 0;
} ram;

uint8_t gates_of(int sector) {
  if (sector < 0) return 0;
  return static_cast<uint8_t>((1u << (2 * kHigh[sector])) | (2u << (2 * kLow[sector])));
}
int sector_of_levels(uint8_t levels) {
  int code = ((levels & 1) << 2) | (levels & 2) | ((levels >> 2) & 1);
  return kSectorOfCode[code];
}
void fault(uint16_t code) {
  for (int k = 0; k < ram.fault_count; ++k) if (ram.faults[k] == code) return;
  for (int k = 3; k > 0; --k) ram.faults[k] = ram.faults[k - 1];
  ram.faults[0] = code;
  if (ram.fault_count < 4) ++ram.fault_count;
  ram.error_register |= 0x81;
  if (ram.emcy_n < 8) ram.emcy[ram.emcy_n++] = code;
}
void commutate(uint8_t levels) {
  int s = sector_of_levels(levels);
  if (s < 0) { fault(0x3101); return; }
  ram.hall_sector = s;
#ifdef SIXSTEP_ESTIMATED_ANGLE
  if (ram.edges > 6) return;  // running: the control interrupt switches the gates from the estimate
#endif
  ram.gates = gates_of(s);
#ifdef SIXSTEP_SHOOT_THROUGH
  if (ram.edges == 200) ram.gates |= 0x03;  // both switches of leg A
#endif
}
template <typename T> int32_t put(uint8_t* buf, uint32_t size, T v) {
  if (size < sizeof(T)) return -0x06070010;
  std::memcpy(buf, &v, sizeof(T));
  return sizeof(T);
}
}  // namespace

extern "C" {
HIL_SIL_EXPORT void hil_sil_describe(hil_sil_info* info) {
#ifdef SIXSTEP_WRONG_ABI
  info->abi = 2;
#else
  info->abi = HIL_SIL_ABI;
#endif
  info->name = "six-step test firmware 0.1 (C++)";
  info->timer_hz = kTimerHz;
  info->timer_bits = SIXSTEP_TIMER_BITS;
  info->control_hz = kControlHz;
  info->amps_per_count = 0.01f;
  info->pole_pairs = kPolePairs;
}
HIL_SIL_EXPORT void hil_sil_reset(uint8_t levels) {
  ram = Ram{};
  ram.duty = nvm.setpoint_rpm * (0.342f / 6000.0f);
  ram.integral = 0.0f;
  commutate(levels);
}
HIL_SIL_EXPORT void hil_sil_hall_isr(uint32_t count, uint8_t pin, uint8_t levels, const int16_t adc[3]) {
  (void)pin; (void)adc;
#ifdef SIXSTEP_HANG
  if (ram.edges == 300) for (volatile int spin = 1; spin;) {}
#endif
  uint32_t dt = (count - ram.last_edge) & kMask;
  ram.sector_ticks = dt;
  if (ram.edges > 0 && dt > 0) {
    float sector_s = static_cast<float>(dt) / kTimerHz;
    ram.speed_rpm = 60.0f / (6.0f * kPolePairs * sector_s);
  }
  ram.last_edge = count;
  ram.ticks_since_edge = 0;
  ++ram.edges;
  commutate(levels);
}
HIL_SIL_EXPORT void hil_sil_control_isr(uint32_t count, const int16_t adc[3]) {
  (void)adc;
  ++ram.isr_calls;
#ifdef SIXSTEP_ESTIMATED_ANGLE
  // a FOC-style firmware: the rotor angle estimated at every PWM interrupt from the last Hall
  // edge's sector boundary and the last sector's duration; the gates switch when the estimate
  // crosses into the next sector (never ahead of the Hall state by more than that one sector)
  if (ram.edges > 6 && ram.sector_ticks > 0) {
    uint32_t since = (count - ram.last_edge) & kMask;
    float advance = 60.0f * static_cast<float>(since) / static_cast<float>(ram.sector_ticks);
    int s = ram.hall_sector + (advance >= 60.0f ? 1 : 0);
    ram.gates = gates_of(s % 6);
  }
#endif
#ifdef SIXSTEP_CRASH
  if (ram.isr_calls == 5000) { volatile int* null = nullptr; *null = 1; }
#endif
  if (++ram.ticks_since_edge > kControlHz / 10) ram.speed_rpm = 0.0f;  // no edge for 100 ms: stopped
  if (ram.edges < 6) return;
  float error = nvm.setpoint_rpm - ram.speed_rpm;
  ram.integral += error * (2e-3f / kControlHz);
  float duty = nvm.setpoint_rpm * (0.342f / 6000.0f) + 1e-4f * error + ram.integral;
  ram.duty = duty < 0.0f ? 0.0f : (duty > 0.95f ? 0.95f : duty);
}
#ifndef SIXSTEP_MISSING_EXPORT
HIL_SIL_EXPORT uint8_t hil_sil_gates(void) { return ram.gates; }
#endif
HIL_SIL_EXPORT uint16_t hil_sil_duty(void) { return static_cast<uint16_t>(ram.duty * 65535.0f); }
HIL_SIL_EXPORT int hil_sil_emcy(uint16_t* code) {
  if (ram.emcy_n == 0) return 0;
  *code = ram.emcy[0];
  for (int k = 1; k < ram.emcy_n; ++k) ram.emcy[k - 1] = ram.emcy[k];
  --ram.emcy_n;
  return 1;
}
HIL_SIL_EXPORT int32_t hil_sil_od_read(uint16_t index, uint8_t sub, uint8_t* buf, uint32_t size) {
  switch (index) {
    case 0x1001: return sub ? -0x06090011 : put<uint8_t>(buf, size, ram.error_register);
    case 0x1003:
      if (sub == 0) return put<uint8_t>(buf, size, ram.fault_count);
      if (sub <= 4) return put<uint32_t>(buf, size, ram.faults[sub - 1]);
      return -0x06090011;
    case 0x1018:
      if (sub == 0) return put<uint8_t>(buf, size, 4);
      return sub <= 4 ? put<uint32_t>(buf, size, sub == 1 ? 0x5EC0DEu : sub) : -0x06090011;
    case 0x2200: return sub ? -0x06090011 : put<float>(buf, size, nvm.setpoint_rpm);
    case 0x2201: return sub ? -0x06090011 : put<int32_t>(buf, size, static_cast<int32_t>(ram.speed_rpm));
    default: return -0x06020000;
  }
}
HIL_SIL_EXPORT int32_t hil_sil_od_write(uint16_t index, uint8_t sub, const uint8_t* buf, uint32_t size) {
  if (index == 0x2200 && sub == 0) {
    if (size != 4) return -0x06070010;
    float v;
    std::memcpy(&v, buf, 4);
    if (!(v >= 0.0f && v <= 20000.0f)) return -0x06090030;
    nvm.setpoint_rpm = v;
    return 0;
  }
  if (index == 0x2201 || index == 0x1018 || index == 0x1001 || index == 0x1003) return -0x06010002;
  return -0x06020000;
}
}  // extern "C"

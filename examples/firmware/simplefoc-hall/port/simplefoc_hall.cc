// SimpleFOC's HallSensor in the loop (hil-sil/1): its Hall interrupts fed from the capture
// channels, six-step commutation from the electrical angle it reports, a speed PI on the duty
// from the velocity it reports. The estimator is SimpleFOC's, unmodified and fetched, never copied
// here (sil.toml's [fetch]); what is here is what a SimpleFOC user writes around it (the motor's
// zero electric angle, the drive, the speed loop) plus the object dictionary the framework reaches
// it through.
#include <cmath>
#include <cstdint>
#include <cstring>
#include <new>

#include "hil_sil.h"
#include "hil_sil_util.h"
#include "sil_board.h"
#include "sensors/HallSensor.h"  // SimpleFOC's src/, on the include path by sil.toml's [fetch]

namespace {

constexpr uint32_t kControlHz = 20000u;
constexpr uint8_t kPolePairs = 2;
// SimpleFOC numbers the sector of Hall code 001 zero (HallSensor.h: ELECTRIC_SECTORS); the drive
// below numbers sectors from the rotor angle where code 101 begins. The offset between the two is
// what SimpleFOC's BLDCMotor keeps as zero_electric_angle (five sectors, 300 deg e, here), given
// by the user as the motor's wiring fixes it: nothing here measures or corrects the sensors'
// placement.
constexpr int kZeroElectricSectors = 5;
constexpr uint16_t kIllegalHallCode = 0x3101;
constexpr float kRadPerSToRpm = 60.0f / _2PI;
constexpr float kDutyPerRpm = 0.342f / 6000.0f;  // the plant motor's duty at no load, per rpm
constexpr float kSpeedKp = 1e-4f, kSpeedKi = 2e-3f, kDutyMax = 0.95f;
constexpr int kFaultSlots = 4;
constexpr long kEdgesBeforeSpeedLoop = 6;
constexpr float kVelocityLpfTf_s = 0.005f;  // SimpleFOC's DEF_VEL_FILTER_Tf
constexpr float kVelocityLpfAlpha = kVelocityLpfTf_s / (kVelocityLpfTf_s + 1.0f / kControlHz);

struct Nvm { float setpoint_rpm = 5000.0f; } nvm;  // survives hil_sil_reset
struct Ram {
  uint8_t gates = 0;
  float duty = 0.0f, integral = 0.0f, speed_rpm = 0.0f, velocity_lpf_rad_s = 0.0f;
  uint32_t faults[kFaultSlots] = {};
  uint8_t fault_count = 0, error_register = 0;
  hil_emcy_queue emcy = {};
} ram;

// The sensor is a global object on the MCU: static storage zeroed at power-on, then constructed.
// A power cycle here does the same to the same storage (HallSensor leaves most members to that
// zeroing: its constructor sets only the pins, cpr and pull-up).
alignas(HallSensor) unsigned char sensor_storage[sizeof(HallSensor)];
HallSensor& sensor() { return *std::launder(reinterpret_cast<HallSensor*>(sensor_storage)); }

void doA() { sensor().handleA(); }
void doB() { sensor().handleB(); }
void doC() { sensor().handleC(); }

void fault(uint16_t code) {
  for (int k = 0; k < ram.fault_count; ++k) if (ram.faults[k] == code) return;
  for (int k = kFaultSlots - 1; k > 0; --k) ram.faults[k] = ram.faults[k - 1];
  ram.faults[0] = code;
  if (ram.fault_count < kFaultSlots) ++ram.fault_count;
  ram.error_register |= HIL_ERR_REG_GENERIC | HIL_ERR_REG_MANUFACTURER;
  hil_emcy_push(&ram.emcy, code);
}

// BLDCMotor::loopFOC's first half, six-step: the sensor's update(), then the electrical angle
// from the mechanical one it holds. SimpleFOC's angle is its sector's lower bound; the drive
// sector is that angle plus the zero electric angle. An illegal Hall code is reported, and the
// drive follows the angle SimpleFOC gives for it, as a SimpleFOC user's motor would.
void commutate() {
  HallSensor& s = sensor();
  s.update();
  if (s.hall_state == 0 || s.hall_state == 7) fault(kIllegalHallCode);
  float electrical = _normalizeAngle(_electricalAngle(s.getMechanicalAngle(), kPolePairs));
  int simplefoc_sector = static_cast<int>(std::lround(electrical / _PI_3)) % 6;
  ram.gates = hil_gates_of_sector((simplefoc_sector + kZeroElectricSectors) % 6);
}

// SimpleFOC's sector callback runs inside the Hall interrupt, after the sensor took the edge:
// the drive switches at the edge's capture, not at the next control interrupt
void on_sector_change(int) { commutate(); }

template <typename T> int32_t put(uint8_t* buf, uint32_t size, T v) {
  if (size < sizeof(T)) return -HIL_SDO_LENGTH;
  std::memcpy(buf, &v, sizeof(T));
  return sizeof(T);
}

}  // namespace

extern "C" {
HIL_SIL_EXPORT void hil_sil_describe(hil_sil_info* info) {
  info->abi = HIL_SIL_ABI;
  info->name = "SimpleFOC HallSensor (Arduino-FOC 7f9c45f) six-step port 0.1";
  info->timer_hz = sil_board::kTimerHz;
  info->timer_bits = sil_board::kTimerBits;
  info->control_hz = kControlHz;
  info->amps_per_count = 0.01f;
  info->pole_pairs = kPolePairs;
}

HIL_SIL_EXPORT void hil_sil_reset(uint8_t levels) {
  ram = Ram{};
  ram.duty = nvm.setpoint_rpm * kDutyPerRpm;
  sil_board::power_on(levels);
  std::memset(sensor_storage, 0, sizeof sensor_storage);
  HallSensor* s = new (sensor_storage) HallSensor(0, 1, 2, kPolePairs);
  s->init();  // reads the pins at start-up
  s->enableInterrupts(doA, doB, doC);
  s->attachSectorCallback(on_sector_change);
  commutate();
}

HIL_SIL_EXPORT void hil_sil_hall_isr(uint32_t count, uint8_t pin, uint8_t levels, const int16_t adc[3]) {
  (void)adc;
  sil_board::clock_at(count);
  sil_board::pin_changed(pin, levels);
}

HIL_SIL_EXPORT void hil_sil_control_isr(uint32_t count, const int16_t adc[3]) {
  (void)adc;
  sil_board::clock_at(count);
  commutate();
  // BLDCMotor::move()'s velocity loop, on the duty: SimpleFOC's velocity is mechanical rad/s and
  // zero once the last edge is older than twice the last sector's duration
  // BLDCMotor filters the sensor's velocity before its loop (LPF_velocity, SimpleFOC's default
  // time constant): the raw one is one sector's duration, and zero while the edge it waits for is
  // later than twice the last interval, which uneven sectors at speed make it now and then
  float velocity_rad_s = sensor().getVelocity();
  ram.velocity_lpf_rad_s = kVelocityLpfAlpha * ram.velocity_lpf_rad_s + (1.0f - kVelocityLpfAlpha) * velocity_rad_s;
  ram.speed_rpm = ram.velocity_lpf_rad_s * kRadPerSToRpm;
  // SimpleFOC's velocity stays zero until two sectors in one direction were timed: a PI running
  // before that sees the whole set point as error and slams the duty to its limit, and the
  // armature current's lag then holds the motor there (the template waits for six edges too)
  if (sensor().total_interrupts < kEdgesBeforeSpeedLoop) return;
  float error = nvm.setpoint_rpm - ram.speed_rpm;
  float feedforward = nvm.setpoint_rpm * kDutyPerRpm;
  // the integral stops where the duty does (anti-windup): a zero velocity after a wiring fault
  // must not leave a wound-up duty behind once the speed reads again
  ram.integral = _constrain(ram.integral + error * (kSpeedKi / kControlHz), -feedforward, kDutyMax - feedforward);
  float duty = feedforward + kSpeedKp * error + ram.integral;
  ram.duty = _constrain(duty, 0.0f, kDutyMax);
}

HIL_SIL_EXPORT uint8_t hil_sil_gates(void) { return ram.gates; }
HIL_SIL_EXPORT uint16_t hil_sil_duty(void) { return static_cast<uint16_t>(ram.duty * 65535.0f); }

HIL_SIL_EXPORT int hil_sil_emcy(uint16_t* code) { return hil_emcy_pop(&ram.emcy, code); }

HIL_SIL_EXPORT int32_t hil_sil_od_read(uint16_t index, uint8_t sub, uint8_t* buf, uint32_t size) {
  constexpr int32_t kNoSub = -HIL_SDO_NO_SUBINDEX;
  switch (index) {
    case 0x1001: return sub ? kNoSub : put<uint8_t>(buf, size, ram.error_register);
    case 0x1003:
      if (sub == 0) return put<uint8_t>(buf, size, ram.fault_count);
      return sub <= kFaultSlots ? put<uint32_t>(buf, size, ram.faults[sub - 1]) : kNoSub;
    case 0x1018:  // identity: vendor, product, revision, serial
      if (sub == 0) return put<uint8_t>(buf, size, 4);
      if (sub == 1) return put<uint32_t>(buf, size, 0x5F0C0000u);
      return sub <= 4 ? put<uint32_t>(buf, size, sub) : kNoSub;
    case 0x2200: return sub ? kNoSub : put<float>(buf, size, nvm.setpoint_rpm);
    case 0x2201: return sub ? kNoSub : put<int32_t>(buf, size, static_cast<int32_t>(ram.speed_rpm));
    default: return -HIL_SDO_NO_OBJECT;
  }
}

HIL_SIL_EXPORT int32_t hil_sil_od_write(uint16_t index, uint8_t sub, const uint8_t* buf, uint32_t size) {
  if (index == 0x2200 && sub == 0) {
    if (size != 4) return -HIL_SDO_LENGTH;
    float v;
    std::memcpy(&v, buf, 4);
    if (!(v >= 0.0f && v <= 20000.0f)) return -HIL_SDO_VALUE_INVALID;
    nvm.setpoint_rpm = v;
    return 0;
  }
  if (index == 0x2201 || index == 0x1018 || index == 0x1001 || index == 0x1003) return -HIL_SDO_READ_ONLY;
  return -HIL_SDO_NO_OBJECT;
}
}  // extern "C"

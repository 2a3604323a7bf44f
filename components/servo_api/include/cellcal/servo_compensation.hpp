// The servo library's C++ face: one robot's compensation inside a controller's own loop (servo_compensation.h),
// owned by an object. Header-only over the C functions, so a bridge built with another compiler or standard library
// links the same libcellcal_servo.so (find_package(cellcal), target cellcal::servo).
//
//   cellcal::ServoCompensation servo("/etc/cellcal/cell.yaml", "ur10");  // throws std::runtime_error with the reason
//   ... per cycle, on the controller's thread:
//   servo.correct(stamp_ns, q_setpoint, 6, q_command);                  // noexcept; no allocation, lock or syscall
//   ... elsewhere: std::cerr << servo.describe();                        // the calibration feed's state
#pragma once

#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <string>

#include "cellcal/servo_compensation.h"

namespace cellcal {

class ServoCompensation {
 public:
  ServoCompensation(const std::string& cell_file, const std::string& robot_id) {
    char why[512] = {0};
    servo_ = cellcal_servo_create(cell_file.c_str(), robot_id.c_str(), why, sizeof why);
    if (!servo_) throw std::runtime_error(why);
  }
  ~ServoCompensation() {
    if (servo_) cellcal_servo_destroy(servo_);
  }
  ServoCompensation(const ServoCompensation&) = delete;
  ServoCompensation& operator=(const ServoCompensation&) = delete;
  ServoCompensation(ServoCompensation&& o) noexcept : servo_(o.servo_) { o.servo_ = nullptr; }
  ServoCompensation& operator=(ServoCompensation&& o) noexcept {
    if (this != &o) {
      if (servo_) cellcal_servo_destroy(servo_);
      servo_ = o.servo_;
      o.servo_ = nullptr;
    }
    return *this;
  }

  // Controller thread, once per cycle: the joints to command (q_out_rad, `joints` values) for a setpoint; the status
  // (cellcal_servo_status). `answer`: the details, may be null.
  int correct(std::int64_t cycle_stamp_ns, const double* q_setpoint_rad, int joints, double* q_out_rad,
              cellcal_servo_answer* answer = nullptr) noexcept {
    return cellcal_servo_correct(servo_, cycle_stamp_ns, q_setpoint_rad, joints, q_out_rad, answer);
  }
  std::uint64_t version() const noexcept { return cellcal_servo_version(servo_); }  // controller thread
  int joints() const noexcept { return cellcal_servo_joints(servo_); }
  // The feed's state in words; not for the controller's thread.
  std::string describe() const {
    std::string text(cellcal_servo_describe(servo_, nullptr, 0) + 64, '\0');  // room for a longer state since
    const std::size_t n = cellcal_servo_describe(servo_, &text[0], text.size());
    text.resize(n < text.size() ? n : text.size() - 1);
    return text;
  }

 private:
  cellcal_servo* servo_ = nullptr;
};

}  // namespace cellcal

// The C API of cellcal/servo_compensation.h: a RealtimeCompensator and its CalibrationFeed behind one handle.
#include "cellcal/servo_compensation.h"

#include <algorithm>
#include <cstring>
#include <exception>
#include <stdexcept>
#include <memory>
#include <string>

#include "cellcal/components/calibration_feed.hpp"
#include "cellcal/core/files/cell_config.hpp"
#include "cellcal/core/servo/realtime_compensator.hpp"

struct cellcal_servo {
  cellcal::CellConfig cell;
  const cellcal::CellRobot* robot = nullptr;
  std::unique_ptr<cellcal::RealtimeCompensator> compensator;
  std::unique_ptr<cellcal::components::CalibrationFeed> feed;  // after the compensator: destroyed first
};

namespace {
size_t copyOut(const std::string& s, char* out, size_t size) {
  if (out && size > 0) {
    const size_t n = std::min(s.size(), size - 1);
    std::memcpy(out, s.data(), n);
    out[n] = '\0';
  }
  return s.size();
}
}  // namespace

extern "C" {

cellcal_servo* cellcal_servo_create(const char* cell_file, const char* robot_id, char* error, size_t error_size) {
  try {
    if (!cell_file || !robot_id) throw std::invalid_argument("cellcal_servo_create: cell_file and robot_id are required");
    auto s = std::make_unique<cellcal_servo>();
    s->cell = cellcal::loadCellConfig(cell_file);
    std::string ids;
    for (const cellcal::CellRobot& r : s->cell.robots) {
      if (r.robot_id == robot_id) s->robot = &r;
      ids += (ids.empty() ? "" : ", ") + r.robot_id;
    }
    if (!s->robot)
      throw std::invalid_argument(std::string("robot '") + robot_id + "' is not in " + cell_file + " (its robots: " +
                                  ids + ")");
    s->compensator = std::make_unique<cellcal::RealtimeCompensator>(s->robot->model,
                                                                    cellcal::components::realtimeSettings(s->cell));
    s->feed = std::make_unique<cellcal::components::CalibrationFeed>(s->cell, robot_id, *s->compensator);
    return s.release();
  } catch (const std::exception& e) {
    copyOut(e.what(), error, error_size);
    return nullptr;
  }
}

int cellcal_servo_correct(cellcal_servo* servo, int64_t cycle_stamp_ns, const double* q_setpoint_rad, int joints,
                          double* q_out_rad, cellcal_servo_answer* answer) {
  const cellcal::RealtimeAnswer a = servo->compensator->correct(cycle_stamp_ns, q_setpoint_rad, joints);
  if (q_out_rad)
    for (int j = 0; j < static_cast<int>(a.q_rad.size()) && j < joints; ++j) q_out_rad[j] = a.q_rad[j];
  if (answer) {
    answer->status = static_cast<int>(a.status);
    answer->outcome = static_cast<int>(a.outcome);
    answer->version = a.version;
    answer->from_version = a.from_version;
    answer->weight = a.weight;
    answer->hold_fraction = a.hold_fraction;
    answer->predicted_sigma_m = a.predicted_sigma_m;
  }
  return static_cast<int>(a.status);
}

uint64_t cellcal_servo_version(const cellcal_servo* servo) { return servo->compensator->version(); }

int cellcal_servo_joints(const cellcal_servo* servo) { return servo->robot->model.numJoints(); }

size_t cellcal_servo_describe(const cellcal_servo* servo, char* text, size_t size) {
  return copyOut(cellcal::components::describe(servo->feed->status()), text, size);
}

void cellcal_servo_destroy(cellcal_servo* servo) { delete servo; }

}  // extern "C"

// The two shapes a servo loop outside cellcal takes, built against the installed cellcal::servo with its C++ face
// (cellcal/servo_compensation.hpp), as docs/deployment.md shows them. Neither stack is here, so each stands in for
// its calls with a function of the same role:
//   - a ros2_control hardware interface: on_activate() makes the compensation, write() corrects the command the
//     controllers wrote before it is sent (read/update/write run in one SCHED_FIFO thread);
//   - a ur_rtde servoJ loop at 500 Hz: the program's joint target corrected each cycle before servoJ.
// No engine runs here: every setpoint comes back as given (no_calibration) and the feed says so. Exit 0 when both
// loops ran every cycle that way.
#include <array>
#include <cstdint>
#include <cstdio>
#include <memory>
#include <string>

#include "cellcal/servo_compensation.hpp"

namespace {

// --- ros2_control: the part of a SystemInterface that matters (hardware_interface::SystemInterface in a real one).
class CompensatedArm {
 public:
  explicit CompensatedArm(std::string cell_file) : cell_file_(std::move(cell_file)) {}
  bool on_activate() {  // not the real-time thread: the feed joins the cell's DDS domain here
    try {
      servo_ = std::make_unique<cellcal::ServoCompensation>(cell_file_, "tx60");
    } catch (const std::exception& e) {
      std::fprintf(stderr, "CompensatedArm: %s\n", e.what());
      return false;
    }
    return true;
  }
  // write(time, period): hw_commands_ hold what the controllers want; the robot gets the corrected joints.
  int write(std::int64_t time_ns) {
    const int status = servo_->correct(time_ns, hw_commands_.data(), 6, sent_to_robot_.data());
    // ... send sent_to_robot_ to the robot's driver here ...
    return status;
  }
  std::array<double, 6> hw_commands_{0.1, -0.4, 1.2, 0.05, 0.6, -0.2};
  std::array<double, 6> sent_to_robot_{};
  std::unique_ptr<cellcal::ServoCompensation> servo_;

 private:
  std::string cell_file_;
};

// --- ur_rtde: RTDEControlInterface::servoJ(q, speed, acceleration, dt, lookahead_time, gain) in a real loop.
std::array<double, 6> g_servoj_last{};
void servoJ(const std::array<double, 6>& q) { g_servoj_last = q; }

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: servo_loops CELL_FILE\n");
    return 2;
  }
  int failures = 0;
  CompensatedArm arm(argv[1]);
  if (!arm.on_activate()) return 1;
  for (int k = 0; k < 250; ++k) {  // 1 s of a 250 Hz controller manager
    arm.hw_commands_[0] = 0.1 + 0.001 * k;
    if (arm.write(std::int64_t{k} * 4'000'000) != CELLCAL_SERVO_NO_CALIBRATION ||
        arm.sent_to_robot_ != arm.hw_commands_)
      ++failures;
  }

  cellcal::ServoCompensation servo(argv[1], "tx60");
  std::array<double, 6> q_target{0.1, -0.4, 1.2, 0.05, 0.6, -0.2}, q_command{};
  const std::int64_t dt_ns = 2'000'000;  // servoJ at 500 Hz
  for (int k = 0; k < 500; ++k) {
    q_target[5] = -0.2 + 0.001 * k;  // the program's next target
    servo.correct(k * dt_ns, q_target.data(), 6, q_command.data());
    servoJ(q_command);
    if (g_servoj_last != q_target) ++failures;  // nothing applied without a calibration
  }
  const std::string feed = servo.describe();
  std::printf("servo_loops: ros2_control write() and a servoJ loop ran; version %llu; feed: %s\n",
              static_cast<unsigned long long>(servo.version()), feed.c_str());
  if (failures) std::fprintf(stderr, "servo_loops: %d cycles not as expected\n", failures);
  return failures == 0 && feed.find("no calibration received yet") != std::string::npos ? 0 : 1;
}

// `cellcal cell`'s application: TargetPoses (and servo setpoints) on the launcher's participant.
#include <atomic>
#include <cstdio>
#include <optional>
#include <random>

#include "cell_roles.hpp"
#include "cellcal/components/convert.hpp"
#include "cellcal/components/dds_node.hpp"
#include "cellcal/core/files/measurement_csv.hpp"
#include "cellcal/lab/sim_program.hpp"

namespace cellcal::cli {

using namespace cellcal::components;

class CellApplication::Impl {
 public:
  Impl(const CellConfig& cell, const CellArgs& a) : a_(a), target_rng_(cell.simulation.seed + 777) {
    for (size_t i = 0; i < cell.robots.size(); ++i) {
      Robot r{&cell.robots[i], makeSimulatedCell(cell.robots[i], cell.simulation, static_cast<int>(i))};
      // The judge's hold-out poses come first in this stream (cell_judge.cpp), the targets' configurations after.
      std::mt19937_64 rng(cell.simulation.seed * 31 + 12345 + i);
      r.sim.randomConfigurations(a.holdout_poses, rng);
      r.target_qs = r.sim.randomConfigurations(200, rng);
      if (!a.targets_program.empty()) {  // the program's rows instead, each once
        MeasurementCsvOptions po;
        po.joints_only = true;
        r.program = readMeasurementCsv(a.targets_program, cell.robots[i].model, po).rows;
      }
      robots_.push_back(std::move(r));
      sent_[cell.robots[i].robot_id];
    }
  }

  void attach(DdsNode& node) {
    targets_.emplace(node.writer<msg::TargetPose>());
    if (a_.servo) {
      servo_.emplace(node.writer<msg::ServoSetpoint>());
      node.reader<msg::ServoCorrection>([this](const msg::ServoCorrection& m, const fdds::SampleInfo&) {
        ++servo_answered_;
        if (m.applied()) ++servo_applied_;
      });
    }
  }

  void sendTargets() {
    for (auto& r : robots_) {
      const MeasurementRow* row = nullptr;  // --targets-program: the next row, until the program ends
      if (!a_.targets_program.empty()) {
        if (r.target_seq >= r.program.size()) continue;
        row = &r.program[r.target_seq];
      }
      const Eigen::VectorXd& q =
          row ? row->q_rad : r.target_qs[std::uniform_int_distribution<size_t>(0, r.target_qs.size() - 1)(target_rng_)];
      KinematicsData d(r.sim.model());
      const Pose desired = forwardKinematics(r.sim.model(), d, r.sim.nominalParams(), q);
      msg::TargetPose t;
      t.robot_id(r.robot->robot_id);
      t.sequence_number(++r.target_seq);
      fromPose(desired, t.position_m(), t.orientation_xyzw());
      t.seed_position_rad(std::vector<double>(q.data(), q.data() + q.size()));
      const std::int64_t now = wallNs();
      t.source_stamp_ns(static_cast<std::uint64_t>(now));
      sent_[r.robot->robot_id][r.target_seq] = {now, q, row ? row->pose : std::nullopt, row ? row->cycle : std::nullopt};
      targets_->write(t);
      if (servo_) {  // the robot holding the target's joints, one setpoint per cycle
        servo_sample_.robot_id(r.robot->robot_id);
        servo_sample_.sequence_number(r.target_seq);  // one setpoint per target: the same count
        servo_sample_.source_stamp_ns(static_cast<std::uint64_t>(now));
        servo_sample_.cycle_stamp_ns(static_cast<std::uint64_t>(now));
        servo_sample_.cartesian(false);
        servo_sample_.joint_position_rad().assign(q.data(), q.data() + q.size());
        servo_->write(servo_sample_);
        ++servo_sent_;
      }
    }
  }

  void summarize(nlohmann::json* summary) const {
    if (!servo_) return;
    (*summary)["servo"] = {{"sent", servo_sent_}, {"answered", servo_answered_.load()}, {"applied", servo_applied_.load()}};
    std::printf("cell: servo stream: %llu joint setpoints, %llu answered on cellcal/servo_correction (%llu applied)\n",
                static_cast<unsigned long long>(servo_sent_), static_cast<unsigned long long>(servo_answered_.load()),
                static_cast<unsigned long long>(servo_applied_.load()));
  }

  SentTargets sent_;

 private:
  struct Robot {
    const CellRobot* robot;
    SimulatedCell sim;
    std::vector<Eigen::VectorXd> target_qs = {};
    std::vector<MeasurementRow> program = {};  // --targets-program
    std::uint64_t target_seq = 0;
  };
  const CellArgs& a_;
  std::vector<Robot> robots_;
  std::mt19937_64 target_rng_;
  std::optional<Writer<msg::TargetPose>> targets_;
  std::optional<Writer<msg::ServoSetpoint>> servo_;  // --servo
  msg::ServoSetpoint servo_sample_;
  std::uint64_t servo_sent_ = 0;
  std::atomic<std::uint64_t> servo_answered_{0}, servo_applied_{0};  // corrections received (a DDS callback counts)
};

CellApplication::CellApplication(const CellConfig& cell, const CellArgs& a) : impl_(std::make_unique<Impl>(cell, a)) {}
CellApplication::~CellApplication() = default;
void CellApplication::attach(DdsNode& node) { impl_->attach(node); }
void CellApplication::sendTargets() { impl_->sendTargets(); }
SentTargets& CellApplication::sent() { return impl_->sent_; }
void CellApplication::summarize(nlohmann::json* summary) const { impl_->summarize(summary); }

}  // namespace cellcal::cli

// Physical effects a geometric model does not have, each as an extension with few parameters.
//
// Every cause acts on the kinematic parameters of one observation: the extension's parameters e (a handful) perturb
// the parameter vector as  params_i = params + B_i e,  with B_i (numParams x numParams(ext)) built once per
// observation from its joint angles and drivers. A joint error dq_j adds to joint j's theta offset; a length change
// adds to the a and d entries. The pose Jacobian with respect to e is therefore J_i B_i, with J_i the kinematic
// Jacobian of kinematics.hpp: no new derivative code.
//
// The causes (joint j, 1-based in names and output, 0-based in code) are listed in cause_list.hpp; each is described
// and implemented in its own file of core/src/model/causes/ (joint_compliance, thermal_drift, cyclic_transmission,
// joint_scale, backlash, link_deflection, frame_drift) behind the CauseModel interface of cause.hpp. The functions
// below dispatch to them; adding a cause is its file and its line in cause_list.hpp (docs/ARCHITECTURE.md).
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <deque>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "cellcal/core/model/cause_list.hpp"
#include "cellcal/core/model/robot_model.hpp"
#include "cellcal/core/model/se3.hpp"

namespace cellcal {

// kNone, then the causes of cause_list.hpp. Everything about one cause is in its CauseModel (cause.hpp).
#define CELLCAL_CAUSE_ENUMERATOR(enumerator, stem) enumerator,
enum class Cause { kNone, CELLCAL_CAUSES(CELLCAL_CAUSE_ENUMERATOR) };
#undef CELLCAL_CAUSE_ENUMERATOR

const char* causeName(Cause c);                               // "joint_compliance", ...
std::optional<Cause> causeFromName(const std::string& name);  // inverse of causeName
const std::vector<Cause>& extensionCauses();                  // the robot's causes: every one except kNone, kFrameDrift
// Whether the cause follows the thermal driver (thermal_drift, frame_drift): a warm-up time constant applies on time.
bool followsThermalDriver(Cause c);
// Whether the cause reads the path to a pose (backlash: a play state).
bool followsPath(Cause c);

// Values of the drivers other than q at one observation.
struct Drivers {
  double thermal = 0.0;               // K above the reference temperature, or hours since the first row; see below
  bool thermal_is_time = false;       // `thermal` is the hours since the first row (no temperature): a warm-up applies
  double elapsed_h = std::numeric_limits<double>::quiet_NaN();  // hours since the first row; NaN without stamps
  Eigen::VectorXd motion_direction;   // per joint: +1 / -1 = sign of (q - q of the row visited before), 0 unknown
  // Joints x kPlayHistory: the last moves of each joint up to this row (q - q of the row before; last column: the
  // move onto this row), zero before the first row. Enough for the play state of any backlash narrower than the
  // largest of these moves.
  Eigen::MatrixXd recent_steps_rad;
};
constexpr int kPlayHistory = 8;

// Play state of joint j at a row for a backlash of this width (see `backlash` above): from 0 (unknown) before the
// recorded moves, each move shifts it by 2 step / width, clamped to [-1, 1]. width <= 0: motion_direction[j].
double playState(const Drivers& drivers, int j, double width_rad);
// The play operator itself: the state after one move.
inline double playStep(double state, double step_rad, double width_rad) {
  const double s = state + 2.0 * step_rad / width_rad;
  return s > 1.0 ? 1.0 : (s < -1.0 ? -1.0 : s);
}

// Drivers of rows given in visiting order. thermal: temperature_c[i] - temperature reference (their mean) if every
// row has a temperature and it changes (by kConstantTemperatureC or more over the rows: a constant column drives
// nothing); else (stamp_s[i] - stamp_s[0]) / 3600 if every row has a stamp; else none (has_thermal = false). Joints
// that moved less than 1e-4 rad get direction of the last real motion.
constexpr double kConstantTemperatureC = 0.05;
struct DriverTable {
  std::vector<Drivers> rows;
  bool has_thermal = false;
  std::string thermal_source;  // "temperature_c", "stamp_s" or ""
  // Every row's temperature, when they all lie within kConstantTemperatureC of each other (their mean): not a driver.
  std::optional<double> constant_temperature_c;
};
DriverTable driversFromSequence(const std::vector<Eigen::VectorXd>& q_rad, const std::vector<std::optional<double>>& temperature_c,
                                const std::vector<std::optional<double>>& stamp_s);

struct Extension {
  Cause cause = Cause::kNone;
  int joint = -1;  // 0-based (link_deflection: the link, 0-based); -1 for kNone, frame_drift and thermal drift of the lengths
  // thermal_drift or frame_drift on a time driver: the warm-up's time constant (h). 0: not chosen yet (fitExtended fits it; a
  // straight line where used unfitted); infinity: a straight line in time. Ignored with a temperature driver.
  double time_constant_h = 0.0;
};

// The first-order warm-up on time: tau (1 - exp(-t / tau)) hours after t hours, for a time constant tau (h); t itself
// (a straight line) when tau is 0 (not fitted yet) or infinite.
double warmUpDriver(double t_h, double tau_h);
// The thermal driver an extension that follows it sees at a row: Drivers::thermal, or on time its warm-up
// (warmUpDriver with Extension::time_constant_h).
double thermalDriverValue(const Extension& ext, const Drivers& drivers);

// Whether `extensions` include a backlash; whether a row's play state is unknown for one of their backlash joints (it
// has not moved since the data began: which side of the gap it rests on is unknown to anyone, and a fit leaves the
// row out).
bool hasBacklash(const std::vector<Extension>& extensions);
bool playStateUnknown(const std::vector<Extension>& extensions, const Drivers& drivers);

// Frames of the chain in the tracker frame: [0] robot base, [i] after A_i (i = 1..n), [n+1] target.
std::vector<Pose> chainFrames(const RobotModel& model, const Eigen::VectorXd& params, const Eigen::VectorXd& q_rad);

// Gravity torque on each joint (N m, about its axis) of the masses in model.links at (params, q).
Eigen::VectorXd gravityTorques(const RobotModel& model, const Eigen::VectorXd& params, const Eigen::VectorXd& q_rad);

// The driver of joint_compliance on joint j: the gravity torque of the robot file's masses (N m), or without masses
// that of a unit mass at the target (N m/kg).
double complianceDriver(const RobotModel& model, const Eigen::VectorXd& params, const Eigen::VectorXd& q_rad, int j);

// Length (m) of link j: between the axes of joints j and j+1 (the origins of frames j-1 and j of chainFrames).
double linkLength(const RobotModel& model, const Eigen::VectorXd& params, int j);

// Whether the cause applies to this joint with these data (e.g. no compliance on a joint gravity never loads).
bool applicable(const RobotModel& model, const Extension& ext, bool has_thermal);
int numExtensionParams(const RobotModel& model, const Extension& ext);
std::vector<std::string> extensionParamNames(const RobotModel& model, const Extension& ext);

// B_i of one observation (see the top of this file). `params` sets the geometry of the gravity basis;
// `backlash_width_rad` the width the play state is evaluated at (backlash only).
Eigen::MatrixXd extensionBasis(const RobotModel& model, const Eigen::VectorXd& params, const Extension& ext,
                               const Eigen::VectorXd& q_rad, const Drivers& drivers, double backlash_width_rad = 0.0);

// Several extensions side by side (their parameters concatenated in list order). A backlash's play state is evaluated
// at the absolute value of its parameter in `evaluated_at` (same layout; empty or zero: width 0).
int numExtensionParams(const RobotModel& model, const std::vector<Extension>& exts);
std::vector<std::string> extensionParamNames(const RobotModel& model, const std::vector<Extension>& exts);
Eigen::MatrixXd extensionBasis(const RobotModel& model, const Eigen::VectorXd& params, const std::vector<Extension>& exts,
                               const Eigen::VectorXd& q_rad, const Drivers& drivers, const Eigen::VectorXd& evaluated_at);

// Written and read form of an extension: "joint_compliance:2" (cause, then the 1-based joint), "thermal_drift"
// (lengths only). parseExtensionList takes a comma-separated list; errors (std::invalid_argument) name the item and
// say what is wrong (unknown cause, missing or bad joint, not applicable to `model`).
std::string extensionSpec(const Extension& ext);
Extension parseExtension(const std::string& item, const RobotModel& model, bool has_thermal = true);
std::vector<Extension> parseExtensionList(const std::string& spec, const RobotModel& model, bool has_thermal = true);

// The kinematic parameters of one pose under an extended model: params + B(q, drivers) e (backlash evaluated at its
// width |e|). With no extensions: params.
Eigen::VectorXd extendedParams(const RobotModel& model, const Eigen::VectorXd& params, const std::vector<Extension>& exts,
                               const Eigen::VectorXd& extension_params, const Eigen::VectorXd& q_rad,
                               const Drivers& drivers);

// A prior for extension parameters nothing is known about: 1 sigma of each parameter is the value whose basis column
// makes an RMS joint error of `joint_error_rad` over configurations spread through the joint limits (deterministic).
// 0 for a parameter whose column does not act (rounding level against the extension's others, e.g. a link's moment
// along an axis parallel to the joint's): such a parameter cannot be estimated and stays out of an RLS state.
Eigen::VectorXd extensionPriorSigma(const RobotModel& model, const Eigen::VectorXd& params,
                                    const std::vector<Extension>& exts, double joint_error_rad);

// Drivers from a joint-state stream instead of a list of rows: the play state of a pose depends on the path the
// joint took to it, not only on the previous measured pose (the robot works between measurements). Keeps each
// joint's turning points (reversals larger than `hysteresis_rad`, so encoder noise does not fill the history) and
// gives, for a pose reached at stamp t, the last kPlayHistory monotone moves of each joint ending at the pose
// (Drivers::recent_steps_rad, per joint: the columns of different joints are not simultaneous, which playState does
// not need). Thermal driver: 0 (the stream has no temperature).
class PlayTracker {
 public:
  struct Turn {
    std::int64_t stamp_ns;
    double q_rad;
  };
  struct Joint {
    std::deque<Turn> turns;   // confirmed turning points, oldest first (the first sample opens the history)
    int direction = 0;        // of the move in progress: +1, -1, 0 not yet moved
    Turn extreme{0, 0.0};     // furthest point of the move in progress
  };
  static constexpr size_t kMaxTurns = 4 * kPlayHistory;

  explicit PlayTracker(int joints = 0, double hysteresis_rad = 1e-5);
  // Joint readings in time order (older or wrong-sized readings are ignored).
  void add(std::int64_t stamp_ns, const Eigen::VectorXd& q_rad);
  Drivers driversAt(std::int64_t stamp_ns, const Eigen::VectorXd& q_rad) const;
  const std::vector<Joint>& joints() const { return joints_; }
  // Restores a saved history (e.g. the engine's state file).
  void restore(std::vector<Joint> joints, std::int64_t last_stamp_ns);
  std::int64_t lastStampNs() const { return last_ns_; }

 private:
  double hysteresis_rad_;
  std::vector<Joint> joints_;
  std::int64_t last_ns_ = 0;
};

}  // namespace cellcal

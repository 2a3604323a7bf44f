// The engine state's fields, listed once. The state file (state_file.cpp: JSON, by name) and the journal
// (state_journal.cpp: binary records, in this order) each walk this list with a codec of their own, writing or
// reading; a new field of EngineState is one line here (with its presence: kAppended at the end for a field older
// files and records lack).
//
// A codec C is a writer or a reader (C::kReads) of one format and offers, each with the field's JSON name:
//   c.text(name, std::string&)                 c.number<Stored>(name, T&)   (the journal stores Stored)
//   c.flag(name, bool&)                        c.vec(name, Eigen::VectorXd&)
//   c.doubles(name, std::vector<double>&)      c.ints(name, std::vector<int>&)
//   c.square(name, Eigen::MatrixXd&)           c.texts(name, std::vector<std::string>&)
//   c.choice(name, E&, {names in the order of E's values})      (the journal: a byte)
//   c.object(name, std::optional<T>&, fields)  an optional nested object (the journal: a flag, then its fields)
//   c.objects(name, container<T>&, bytes, fields[, presence])  an array of objects; `bytes`: the least one takes
//                                              in the journal
//   c.tuple(name, T&, fields)                  a nested array (JSON by position)
//   c.tuples(name, container<T>&, bytes, fields)   an array of such arrays
//   c.pose(Pose&)                              a reading's pose (JSON: position_m and orientation_xyzw; the journal:
//                                              the matrix, bit for bit)
// A writer never assigns to the fields (so a const state may be walked with a writer: writeFields). Presence: kRequired (an error when a reader does not find it), kOptional (a JSON file may lack it: the default
// stays), kAppended (a JSON file or a journal record may lack it: appended after the first records; only at the end).
#pragma once

#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "cellcal/core/engine/engine_state.hpp"

namespace cellcal::state_fields {

enum class Presence { kRequired, kOptional, kAppended };
constexpr Presence kRequired = Presence::kRequired, kOptional = Presence::kOptional, kAppended = Presence::kAppended;

template <class C>
void reading(C& c, PairedReading& p) {
  Observation& o = p.observation;
  c.vec("q_rad", o.q_rad);
  c.pose(o.measured_in_tracker);
  bool six_d = o.kind == MeasurementKind::kPose6D;
  c.flag("pose6d", six_d);
  if (C::kReads) o.kind = six_d ? MeasurementKind::kPose6D : MeasurementKind::kPosition3D;
  c.template number<double>("sigma_position_m", o.sigma_position_m);
  c.template number<double>("sigma_orientation_rad", o.sigma_orientation_rad);
  c.template number<std::int64_t>("tracker_stamp_ns", p.tracker_stamp_ns);
  c.template number<std::uint64_t>("tracker_sequence", p.tracker_sequence);
  c.template number<std::int64_t>("joint_stamp_ns", p.joint_stamp_ns);
}

// The drivers a pending pose was paired with (a play history per joint: kPlayHistory steps each).
template <class C>
void drivers(C& c, Drivers& d) {
  c.vec("motion_direction", d.motion_direction);
  std::vector<double> steps(d.recent_steps_rad.data(), d.recent_steps_rad.data() + d.recent_steps_rad.size());
  if (!C::kReads && steps.size() != static_cast<std::size_t>(d.motion_direction.size()) * kPlayHistory)
    throw std::runtime_error("pending_batch drivers: recent_steps_rad size");
  c.doubles("recent_steps_rad", steps);
  if (C::kReads) {
    if (steps.size() != static_cast<std::size_t>(d.motion_direction.size()) * kPlayHistory)
      throw std::runtime_error("recent_steps_rad size");
    d.recent_steps_rad = Eigen::Map<const Eigen::MatrixXd>(steps.data(), d.motion_direction.size(), kPlayHistory);
  }
}

template <class C>
void pendingPose(C& c, EngineState::PendingPose& p) {
  reading(c, p.reading);
  c.object("drivers", p.drivers, drivers<C>);
}

template <class C>
void turn(C& c, PlayTracker::Turn& t) {
  c.template number<std::int64_t>("stamp_ns", t.stamp_ns);
  c.template number<double>("q_rad", t.q_rad);
}

template <class C>
void engineState(C& c, EngineState& s) {
  c.text("robot_id", s.robot_id);
  c.text("robot_name", s.robot_name);
  c.template number<std::int32_t>("num_params", s.num_params);
  c.template number<std::uint64_t>("version", s.version);
  c.template number<std::uint32_t>("poses_used", s.poses_used);
  c.choice("mode", s.mode, {"continuous", "periodic"}, kOptional);
  c.template number<std::int64_t>("last_measurement_stamp_ns", s.last_measurement_stamp_ns);
  c.template number<std::uint64_t>("last_tracker_sequence", s.last_tracker_sequence);
  c.template number<std::int64_t>("last_update_stamp_ns", s.last_update_stamp_ns);
  c.vec("nominal", s.nominal);
  c.vec("params", s.params);
  c.ints("estimated", s.estimated);
  c.square("covariance", s.covariance);
  c.template number<std::int32_t>("consecutive_outliers", s.consecutive_outliers, kOptional);
  c.doubles("gate_window", s.gate_window, kOptional);
  c.object("last_good", s.last_good, [](C& c, EngineState::Good& g) {
    c.template number<std::uint64_t>("version", g.version);
    c.vec("params", g.params);
    c.vec("extension_params", g.extension_params);
    c.ints("estimated", g.estimated);
    c.square("covariance", g.covariance);
  });
  c.texts("extensions", s.extensions, kOptional);
  c.vec("extension_params", s.extension_params, kOptional);
  c.ints("estimated_extension", s.estimated_extension, kOptional);
  c.object("play", s.play, [](C& c, EngineState::Play& p) {
    c.objects("joints", p.joints, 8 + 4 + 16, [](C& c, PlayTracker::Joint& j) {
      c.tuples("turns", j.turns, 16, turn<C>);
      c.template number<std::int32_t>("direction", j.direction);
      c.tuple("extreme", j.extreme, turn<C>);
    });
    c.template number<std::int64_t>("last_stamp_ns", p.last_stamp_ns);
  });
  c.tuples("recent", s.recent, 32, [](C& c, EngineState::Recent& r) {
    c.template number<double>("prior_error_m", r.prior_error_m);
    c.template number<double>("post_error_m", r.post_error_m);
    c.template number<double>("post_error_rad", r.post_error_rad);
    c.template number<double>("nis_per_row", r.nis_per_row);
  });
  c.objects("pending_batch", s.pending_batch, 8, pendingPose<C>);
  c.choice("started_from", s.started_from,
           {"nominal", "calibration_file", "nominal_calibration_file_refused", "nominal_calibration_file_worse"},
           kAppended);
  c.template number<std::int64_t>("file_drift_pending_since_ns", s.file_drift_pending_since_ns, kAppended);
  c.text("start_warning", s.start_warning, kAppended);
  c.objects("work_configurations", s.work_configurations, 8,
            [](C& c, Eigen::VectorXd& q) { c.vec("q_rad", q); }, kAppended);
  c.object("file_trial", s.file_trial, [](C& c, EngineState::FileTrialState& t) {
    c.vec("file_params", t.file_params);
    c.vec("file_extension_params", t.file_extension_params);
    c.vec("nominal", t.nominal);
    c.objects("poses", t.poses, 8, pendingPose<C>);
  }, kAppended);
}

// Walks a state with a writer: the list takes fields by reference, a writer only reads them.
template <class Writer>
void writeFields(Writer& w, const EngineState& s) {
  static_assert(!Writer::kReads);
  engineState(w, const_cast<EngineState&>(s));
}

}  // namespace cellcal::state_fields

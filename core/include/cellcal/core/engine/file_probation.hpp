// The probation of a calibration file (calibration_engine.hpp). An engine that starts from a calibrated robot file
// holds the first new stand-stills its outlier gate refuses, until one passes: kPoses of them in a row mean the file
// does not fit this cell (calibrated on another set-up, a moved tracker, another robot), and the engine starts from
// the nominal model and takes the held readings. A pose that passes the gate ends the probation: the held readings
// were outliers after all.
//
//   if (probation.hold({pending, rejection, prior_error_m, nis_per_row})) {   // the kPoses-th in a row
//     warn(probation.refusal(file, gate));
//     for (const auto& h : probation.take()) apply(h.pending);
//   }
#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include "cellcal/core/engine/pairing.hpp"
#include "cellcal/core/model/model_extension.hpp"

namespace cellcal {

// A paired reading with its extensions' drivers (the play state) as they were when it was paired: the joint history
// moves on while it waits.
struct DrivenReading {
  PairedReading reading;
  Drivers drivers;
};

class FileProbation {
 public:
  static constexpr std::size_t kPoses = 3;
  struct Held {
    DrivenReading pending;
    std::string rejection;     // what its rejection as an outlier says
    double prior_error_m = 0;  // |measured - predicted| position under the file's model
    double nis_per_row = 0;    // its normalized innovation per row
  };
  // Holds one more refused stand-still; true when kPoses are held: the file does not fit.
  bool hold(Held held);
  // Why the file is refused, naming it, the held poses' errors (mm) and the gate, and what to do.
  std::string refusal(const std::string& file, double gate) const;
  // The held readings in the order held; none are held after.
  std::vector<Held> take();

 private:
  std::vector<Held> held_;
};

}  // namespace cellcal

// cellcal_tracker_adapter: publishes 6D poses (or 3D points) of the target on the flange (cellcal/tracker_pose) from
// the simulated tracker, a measurement file or a tracker bridge over UDP. The process: tracker_adapter.hpp.
#include "tracker_adapter.hpp"

using namespace cellcal::components;

int main(int argc, char** argv) {
  return componentMain<TrackerAdapter>(
      "cellcal_tracker_adapter", argc, argv, [](CLI::App& app, TrackerAdapter::Options& o) {
        addSourceOptions(app, o.input);
        app.add_option("--sigma-position-mm", o.sigma_position_mm, "csv: 1-sigma position noise of the tracker")
            ->capture_default_str();
        app.add_option("--wait-for-readers", o.wait_for_readers,
                       "sim: start measuring once TrackerPose has N readers (at most 10 s)");
        app.add_option("--sigma-orientation-deg", o.sigma_orientation_deg, "csv: 1-sigma orientation noise")
            ->capture_default_str();
      });
}

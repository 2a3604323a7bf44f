// cellcal_calibration_engine: pairs tracker readings with joint states, updates each robot's calibration with RLS
// (per pose, or per batch in periodic mode), persists it atomically, publishes cellcal/calibration_state (RELIABLE,
// TRANSIENT_LOCAL, KEEP_LAST 1 per robot: late joiners get the latest at once; republished every
// engine.republish_period_s) and cellcal/calibration_diagnostics. The process: engine_process.hpp; the engines and
// their state files: components' EngineHost; the logic: core's CalibrationEngine.
#include <malloc.h>

#include "engine_process.hpp"

using namespace cellcal::components;

int main(int argc, char** argv) {
  // glibc raises its mmap threshold to the size of any large block freed, so the input queue's backlog after a stall
  // (MBs) would stay in the heap for good. A fixed threshold returns such blocks to the system when freed.
  mallopt(M_MMAP_THRESHOLD, 128 * 1024);
  return componentMain<EngineProcess>(
      "cellcal_calibration_engine", argc, argv, [](CLI::App& app, EngineProcess::Options& o) {
        addCommonOptions(app, o.process);
        app.add_option("--state-dir", o.process.state_dir,
                       "where each robot's state is persisted (overrides engine.state_dir)");
        app.add_option("--duration-s", o.duration_s, "stop after this many seconds (0: run until SIGINT/SIGTERM)");
        app.add_flag("-q,--quiet", o.quiet, "no line per update on stderr");
      });
}

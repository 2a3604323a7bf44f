// cellcal_calibration_engine: pairs tracker readings with joint states, updates each robot's calibration with RLS
// (per pose, or per batch in periodic mode), persists it atomically, publishes cellcal/calibration_state (RELIABLE,
// TRANSIENT_LOCAL, KEEP_LAST 1 per robot: late joiners get the latest at once; republished every
// engine.republish_period_s) and cellcal/calibration_diagnostics. The process: engine_process.hpp; the engines and
// their state files: components' EngineHost; the logic: core's CalibrationEngine.
#include <malloc.h>

#include "engine_process.hpp"

using namespace cellcal::components;

int main(int argc, char** argv) {
  CLI::App app{"cellcal calibration engine: continuous kinematic calibration from tracker poses and joint states"};
  app.footer(manFooter(
      "cellcal/joint_state, cellcal/tracker_pose",
      "cellcal/calibration_state, cellcal/calibration_diagnostics (reliable, transient local: a late joiner gets the latest)",
      "  cellcal_calibration_engine --state-dir /var/lib/cellcal          run for good; state survives restarts\n"
      "  cellcal_calibration_engine --config cell.yaml --duration-s 60    a one-minute run\n",
      "  <state-dir>/<robot_id>.state.journal: a record appended per change before it is published;\n"
      "  <state-dir>/<robot_id>.state.json: the snapshot, current after a clean stop. The engine resumes from them\n"
      "    after a restart, a SIGKILL included (no published update lost, none applied twice)\n"));
  EngineProcess::Options o;
  addCommonOptions(app, o.process);
  app.add_option("--state-dir", o.process.state_dir, "where each robot's state is persisted (overrides engine.state_dir)");
  app.add_option("--duration-s", o.duration_s, "stop after this many seconds (0: run until SIGINT/SIGTERM)");
  app.add_flag("-q,--quiet", o.quiet, "no line per update on stderr");
  return runMain("cellcal_calibration_engine", argc, argv, app, [&] {
    // glibc raises its mmap threshold to the size of any large block freed, so the input queue's backlog after a
    // stall (MBs) would stay in the heap for good. A fixed threshold returns such blocks to the system when freed.
    mallopt(M_MMAP_THRESHOLD, 128 * 1024);
    return EngineProcess(o).run();
  });
}

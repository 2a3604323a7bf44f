// cellcal_compensation_publisher: corrected targets for the unmodified robot controller (cellcal/target_pose ->
// cellcal/compensated_target) with the latest healthy calibration. The process: compensation_publisher.hpp.
#include "compensation_publisher.hpp"

using namespace cellcal::components;

int main(int argc, char** argv) {
  CLI::App app{"cellcal compensation publisher: corrected targets for the unmodified robot controller"};
  app.footer(manFooter(
      "cellcal/target_pose, cellcal/calibration_state, cellcal/calibration_diagnostics",
      "cellcal/compensated_target (never a correction beyond compensation.max_correction_mm / _deg)",
      "  cellcal_compensation_publisher                                   answer targets with the latest ok calibration\n"
      "  cellcal_compensation_publisher --wait-for-calibration-s 30      wait for the engine before answering\n",
      ""));
  CompensationPublisher::Options o;
  addCommonOptions(app, o.process);
  app.add_option("--wait-for-calibration-s", o.wait_for_calibration_s,
                 "at start, wait this long for every robot's calibration before taking targets")
      ->capture_default_str();
  app.add_option("--duration-s", o.duration_s, "stop after this many seconds (0: run until SIGINT/SIGTERM)");
  return runMain("cellcal_compensation_publisher", argc, argv, app, [&] { return CompensationPublisher(o).run(); });
}

// Measurement files (CSV v1, docs/measurement-csv.md): parseMeasurementCsv on arbitrary text, strict and with
// skip_bad_rows.
#include "cellcal/core/files/measurement_csv.hpp"
#include "cellcal/core/files/robot_yaml.hpp"
#include "fuzz_support.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const cellcal::RobotModel robot = cellcal::loadRobotModel(std::string(CELLCAL_CONFIG_DIR) + "/robots/ur10.yaml");
  const std::string text(reinterpret_cast<const char*>(data), size);
  cellcal::MeasurementCsvOptions options;
  options.skip_bad_rows = size % 2 == 1;
  cellcal::fuzz::expectCleanRefusal([&] { cellcal::parseMeasurementCsv(text, cellcal::fuzz::kSource, robot, options); });
  return 0;
}

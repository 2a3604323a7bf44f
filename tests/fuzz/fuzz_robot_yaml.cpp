// Robot files (config/robots/*.yaml): parseRobotModel on arbitrary text.
#include "cellcal/core/files/robot_yaml.hpp"
#include "fuzz_support.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  cellcal::fuzz::expectCleanRefusal([&] { cellcal::parseRobotModel(text, cellcal::fuzz::kSource); });
  return 0;
}

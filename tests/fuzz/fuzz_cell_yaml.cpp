// Cell files (config/cell.yaml): parseCellConfig on arbitrary text. Robot files it names resolve against the shipped
// config folder, so a mutated cell file reaches the robot parser and the registration checks too.
#include "cellcal/core/files/cell_config.hpp"
#include "fuzz_support.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  cellcal::fuzz::expectCleanRefusal([&] { cellcal::parseCellConfig(text, cellcal::fuzz::kSource, CELLCAL_CONFIG_DIR); });
  return 0;
}

// Robot descriptions (URDF): importUrdf on arbitrary text (XML, liburdfdom, the conversion to the DH model).
#include "cellcal/core/files/urdf.hpp"
#include "fuzz_support.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  cellcal::fuzz::expectCleanRefusal([&] { cellcal::importUrdf(text, cellcal::fuzz::kSource); });
  return 0;
}

// Recordings (MCAP): the reader on arbitrary bytes, strict and tolerating a cut end (what `cellcal validate` and
// `replay` do with a file).
#include <unistd.h>

#include <fstream>

#include "cellcal/mcap/mcap.hpp"
#include "fuzz_support.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const std::string path = "/tmp/" + std::string(cellcal::fuzz::kSource) + "-" + std::to_string(::getpid()) + ".mcap";
  {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  }
  for (bool tolerate : {false, true}) {
    cellcal::mcap::ReadOptions options;
    options.tolerate_truncation = tolerate;
    cellcal::fuzz::expectCleanRefusal([&] { cellcal::mcap::readFile(path, options); });
  }
  return 0;
}

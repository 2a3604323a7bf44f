// The engine's state journal (<robot_id>.state.journal, core/engine/state_journal.hpp): loadDurableState on arbitrary
// bytes as the journal beside no snapshot. A cut or corrupted record must read as the records before it; damage that
// is not a crash must be refused naming the file; nothing may crash or allocate beyond what the file holds.
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <string>

#include "cellcal/core/engine/state_journal.hpp"
#include "fuzz_support.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("cellcal_fuzz_journal_" + std::to_string(::getpid()));
  static const bool made = std::filesystem::create_directories(dir) || true;
  (void)made;
  const std::string state = (dir / (std::string(cellcal::fuzz::kSource) + ".state.json")).string();
  if (std::FILE* f = std::fopen(cellcal::stateJournalPath(state).c_str(), "wb")) {
    std::fwrite(data, 1, size, f);
    std::fclose(f);
  }
  cellcal::fuzz::expectCleanRefusal([&] { cellcal::loadDurableState(state); });
  return 0;
}

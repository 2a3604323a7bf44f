// Shared by the fuzz targets: a parser may refuse its input with a std::exception whose message names the source
// (the file the user gave); anything else -- a crash, a sanitizer report, another exception, an error that does not
// say which file -- is a finding.
#pragma once

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <string>

namespace cellcal::fuzz {

constexpr const char* kSource = "fuzz-input";

template <class F>
void expectCleanRefusal(F&& parse) {
  try {
    parse();
  } catch (const std::exception& e) {
    if (std::string(e.what()).find(kSource) == std::string::npos) {
      std::fprintf(stderr, "error does not name the source: %s\n", e.what());
      std::abort();
    }
  }
}

}  // namespace cellcal::fuzz

// KUKA RSI's packets (core/servo/rsi_xml.hpp): parseRsiRob and parseRsiSen on arbitrary bytes. A refusal is a code;
// what is accepted must have 1-7 axes and finite values, and written back it must read the same.
#include <cmath>
#include <cstdlib>

#include "cellcal/core/servo/rsi_xml.hpp"
#include "fuzz_support.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const char* text = reinterpret_cast<const char*>(data);
  cellcal::RsiRob rob;
  if (cellcal::parseRsiRob(text, size, rob) == cellcal::RsiError::kNone) {
    if (rob.axes < 1 || rob.axes > cellcal::kMaxServoJoints) std::abort();
    for (int k = 0; k < rob.axes; ++k)
      if (!std::isfinite(rob.setpoint_deg[k]) || (rob.has_actual && !std::isfinite(rob.actual_deg[k]))) std::abort();
    char out[cellcal::kMaxRsiPacketBytes];
    const std::size_t n = cellcal::writeRsiRob(out, sizeof out, rob.actual_deg.data(), rob.setpoint_deg.data(), rob.axes,
                                               rob.ipoc);
    cellcal::RsiRob again;
    if (n == 0 || cellcal::parseRsiRob(out, n, again) != cellcal::RsiError::kNone || again.ipoc != rob.ipoc ||
        again.setpoint_deg != rob.setpoint_deg)
      std::abort();
  }
  cellcal::RsiSen sen;
  if (cellcal::parseRsiSen(text, size, sen) == cellcal::RsiError::kNone) {
    if (sen.axes < 1 || sen.axes > cellcal::kMaxServoJoints) std::abort();
    for (int k = 0; k < sen.axes; ++k)
      if (!std::isfinite(sen.correction_deg[k])) std::abort();
  }
  return 0;
}

#include "cellcal/core/servo/rsi_xml.hpp"

#include <charconv>
#include <cmath>
#include <cstring>
#include <string_view>

namespace cellcal {

const char* rsiErrorName(RsiError e) {
  switch (e) {
    case RsiError::kNone: return "none";
    case RsiError::kTooLong: return "too_long";
    case RsiError::kNotThisElement: return "not_this_element";
    case RsiError::kTruncated: return "truncated";
    case RsiError::kMissingAxes: return "missing_axes";
    case RsiError::kBadAxis: return "bad_axis";
    case RsiError::kNotFinite: return "not_finite";
    case RsiError::kAxesDisagree: return "axes_disagree";
    case RsiError::kMissingIpoc: return "missing_ipoc";
    case RsiError::kBadIpoc: return "bad_ipoc";
    case RsiError::kBadStop: return "bad_stop";
  }
  return "?";
}

namespace {
using Text = std::string_view;
constexpr std::size_t npos = Text::npos;

bool isSpace(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\n'; }
Text trimmed(Text v) {
  while (!v.empty() && isSpace(v.front())) v.remove_prefix(1);
  while (!v.empty() && isSpace(v.back())) v.remove_suffix(1);
  return v;
}
// Whether `<name` starts at p and the name ends there (a space, '/' or '>' follows).
bool tagAt(Text t, std::size_t p, Text name) {
  const std::size_t after = p + 1 + name.size();
  return p < t.size() && t[p] == '<' && t.substr(p + 1, name.size()) == name && after < t.size() &&
         (isSpace(t[after]) || t[after] == '/' || t[after] == '>');
}
// The first child element <name in [from, end): the index of its '<', or npos.
std::size_t findElement(Text t, Text name, std::size_t from, std::size_t end) {
  for (std::size_t p = t.find('<', from); p != npos && p < end; p = t.find('<', p + 1))
    if (tagAt(t, p, name)) return p;
  return npos;
}

// The root element `name`: the content's [begin, end) between its start tag and its closing tag, which must close the
// packet (only whitespace after it).
RsiError root(Text t, Text name, std::size_t& begin, std::size_t& end) {
  std::size_t i = 0;
  while (i < t.size() && isSpace(t[i])) ++i;
  if (t.substr(i, 5) == "<?xml") {
    const std::size_t close = t.find("?>", i);
    if (close == npos) return RsiError::kTruncated;
    i = close + 2;
    while (i < t.size() && isSpace(t[i])) ++i;
  }
  if (!tagAt(t, i, name)) return i + 1 + name.size() >= t.size() ? RsiError::kTruncated : RsiError::kNotThisElement;
  const std::size_t open_end = t.find('>', i);
  if (open_end == npos) return RsiError::kTruncated;
  char closing[16] = "</";
  std::memcpy(closing + 2, name.data(), name.size());
  closing[2 + name.size()] = '>';
  const Text closing_tag(closing, name.size() + 3);
  const std::size_t close = t.find(closing_tag, open_end);
  if (close == npos) return RsiError::kTruncated;
  for (std::size_t k = close + closing_tag.size(); k < t.size(); ++k)
    if (!isSpace(t[k])) return RsiError::kNotThisElement;
  begin = open_end + 1;
  end = close;
  return RsiError::kNone;
}

// The attributes A1..A7 of the element whose '<' is at p (named `name`): values, and how many (A1..An, no gap).
RsiError readAxes(Text t, std::size_t p, Text name, std::size_t end, std::array<double, kMaxServoJoints>& values,
                  int& axes) {
  const std::size_t close = t.find('>', p);
  if (close == npos || close >= end) return RsiError::kTruncated;
  unsigned seen = 0;
  std::size_t i = p + 1 + name.size();
  while (i < close) {
    while (i < close && isSpace(t[i])) ++i;
    if (i >= close || t[i] == '/') break;
    const std::size_t eq = t.find('=', i);
    if (eq == npos || eq >= close) return RsiError::kTruncated;
    const Text attribute = trimmed(t.substr(i, eq - i));
    std::size_t q = eq + 1;
    while (q < close && isSpace(t[q])) ++q;
    if (q >= close || (t[q] != '"' && t[q] != '\'')) return RsiError::kTruncated;
    const std::size_t q2 = t.find(t[q], q + 1);
    if (q2 == npos || q2 >= close) return RsiError::kTruncated;
    i = q2 + 1;
    if (attribute.size() < 2 || attribute[0] != 'A' || attribute[1] < '0' || attribute[1] > '9') continue;
    if (attribute.size() != 2 || attribute[1] == '0' || attribute[1] - '0' > kMaxServoJoints) return RsiError::kBadAxis;
    const int k = attribute[1] - '1';
    const Text v = trimmed(t.substr(q + 1, q2 - q - 1));
    double x = 0;
    const auto [ptr, ec] = std::from_chars(v.data(), v.data() + v.size(), x);
    if (v.empty() || ec != std::errc() || ptr != v.data() + v.size() || (seen & (1u << k))) return RsiError::kBadAxis;
    if (!std::isfinite(x)) return RsiError::kNotFinite;
    values[static_cast<std::size_t>(k)] = x;
    seen |= 1u << k;
  }
  axes = 0;
  while (seen & (1u << axes)) ++axes;
  if (axes == 0) return RsiError::kMissingAxes;
  return seen == (1u << axes) - 1 ? RsiError::kNone : RsiError::kBadAxis;
}

// The unsigned integer content of the first <name> element in [from, end).
RsiError readUnsigned(Text t, Text name, std::size_t from, std::size_t end, std::uint64_t& value, RsiError missing,
                      RsiError bad) {
  const std::size_t p = findElement(t, name, from, end);
  if (p == npos) return missing;
  const std::size_t open_end = t.find('>', p);
  const std::size_t close = t.find("</", open_end == npos ? p : open_end);
  if (open_end == npos || close == npos || close > end) return RsiError::kTruncated;
  const Text v = trimmed(t.substr(open_end + 1, close - open_end - 1));
  const auto [ptr, ec] = std::from_chars(v.data(), v.data() + v.size(), value);
  return v.empty() || ec != std::errc() || ptr != v.data() + v.size() ? bad : RsiError::kNone;
}

// The packet as the root element `name` (its content's [begin, end)) and the axes of its first `element`.
RsiError rootAndAxes(Text t, Text name, Text element, std::size_t& begin, std::size_t& end,
                     std::array<double, kMaxServoJoints>& values, int& axes) {
  if (t.size() > kMaxRsiPacketBytes) return RsiError::kTooLong;
  if (const RsiError e = root(t, name, begin, end); e != RsiError::kNone) return e;
  const std::size_t p = findElement(t, element, begin, end);
  return p == npos ? RsiError::kMissingAxes : readAxes(t, p, element, end, values, axes);
}

// Appends to a fixed buffer; `ok` turns false once it does not fit.
struct Out {
  char* p;
  std::size_t capacity, size = 0;
  bool ok = true;
  void text(const char* s) {
    const std::size_t n = std::strlen(s);
    if (!ok || size + n > capacity) {
      ok = false;
      return;
    }
    std::memcpy(p + size, s, n);
    size += n;
  }
  template <class T>
  void number(T x) {
    if (!ok) return;
    const auto [end, ec] = std::to_chars(p + size, p + capacity, x);
    if (ec != std::errc()) {
      ok = false;
      return;
    }
    size = static_cast<std::size_t>(end - p);
  }
  void axes(const char* element, const double* v, int n) {
    text("<");
    text(element);
    for (int k = 0; k < n; ++k) {
      const char name[] = {' ', 'A', static_cast<char>('1' + k), '=', '"', '\0'};
      text(name);
      number(v[k]);
      text("\"");
    }
    text("/>");
  }
};
}  // namespace

RsiError parseRsiRob(const char* data, std::size_t size, RsiRob& out) noexcept {
  const Text t(data, size);
  std::size_t begin = 0, end = 0;
  RsiRob r;
  if (const RsiError e = rootAndAxes(t, "Rob", "ASPos", begin, end, r.setpoint_deg, r.axes); e != RsiError::kNone)
    return e;
  if (const std::size_t actual = findElement(t, "AIPos", begin, end); actual != npos) {
    int n = 0;
    if (const RsiError e = readAxes(t, actual, "AIPos", end, r.actual_deg, n); e != RsiError::kNone) return e;
    if (n != r.axes) return RsiError::kAxesDisagree;
    r.has_actual = true;
  }
  if (const RsiError e = readUnsigned(t, "IPOC", begin, end, r.ipoc, RsiError::kMissingIpoc, RsiError::kBadIpoc);
      e != RsiError::kNone)
    return e;
  out = r;
  return RsiError::kNone;
}

bool rsiIpoc(const char* data, std::size_t size, std::uint64_t& ipoc) noexcept {
  if (!data || size > kMaxRsiPacketBytes) return false;
  const Text t(data, size);
  std::uint64_t v = 0;
  if (readUnsigned(t, "IPOC", 0, t.size(), v, RsiError::kMissingIpoc, RsiError::kBadIpoc) != RsiError::kNone) return false;
  ipoc = v;
  return true;
}

RsiError parseRsiSen(const char* data, std::size_t size, RsiSen& out) noexcept {
  const Text t(data, size);
  std::size_t begin = 0, end = 0;
  RsiSen s;
  if (const RsiError e = rootAndAxes(t, "Sen", "AK", begin, end, s.correction_deg, s.axes); e != RsiError::kNone)
    return e;
  std::uint64_t stop = 0;
  const RsiError e_stop = readUnsigned(t, "Stop", begin, end, stop, RsiError::kNone, RsiError::kBadStop);
  if (e_stop != RsiError::kNone) return e_stop;
  if (stop > 1) return RsiError::kBadStop;
  s.stop = stop != 0;
  if (const RsiError e = readUnsigned(t, "IPOC", begin, end, s.ipoc, RsiError::kMissingIpoc, RsiError::kBadIpoc);
      e != RsiError::kNone)
    return e;
  out = s;
  return RsiError::kNone;
}

std::size_t writeRsiSen(char* out, std::size_t capacity, const char* sensor_type, const double* correction_deg, int axes,
                        std::uint64_t ipoc, bool stop) noexcept {
  if (axes < 1 || axes > kMaxServoJoints || !out) return 0;
  Out o{out, capacity};
  o.text("<Sen Type=\"");
  o.text(sensor_type);
  o.text(stop ? "\"><Stop>1</Stop>" : "\"><Stop>0</Stop>");
  o.axes("AK", correction_deg, axes);
  o.text("<IPOC>");
  o.number(ipoc);
  o.text("</IPOC></Sen>");
  return o.ok ? o.size : 0;
}

std::size_t writeRsiRob(char* out, std::size_t capacity, const double* actual_deg, const double* setpoint_deg, int axes,
                        std::uint64_t ipoc) noexcept {
  if (axes < 1 || axes > kMaxServoJoints || !out) return 0;
  Out o{out, capacity};
  o.text("<Rob Type=\"KUKA\">");
  o.axes("AIPos", actual_deg, axes);
  o.axes("ASPos", setpoint_deg, axes);
  o.text("<IPOC>");
  o.number(ipoc);
  o.text("</IPOC></Rob>");
  return o.ok ? o.size : 0;
}

}  // namespace cellcal

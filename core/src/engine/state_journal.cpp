#include "cellcal/core/engine/state_journal.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <Eigen/Geometry>
#include <array>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <stdexcept>
#include <type_traits>

#include "cellcal/core/engine/state_file.hpp"
#include "cellcal/core/files/crc32.hpp"
#include "state_fields.hpp"
#include "write_all.hpp"

namespace cellcal {

namespace {

namespace fs = std::filesystem;

// Record: magic, payload length, CRC-32 of the payload, payload. The magic also tells the byte order.
constexpr std::uint32_t kRecordMagic = 0x314a4343;  // "CCJ1" read little-endian
constexpr std::uint32_t kPayloadFormat = 1;
constexpr std::size_t kHeaderBytes = 12;
constexpr std::uint32_t kMaxRecordBytes = 256u << 20;

class Writer {
 public:
  template <class T>
  void pod(T v) {
    static_assert(std::is_trivially_copyable_v<T>);
    out.append(reinterpret_cast<const char*>(&v), sizeof v);
  }
  void size(std::size_t n) { pod(static_cast<std::uint64_t>(n)); }
  void str(const std::string& s) {
    size(s.size());
    out.append(s);
  }
  void doubles(const double* p, std::size_t n) {
    size(n);
    out.append(reinterpret_cast<const char*>(p), n * sizeof(double));
  }
  void vec(const Eigen::VectorXd& v) { doubles(v.data(), static_cast<std::size_t>(v.size())); }
  void vec(const std::vector<double>& v) { doubles(v.data(), v.size()); }
  void ints(const std::vector<int>& v) {
    size(v.size());
    for (int x : v) pod(static_cast<std::int32_t>(x));
  }
  // A square matrix, column-major (as the JSON snapshot).
  void square(const Eigen::MatrixXd& m) {
    if (m.rows() != m.cols()) throw std::runtime_error("covariance is not square");
    doubles(m.data(), static_cast<std::size_t>(m.size()));
  }
  std::string out;
};

class Reader {
 public:
  explicit Reader(const std::string& b) : bytes(b) {}
  template <class T>
  T pod(const char* what) {
    T v;
    need(sizeof v, what);
    std::memcpy(&v, bytes.data() + at, sizeof v);
    at += sizeof v;
    return v;
  }
  // A count of items of `item_bytes` each: never more than what is left.
  std::size_t size(std::size_t item_bytes, const char* what) {
    const auto n = pod<std::uint64_t>(what);
    if (item_bytes > 0 && n > (bytes.size() - at) / item_bytes)
      throw std::runtime_error(std::string(what) + ": count " + std::to_string(n) + " beyond the record");
    return static_cast<std::size_t>(n);
  }
  std::string str(const char* what) {
    const std::size_t n = size(1, what);
    std::string s = bytes.substr(at, n);
    at += n;
    return s;
  }
  std::vector<double> doubles(const char* what) {
    const std::size_t n = size(sizeof(double), what);
    std::vector<double> v(n);
    if (n) std::memcpy(v.data(), bytes.data() + at, n * sizeof(double));
    at += n * sizeof(double);
    return v;
  }
  Eigen::VectorXd vec(const char* what) {
    const auto v = doubles(what);
    return Eigen::Map<const Eigen::VectorXd>(v.data(), static_cast<Eigen::Index>(v.size()));
  }
  std::vector<int> ints(const char* what) {
    const std::size_t n = size(sizeof(std::int32_t), what);
    std::vector<int> v(n);
    for (auto& x : v) x = pod<std::int32_t>(what);
    return v;
  }
  Eigen::MatrixXd square(const char* what) {
    const auto v = doubles(what);
    Eigen::Index n = 0;
    while (static_cast<std::size_t>(n * n) < v.size()) ++n;
    if (static_cast<std::size_t>(n * n) != v.size()) throw std::runtime_error(std::string(what) + " is not square");
    return Eigen::Map<const Eigen::MatrixXd>(v.data(), n, n);
  }
  bool flag(const char* what) {
    const auto b = pod<std::uint8_t>(what);
    if (b > 1) throw std::runtime_error(std::string(what) + ": not a flag");
    return b == 1;
  }
  void need(std::size_t n, const char* what) const {
    if (bytes.size() - at < n) throw std::runtime_error(std::string(what) + ": the record ends early");
  }
  bool done() const { return at == bytes.size(); }

 private:
  const std::string& bytes;
  std::size_t at = 0;
};

using state_fields::Presence;

// The journal's codecs (state_fields.hpp): the fields in the list's order, names only for messages.
class BinaryWriter {
 public:
  static constexpr bool kReads = false;
  explicit BinaryWriter(Writer& w) : w_(w) {}
  void text(const char*, std::string& v, Presence = Presence::kRequired) { w_.str(v); }
  template <class Stored, class T>
  void number(const char*, T& v, Presence = Presence::kRequired) { w_.pod(static_cast<Stored>(v)); }
  void flag(const char*, bool& v, Presence = Presence::kRequired) { w_.pod(static_cast<std::uint8_t>(v)); }
  void vec(const char*, Eigen::VectorXd& v, Presence = Presence::kRequired) { w_.vec(v); }
  void doubles(const char*, std::vector<double>& v, Presence = Presence::kRequired) { w_.vec(v); }
  void ints(const char*, std::vector<int>& v, Presence = Presence::kRequired) { w_.ints(v); }
  void square(const char*, Eigen::MatrixXd& v, Presence = Presence::kRequired) { w_.square(v); }
  void texts(const char*, std::vector<std::string>& v, Presence = Presence::kRequired) {
    w_.size(v.size());
    for (const auto& x : v) w_.str(x);
  }
  template <class E>
  void choice(const char*, E& v, std::initializer_list<const char*>, Presence = Presence::kRequired) {
    w_.pod(static_cast<std::uint8_t>(v));
  }
  template <class E>
  void choice(const char* n, std::optional<E>& v, std::initializer_list<const char*> names, Presence p) {
    w_.pod(static_cast<std::uint8_t>(v.has_value()));
    if (v) choice(n, *v, names, p);
  }
  template <class T, class F>
  void object(const char*, std::optional<T>& v, F fields, Presence = Presence::kOptional) {
    w_.pod(static_cast<std::uint8_t>(v.has_value()));
    if (v) fields(*this, *v);
  }
  template <class Seq, class F>
  void objects(const char*, Seq& v, std::size_t, F fields, Presence = Presence::kRequired) {
    w_.size(v.size());
    for (auto& x : v) fields(*this, x);
  }
  template <class Seq, class F>
  void tuples(const char* n, Seq& v, std::size_t bytes, F fields) { objects(n, v, bytes, fields); }
  template <class T, class F>
  void tuple(const char*, T& v, F fields) { fields(*this, v); }
  // The pose whole (translation, rotation matrix column-major): a record restores it bit for bit, where the snapshot
  // keeps its quaternion.
  void pose(Pose& T) {
    const Eigen::Matrix4d m = T.matrix();
    for (int c = 0; c < 4; ++c)
      for (int r = 0; r < 3; ++r) w_.pod(m(r, c));
  }

 private:
  Writer& w_;
};

class BinaryReader {
 public:
  static constexpr bool kReads = true;
  explicit BinaryReader(Reader& r) : r_(r) {}
  void text(const char* n, std::string& v, Presence p = Presence::kRequired) {
    if (present(p)) v = r_.str(n);
  }
  template <class Stored, class T>
  void number(const char* n, T& v, Presence p = Presence::kRequired) {
    if (present(p)) v = static_cast<T>(r_.pod<Stored>(n));
  }
  void flag(const char* n, bool& v, Presence p = Presence::kRequired) {
    if (present(p)) v = r_.flag(n);
  }
  void vec(const char* n, Eigen::VectorXd& v, Presence p = Presence::kRequired) {
    if (present(p)) v = r_.vec(n);
  }
  void doubles(const char* n, std::vector<double>& v, Presence p = Presence::kRequired) {
    if (present(p)) v = r_.doubles(n);
  }
  void ints(const char* n, std::vector<int>& v, Presence p = Presence::kRequired) {
    if (present(p)) v = r_.ints(n);
  }
  void square(const char* n, Eigen::MatrixXd& v, Presence p = Presence::kRequired) {
    if (present(p)) v = r_.square(n);
  }
  void texts(const char* n, std::vector<std::string>& v, Presence p = Presence::kRequired) {
    if (!present(p)) return;
    const std::size_t k = r_.size(8, n);
    for (std::size_t i = 0; i < k; ++i) v.push_back(r_.str(n));
  }
  template <class E>
  void choice(const char* n, E& v, std::initializer_list<const char*> names, Presence p = Presence::kRequired) {
    if (!present(p)) return;
    const auto x = r_.pod<std::uint8_t>(n);
    if (x >= names.size()) throw std::runtime_error(std::string(n) + ": unknown value " + std::to_string(x));
    v = static_cast<E>(x);
  }
  template <class E>
  void choice(const char* n, std::optional<E>& v, std::initializer_list<const char*> names, Presence p) {
    if (!present(p) || !r_.flag(n)) return;
    E e{};
    choice(n, e, names);
    v = e;
  }
  template <class T, class F>
  void object(const char* n, std::optional<T>& v, F fields, Presence p = Presence::kOptional) {
    if (!present(p) || !r_.flag(n)) return;
    T x{};
    fields(*this, x);
    v = std::move(x);
  }
  template <class Seq, class F>
  void objects(const char* n, Seq& v, std::size_t bytes, F fields, Presence p = Presence::kRequired) {
    if (!present(p)) return;
    const std::size_t k = r_.size(bytes, n);
    for (std::size_t i = 0; i < k; ++i) {
      typename Seq::value_type x{};
      fields(*this, x);
      v.push_back(std::move(x));
    }
  }
  template <class Seq, class F>
  void tuples(const char* n, Seq& v, std::size_t bytes, F fields) { objects(n, v, bytes, fields); }
  template <class T, class F>
  void tuple(const char*, T& v, F fields) { fields(*this, v); }
  void pose(Pose& T) {
    T = Pose::Identity();
    Eigen::Matrix4d& m = T.matrix();
    for (int c = 0; c < 4; ++c)
      for (int k = 0; k < 3; ++k) m(k, c) = r_.pod<double>("pose");
  }

 private:
  // A field appended since the first records is absent from a record that ends before it.
  bool present(Presence p) const { return p != Presence::kAppended || !r_.done(); }
  Reader& r_;
};

// The whole file; "" when there is none.
std::string readWholeFile(const std::string& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) {
    if (errno == ENOENT) return "";
    throw std::runtime_error(path + ": cannot open: " + std::strerror(errno));
  }
  std::string data;
  char buf[1 << 16];
  for (;;) {
    const ssize_t k = ::read(fd, buf, sizeof buf);
    if (k < 0) {
      if (errno == EINTR) continue;
      const std::string err = std::strerror(errno);
      ::close(fd);
      throw std::runtime_error(path + ": read failed: " + err);
    }
    if (k == 0) break;
    data.append(buf, static_cast<std::size_t>(k));
  }
  ::close(fd);
  return data;
}

}  // namespace

std::string stateJournalPath(const std::string& state_file) {
  return fs::path(state_file).replace_extension(".journal").string();
}

std::string engineStateToBinary(const EngineState& s) {
  Writer w;
  w.pod(kPayloadFormat);
  BinaryWriter bw(w);
  state_fields::writeFields(bw, s);
  return std::move(w.out);
}

EngineState engineStateFromBinary(const std::string& bytes) {
  Reader r(bytes);
  const auto format = r.pod<std::uint32_t>("format");
  if (format != kPayloadFormat) throw std::runtime_error("unknown record format " + std::to_string(format));
  EngineState s;
  BinaryReader br(r);
  state_fields::engineState(br, s);
  if (!r.done()) throw std::runtime_error("bytes after the state");
  return s;
}

LoadedState loadDurableState(const std::string& state_file) {
  LoadedState out;
  out.state = loadEngineState(state_file);
  const std::string journal = stateJournalPath(state_file);
  const std::string data = readWholeFile(journal);
  std::size_t at = 0;
  while (at < data.size()) {
    std::string why;
    std::uint32_t head[3] = {0, 0, 0};
    if (data.size() - at < kHeaderBytes) {
      why = "a record header cut short";
    } else {
      std::memcpy(head, data.data() + at, kHeaderBytes);
      if (head[0] != kRecordMagic)
        why = "no record starts here";
      else if (head[1] > kMaxRecordBytes || head[1] > data.size() - at - kHeaderBytes)
        why = "a record cut short";
      else if (crc32(data.data() + at + kHeaderBytes, head[1]) != head[2])
        why = "a record whose CRC-32 does not match";
    }
    if (why.empty()) {
      try {
        out.state = engineStateFromBinary(data.substr(at + kHeaderBytes, head[1]));
      } catch (const std::runtime_error& e) {
        // The CRC matched: not a torn write but a record this version cannot read.
        throw std::runtime_error(unusableStateMessage(journal, "record " + std::to_string(out.journal_records + 1) +
                                                                   " at byte " + std::to_string(at) + ": " + e.what()));
      }
      ++out.journal_records;
      at += kHeaderBytes + head[1];
      continue;
    }
    out.torn_bytes = data.size() - at;
    out.torn_reason = why + " at byte " + std::to_string(at);
    break;
  }
  return out;
}

DurableState::DurableState(std::string state_file, Options options)
    : state_file_(std::move(state_file)), journal_file_(stateJournalPath(state_file_)), options_(options) {}

DurableState::~DurableState() {
  if (fd_ >= 0) ::close(fd_);
}

const std::string& DurableState::savedPath() const {
  return options_.durability == Durability::kJournal ? journal_file_ : state_file_;
}

std::optional<EngineState> DurableState::load() {
  LoadedState l = loadDurableState(state_file_);
  // Later records must never follow a torn one: what was read becomes the snapshot, the journal starts empty.
  if (l.state && (l.journal_records > 0 || l.torn_bytes > 0)) compact(*l.state);
  else if (!l.state && l.torn_bytes > 0) fs::remove(journal_file_);  // a first record cut short: nothing was published
  return std::move(l.state);
}

void DurableState::openJournal() {
  if (fd_ >= 0) return;
  std::error_code ec;
  const fs::path dir = fs::path(journal_file_).parent_path();
  if (!dir.empty()) fs::create_directories(dir, ec);
  fd_ = ::open(journal_file_.c_str(), O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
  if (fd_ < 0) throw std::runtime_error(journal_file_ + ": cannot open for appending: " + std::strerror(errno));
  struct stat st {};
  journal_bytes_ = ::fstat(fd_, &st) == 0 ? static_cast<std::uint64_t>(st.st_size) : 0;
}

void DurableState::save(const EngineState& state) {
  if (options_.durability == Durability::kSnapshot) {
    saveEngineState(state_file_, state);
    return;
  }
  openJournal();
  const std::string payload = engineStateToBinary(state);
  std::string record(kHeaderBytes, '\0');
  const std::uint32_t head[3] = {kRecordMagic, static_cast<std::uint32_t>(payload.size()),
                                 crc32(payload.data(), payload.size())};
  std::memcpy(record.data(), head, kHeaderBytes);
  record += payload;
  try {
    detail::writeAll(fd_, record.data(), record.size(), journal_file_);
  } catch (...) {
    // A partial record (disk full): cut it off so the next one follows whole records.
    if (::ftruncate(fd_, static_cast<off_t>(journal_bytes_)) != 0) {
      ::close(fd_);
      fd_ = -1;
    }
    throw;
  }
  journal_bytes_ += record.size();
}

bool DurableState::compactionDue() const {
  return options_.durability == Durability::kJournal && journal_bytes_ >= options_.compact_after_bytes;
}

void DurableState::compact(const EngineState& state) {
  // While running, `state` may be newer than the last record (a failed save): it becomes the last record first, so
  // a crash before the journal is emptied still reads it last.
  if (fd_ >= 0) save(state);
  saveEngineState(state_file_, state);  // atomic: the journal still holds the same state until it is emptied
  syncStateFile(state_file_);           // on disk before the records that led to it go
  if (fd_ >= 0) {
    if (::ftruncate(fd_, 0) != 0) throw std::runtime_error(journal_file_ + ": cannot empty: " + std::strerror(errno));
  } else if (::truncate(journal_file_.c_str(), 0) != 0 && errno != ENOENT) {
    throw std::runtime_error(journal_file_ + ": cannot empty: " + std::strerror(errno));
  }
  journal_bytes_ = 0;
  ++compactions_;
}

void DurableState::close(const EngineState& state) {
  if (options_.durability == Durability::kJournal && journal_bytes_ > 0) compact(state);
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

}  // namespace cellcal

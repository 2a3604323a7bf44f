// What the host's kernel allows a DDS process, read from /proc (Linux). Fast DDS asks for the UDP socket buffers
// its transport descriptor names (config/dds/cellcal_qos.xml: 4 MiB); Linux silently caps SO_RCVBUF/SO_SNDBUF at
// net.core.rmem_max / wmem_max (212992 bytes by default). A capped receive buffer holds ~20 ms of 8 robots at 1 kHz,
// so any stall of the host longer than that drops best-effort samples in the kernel (counted in /proc/net/snmp
// Udp RcvbufErrors). config/sysctl/60-cellcal.conf raises the caps; docs/deployment.md says where it goes.
#pragma once

#include <cstdint>
#include <optional>
#include <string>

namespace cellcal::components {

// A number from a /proc/sys file (e.g. "/proc/sys/net/core/rmem_max"); nullopt when it cannot be read.
std::optional<std::int64_t> readKernelLimit(const std::string& proc_file);

// The warning for a transport that asks for socket buffers above the kernel's caps, or "" when nothing is capped
// (a size of 0 means "the OS default" and is never capped; an unknown cap is not judged).
std::string socketBufferWarning(const std::string& transport, std::uint32_t receive_bytes, std::uint32_t send_bytes,
                                std::optional<std::int64_t> rmem_max, std::optional<std::int64_t> wmem_max);

// Udp RcvbufErrors of /proc/net/snmp (datagrams the kernel dropped because a socket's receive buffer was full, in
// this network namespace since boot); nullopt when it cannot be read. `snmp_file` is for tests.
std::optional<std::uint64_t> udpReceiveBufferErrors(const std::string& snmp_file = "/proc/net/snmp");

}  // namespace cellcal::components

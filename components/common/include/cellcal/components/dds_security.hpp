// DDS Security files of one identity (the folder config/security/make_pki.sh fills; docs/SECURITY.md):
//   ca.cert.pem, <identity>.cert.pem, <identity>.key.pem, governance.p7s, permissions.p7s.
// Fast DDS enforces them; this only explains, after Fast DDS refused a participant, which file is at fault (Fast DDS
// 2.9 logs nothing for most of these). It checks what Fast DDS checks, never more: every result it returns is a
// reason Fast DDS would refuse too.
#pragma once

#include <string>

namespace cellcal::components {

// The first problem found, as "<file>: <what>", or "" when every check passes: a file missing or unreadable, the
// certificate not issued by the CA or out of its validity, governance/permissions not signed by the CA (or altered
// since), no grant in the permissions whose subject is the certificate's.
std::string explainSecurityRefusal(const std::string& security_dir, const std::string& identity);

// The certificate's subject as RFC 2253 ("CN=calibration_engine,O=cellcal"); throws naming the file.
std::string certificateSubject(const std::string& cert_pem_file);

}  // namespace cellcal::components

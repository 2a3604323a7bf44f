#include "cellcal/components/dds_security.hpp"

#include <openssl/bio.h>
#include <openssl/err.h>
#include <openssl/pem.h>
#include <openssl/pkcs7.h>
#include <openssl/x509.h>
#include <openssl/x509_vfy.h>

#include <filesystem>
#include <memory>
#include <stdexcept>

namespace cellcal::components {

namespace {

template <class T, void (*F)(T*)>
struct Free {
  void operator()(T* p) const { F(p); }
};
using Bio = std::unique_ptr<BIO, Free<BIO, BIO_free_all>>;
using X509Ptr = std::unique_ptr<X509, Free<X509, X509_free>>;
using Store = std::unique_ptr<X509_STORE, Free<X509_STORE, X509_STORE_free>>;
using StoreCtx = std::unique_ptr<X509_STORE_CTX, Free<X509_STORE_CTX, X509_STORE_CTX_free>>;
using Pkcs7 = std::unique_ptr<PKCS7, Free<PKCS7, PKCS7_free>>;

std::string opensslError() {
  const unsigned long e = ERR_get_error();
  ERR_clear_error();
  if (e == 0) return "unknown OpenSSL error";
  char buf[256];
  ERR_error_string_n(e, buf, sizeof buf);
  return buf;
}

X509Ptr readCert(const std::string& file) {
  Bio bio(BIO_new_file(file.c_str(), "r"));
  if (!bio) throw std::runtime_error(file + ": cannot be read");
  X509Ptr cert(PEM_read_bio_X509(bio.get(), nullptr, nullptr, nullptr));
  if (!cert) throw std::runtime_error(file + ": not a PEM certificate (" + opensslError() + ")");
  return cert;
}

std::string subjectOf(X509* cert) {
  Bio out(BIO_new(BIO_s_mem()));
  X509_NAME_print_ex(out.get(), X509_get_subject_name(cert), 0, XN_FLAG_RFC2253);
  char* data = nullptr;
  const long n = BIO_get_mem_data(out.get(), &data);
  return std::string(data, static_cast<size_t>(n));
}

std::string withoutSpaces(std::string s) {
  std::string o;
  for (char c : s)
    if (c != ' ' && c != '\t' && c != '\n' && c != '\r') o += c;
  return o;
}

// Verifies an S/MIME document signed by the CA; returns its text or throws naming the file.
std::string verifiedText(const std::string& file, X509_STORE* store) {
  Bio in(BIO_new_file(file.c_str(), "r"));
  if (!in) throw std::runtime_error(file + ": cannot be read");
  BIO* content = nullptr;
  Pkcs7 p7(SMIME_read_PKCS7(in.get(), &content));
  Bio content_owner(content);
  if (!p7) throw std::runtime_error(file + ": not an S/MIME signed document (" + opensslError() + ")");
  Bio out(BIO_new(BIO_s_mem()));
  if (PKCS7_verify(p7.get(), nullptr, store, content, out.get(), PKCS7_TEXT) != 1)
    throw std::runtime_error(file + ": its signature does not verify against ca.cert.pem (altered after signing, "
                             "or signed by another CA: " + opensslError() + ")");
  char* data = nullptr;
  const long n = BIO_get_mem_data(out.get(), &data);
  return std::string(data, static_cast<size_t>(n));
}

}  // namespace

std::string certificateSubject(const std::string& cert_pem_file) { return subjectOf(readCert(cert_pem_file).get()); }

std::string explainSecurityRefusal(const std::string& security_dir, const std::string& identity) try {
  const std::filesystem::path d(security_dir);
  const std::string ca_file = (d / "ca.cert.pem").string(), cert_file = (d / (identity + ".cert.pem")).string();
  const std::string key_file = (d / (identity + ".key.pem")).string();
  X509Ptr ca = readCert(ca_file);
  X509Ptr cert = readCert(cert_file);
  {
    Bio bio(BIO_new_file(key_file.c_str(), "r"));
    if (!bio) return key_file + ": cannot be read";
    std::unique_ptr<EVP_PKEY, Free<EVP_PKEY, EVP_PKEY_free>> key(PEM_read_bio_PrivateKey(bio.get(), nullptr, nullptr, nullptr));
    if (!key) return key_file + ": not an unencrypted PEM private key (" + opensslError() + ")";
    if (X509_check_private_key(cert.get(), key.get()) != 1) return key_file + ": not the key of " + cert_file;
  }
  Store store(X509_STORE_new());
  X509_STORE_add_cert(store.get(), ca.get());
  StoreCtx ctx(X509_STORE_CTX_new());
  X509_STORE_CTX_init(ctx.get(), store.get(), cert.get(), nullptr);
  if (X509_verify_cert(ctx.get()) != 1)
    return cert_file + ": " + X509_verify_cert_error_string(X509_STORE_CTX_get_error(ctx.get())) +
           " (checked against " + ca_file + ")";
  verifiedText((d / "governance.p7s").string(), store.get());
  const std::string permissions = verifiedText((d / "permissions.p7s").string(), store.get());
  const std::string subject = subjectOf(cert.get());
  for (size_t at = permissions.find("<subject_name>"); at != std::string::npos;
       at = permissions.find("<subject_name>", at + 1)) {
    const size_t b = at + std::string("<subject_name>").size(), e = permissions.find("</subject_name>", b);
    if (e != std::string::npos && withoutSpaces(permissions.substr(b, e - b)) == withoutSpaces(subject)) return "";
  }
  return (d / "permissions.p7s").string() + ": no grant for " + subject + " (the subject of " + cert_file + ")";
} catch (const std::exception& e) {
  return e.what();
}

}  // namespace cellcal::components

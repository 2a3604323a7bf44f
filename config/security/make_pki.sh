#!/usr/bin/env bash
# Makes the DDS Security files of a cell in OUT_DIR (docs/SECURITY.md):
#   ca.cert.pem, ca.key.pem            a CA (identity and permissions CA at once); keep ca.key.pem off the cell
#   <identity>.cert.pem / .key.pem     one certificate per identity of permissions.xml (CN=<identity>, O=<org>),
#                                      plus any --identity NAME (a certificate with no grant)
#   governance.p7s, permissions.p7s    governance.xml and permissions.xml signed by the CA
# A cell uses it with dds.security_dir: OUT_DIR in the cell file, or CELLCAL_SECURITY_DIR=OUT_DIR.
# This is a test CA for one cell; a plant with its own PKI signs the same two XML files and issues the same subjects.
set -euo pipefail

usage() {
  echo "usage: $0 OUT_DIR [--org NAME] [--days N] [--identity NAME]..." >&2
  exit 2
}
[[ $# -ge 1 ]] || usage
out=$1
shift
org=cellcal
days=365
extra=()
while [[ $# -gt 0 ]]; do
  case $1 in
    --org) org=${2:?}; shift 2 ;;
    --days) days=${2:?}; shift 2 ;;
    --identity) extra+=("${2:?}"); shift 2 ;;
    *) usage ;;
  esac
done
[[ $org =~ ^[A-Za-z0-9_.-]+$ ]] || { echo "$0: --org '$org': letters, digits, _ . - only" >&2; exit 2; }
[[ $days =~ ^[0-9]+$ && $days -ge 1 ]] || { echo "$0: --days '$days': a whole number of days >= 1" >&2; exit 2; }
command -v openssl >/dev/null || { echo "$0: openssl is not installed (apt-get install openssl)" >&2; exit 1; }

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
mkdir -p "$out"
umask 077
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

openssl ecparam -name prime256v1 -genkey -noout -out "$out/ca.key.pem"
openssl req -x509 -new -sha256 -key "$out/ca.key.pem" -days "$days" -subj "/O=$org/CN=${org} cell CA" \
  -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign,digitalSignature" \
  -out "$out/ca.cert.pem" 2>/dev/null

printf 'basicConstraints=CA:FALSE\nkeyUsage=critical,digitalSignature,keyAgreement\n' >"$tmp/leaf.ext"
identities=($(sed -n 's/.*<grant name="\([^"]*\)">.*/\1/p' "$here/permissions.xml") "${extra[@]+"${extra[@]}"}")
for id in "${identities[@]}"; do
  [[ $id =~ ^[A-Za-z0-9_.-]+$ ]] || { echo "$0: identity '$id': letters, digits, _ . - only" >&2; exit 2; }
  openssl ecparam -name prime256v1 -genkey -noout -out "$out/$id.key.pem"
  openssl req -new -sha256 -key "$out/$id.key.pem" -subj "/O=$org/CN=$id" -out "$tmp/$id.csr"
  openssl x509 -req -sha256 -in "$tmp/$id.csr" -CA "$out/ca.cert.pem" -CAkey "$out/ca.key.pem" \
    -set_serial "0x$(openssl rand -hex 8)" -days "$days" -extfile "$tmp/leaf.ext" -out "$out/$id.cert.pem" 2>/dev/null
done

not_before=$(date -u -d '-1 day' +%Y-%m-%dT%H:%M:%S)
not_after=$(date -u -d "+$days days" +%Y-%m-%dT%H:%M:%S)
sed -e "s/@SUBJECT_ORG@/$org/g" -e "s/@NOT_BEFORE@/$not_before/g" -e "s/@NOT_AFTER@/$not_after/g" \
  "$here/permissions.xml" >"$tmp/permissions.xml"
for doc in governance permissions; do
  src=$here/$doc.xml
  [[ $doc == permissions ]] && src=$tmp/permissions.xml
  openssl smime -sign -text -in "$src" -signer "$out/ca.cert.pem" -inkey "$out/ca.key.pem" -out "$out/$doc.p7s"
done
# Check what a participant will check: every certificate chains to the CA, both documents verify against it.
for id in "${identities[@]}"; do
  openssl verify -CAfile "$out/ca.cert.pem" "$out/$id.cert.pem" >/dev/null
done
for doc in governance permissions; do
  openssl smime -verify -text -in "$out/$doc.p7s" -CAfile "$out/ca.cert.pem" -out /dev/null 2>/dev/null ||
    { echo "$0: $out/$doc.p7s does not verify against $out/ca.cert.pem" >&2; exit 1; }
done
chmod 644 "$out"/*.cert.pem "$out"/*.p7s
echo "DDS Security files for ${#identities[@]} identities (O=$org, valid $days days) in $out"

#!/bin/sh
# Make a throwaway certificate authority, the router's certificate and one client
# certificate per role (mutual TLS), and a password per role (user/password
# authentication), for the configs of deploy/secure/ (docs/operations.md).
#
#   sh deploy/secure/make-certs.sh [DIR] [ROUTER_NAME ...]
#
# DIR (default deploy/secure/certs) gets ca.pem, router.pem/router-key.pem, and
# <role>.pem/<role>-key.pem for the roles track-service, track-feed, track-viewer,
# track-intercept (each certificate's common name is its role: the access-control
# policy names them), plus
# credentials.txt ("user:password" per line: the router's dictionary) and
# <role>.password. The router's certificate names ROUTER_NAME... (default: router,
# localhost and 127.0.0.1), the names clients connect to. Keep ca-key.pem offline.
set -eu
dir=${1:-deploy/secure/certs}
if [ $# -gt 0 ]; then shift; fi  # (a bare shift with no argument ends dash)
[ $# -gt 0 ] || set -- router localhost 127.0.0.1
mkdir -p "$dir"
cd "$dir"
umask 077
days=825

openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes -sha256 \
  -days 3650 -subj "/CN=track-ca" -keyout ca-key.pem -out ca.pem \
  -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign" \
  2>/dev/null

sign() {  # name, common name, subjectAltName, extendedKeyUsage
  openssl req -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes -sha256 \
    -subj "/CN=$2" -keyout "$1-key.pem" -out "$1.csr" 2>/dev/null
  printf 'basicConstraints=critical,CA:FALSE\nkeyUsage=critical,digitalSignature\nextendedKeyUsage=%s\nsubjectAltName=%s\n' \
    "$4" "$3" > "$1.ext"
  openssl x509 -req -in "$1.csr" -CA ca.pem -CAkey ca-key.pem -CAcreateserial -sha256 \
    -days "$days" -extfile "$1.ext" -out "$1.pem" 2>/dev/null
  rm -f "$1.csr" "$1.ext"
}

san=""
for name in "$@"; do
  case $name in
    *[!0-9.]*) entry="DNS:$name" ;;
    *) entry="IP:$name" ;;
  esac
  san="${san:+$san,}$entry"
done
sign router track-router "$san" serverAuth
: > credentials.txt
for role in track-service track-feed track-viewer track-intercept; do
  sign "$role" "$role" "DNS:$role" clientAuth
  pw=$(openssl rand -hex 16)
  printf '%s' "$pw" > "$role.password"
  printf '%s:%s\n' "$role" "$pw" >> credentials.txt
done
rm -f ca.srl
echo "made in $dir: ca.pem, router.pem, track-service.pem, track-feed.pem, track-viewer.pem, track-intercept.pem (+ keys), credentials.txt"

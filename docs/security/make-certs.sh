#!/bin/sh
# armd: a throwaway certificate authority and a router certificate, for TLS between Zenoh sessions.
# Usage: sh docs/security/make-certs.sh [DIR] [HOST]   (default: certs, localhost)
# Writes DIR/ca.pem (give it to every client: root_ca_certificate), DIR/router.pem and
# DIR/router.key (the router's: listen_certificate, listen_private_key). DIR/ca.key signs more
# certificates: keep it off the machines. The router certificate names HOST, localhost and
# 127.0.0.1; clients must connect to one of those names (tls/HOST:7448). For a real deployment,
# use your organisation's CA, or at least keep this CA's key offline.
set -eu
dir=${1:-certs}
host=${2:-localhost}
mkdir -p "$dir"
openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes -days 365 \
    -keyout "$dir/ca.key" -out "$dir/ca.pem" -subj "/CN=armd CA" 2>/dev/null
openssl req -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes \
    -keyout "$dir/router.key" -out "$dir/router.csr" -subj "/CN=$host" 2>/dev/null
printf 'subjectAltName=DNS:%s,DNS:localhost,IP:127.0.0.1\nbasicConstraints=CA:FALSE\nextendedKeyUsage=serverAuth\n' \
    "$host" > "$dir/router.ext"
openssl x509 -req -in "$dir/router.csr" -CA "$dir/ca.pem" -CAkey "$dir/ca.key" -CAcreateserial -days 365 \
    -extfile "$dir/router.ext" -out "$dir/router.pem" 2>/dev/null
rm -f "$dir/router.csr" "$dir/router.ext" "$dir/ca.srl"
echo "wrote $dir/ca.pem, $dir/router.pem, $dir/router.key (and $dir/ca.key: keep it safe)"

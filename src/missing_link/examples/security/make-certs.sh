#!/bin/sh
# A ready mutual-TLS setup for the daemon's Zenoh face (docs/security.md):
#   examples/security/make-certs.sh OUTDIR [PORT]
# writes into OUTDIR a certificate authority (ca.pem, ca.key) and a key and certificate for each
# of daemon, operator and viewer (their common names), and three ready files with absolute paths:
#   daemon.toml    the daemon publishing to Zenoh on tls/127.0.0.1:PORT (default 7448) only,
#                  clients must show a certificate from this CA (mutual TLS), and daemon.json5,
#                  its native Zenoh config: the certificates and the access control (viewer may
#                  not put on command keys; operator may)
#   operator.json5 a client session for plain eclipse-zenoh or rmw_zenoh that may command
#   viewer.json5   a client session that receives every topic but whose commands are refused
# Run a board with it:  missing-link run --config OUTDIR/daemon.toml serial:///dev/ttyACM0
# Keep ca.key offline: whoever has it can make an operator.  Needs openssl.
set -eu
out=${1:?usage: make-certs.sh OUTDIR [PORT]}
port=${2:-7448}
command -v openssl >/dev/null || { echo "make-certs.sh: openssl is required" >&2; exit 1; }
mkdir -p "$out"
out=$(cd "$out" && pwd)
days=825
openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes -days 3650 \
    -keyout "$out/ca.key" -out "$out/ca.pem" -subj "/CN=missing-link CA" 2>/dev/null
for who in daemon operator viewer; do
    openssl req -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes \
        -keyout "$out/$who.key" -out "$out/$who.csr" -subj "/CN=$who" 2>/dev/null
    printf 'subjectAltName=DNS:localhost,IP:127.0.0.1\nextendedKeyUsage=serverAuth,clientAuth\n' \
        > "$out/$who.ext"
    openssl x509 -req -in "$out/$who.csr" -CA "$out/ca.pem" -CAkey "$out/ca.key" \
        -CAcreateserial -days $days -out "$out/$who.pem" -extfile "$out/$who.ext" 2>/dev/null
    rm -f "$out/$who.csr" "$out/$who.ext"
done
chmod 600 "$out"/*.key

cat > "$out/daemon.json5" <<JSON
// The daemon's native Zenoh config (missing-link merges its own keys on top: mode, endpoints).
{
  transport: {
    link: {
      tls: {
        root_ca_certificate: "$out/ca.pem",
        listen_private_key: "$out/daemon.key",
        listen_certificate: "$out/daemon.pem",
        enable_mtls: true,
        connect_private_key: "$out/daemon.key",
        connect_certificate: "$out/daemon.pem",
      },
    },
  },
  access_control: {
    enabled: true,
    default_permission: "allow",
    rules: [
      {
        id: "commands",
        permission: "deny",
        flows: ["ingress"],
        messages: ["put", "delete"],
        key_exprs: ["*/**/cmd/**"],
      },
    ],
    subjects: [{ id: "viewer", cert_common_names: ["viewer"] }],
    policies: [{ rules: ["commands"], subjects: ["viewer"] }],
  },
}
JSON

for who in operator viewer; do
    cat > "$out/$who.json5" <<JSON
// A Zenoh client session as "$who" (eclipse-zenoh: zenoh.Config.from_file; rmw_zenoh:
// ZENOH_SESSION_CONFIG_URI=$out/$who.json5).
{
  mode: "client",
  connect: { endpoints: ["tls/127.0.0.1:$port"] },
  scouting: { multicast: { enabled: false } },
  transport: {
    link: {
      tls: {
        root_ca_certificate: "$out/ca.pem",
        connect_private_key: "$out/$who.key",
        connect_certificate: "$out/$who.pem",
        enable_mtls: true,
      },
    },
  },
}
JSON
done

cat > "$out/daemon.toml" <<TOML
# missing-link run --config $out/daemon.toml URL...   (docs/security.md)
[daemon]
publishers = ["bus", "zenoh"]

[zenoh]
listen = ["tls/127.0.0.1:$port"]   # mutual TLS: only clients with a certificate of this CA
connect = []
config = "$out/daemon.json5"        # the certificates and the access control
commands = true                      # the ACL decides who may command (viewer may not)
TOML
echo "wrote $out: ca.pem, daemon/operator/viewer .pem and .key, daemon.toml, daemon.json5, operator.json5, viewer.json5"

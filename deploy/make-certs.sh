#!/usr/bin/env bash
# Make a local test CA, one key + certificate per kinesphere role and one per robot, for the
# TLS configs.
#
# Why: the router and every service authenticate each other with mutual TLS, and the
# router's access control tells roles apart by certificate common name (CN = role name),
# robots by theirs (CN = robot id: a robot may speak only for itself) and operators by
# theirs (CN = the operator's name: robots lease to it and take e-stop releases from it, so
# nobody may command under another's name); see robots.toml.
# This is a test/lab PKI: for production, issue the same CNs from your own CA.
#
# usage: deploy/make-certs.sh [OUT_DIR] [EXTRA_ROUTER_NAME ...]
#   OUT_DIR            where to write (default: deploy/certs)
#   EXTRA_ROUTER_NAME  host names or IP addresses the router is reached by, besides
#                      localhost and 127.0.0.1 (clients verify the router's name)
# env: DAYS (validity, default 825), ROLES (default "router databank operator superuser"),
#      ROBOTS (robot ids, e.g. "baxter-1 nao-1": the ids of robots.toml; default none),
#      OPERATORS (operators' names, e.g. "alice bob": the [operators] of robots.toml)
#
# Writes OUT_DIR/ca.pem (the CA certificate every config trusts), ca.key (keep it
# offline), <role>.pem + <role>.key for each role, robots/<id>.pem + robots/<id>.key for
# each robot and operators/<name>.pem + .key for each operator. Existing files are kept, so
# re-running only adds what is missing (a new robot: ROBOTS=arm-7 deploy/make-certs.sh
# certs); delete OUT_DIR to start over.
set -euo pipefail

out=${1:-"$(dirname "$0")/certs"}
shift || true
days=${DAYS:-825}
roles=${ROLES:-"router databank operator superuser"}
robots=${ROBOTS:-}
operators=${OPERATORS:-}
reserved=" router databank agent operator superuser anonymous "
for id in $robots $operators; do
    # a name is a key segment of at most 64 characters, and never a role's name
    if [[ ! $id =~ ^[A-Za-z0-9_.-]{1,64}$ || $reserved == *" $id "* ]]; then
        echo "make-certs: bad robot id or operator name '$id' (letters, digits, _ . -, at" \
            "most 64, not a role)" >&2
        exit 2
    fi
done
command -v openssl >/dev/null || { echo "make-certs: openssl not found" >&2; exit 1; }

mkdir -p "$out"
umask 077

if [[ ! -s "$out/ca.pem" ]]; then
    openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$out/ca.key" 2>/dev/null
    openssl req -x509 -new -key "$out/ca.key" -sha256 -days "$days" \
        -subj "/O=kinesphere/CN=kinesphere test CA" \
        -addext "basicConstraints=critical,CA:TRUE" \
        -addext "keyUsage=critical,keyCertSign,cRLSign" \
        -out "$out/ca.pem"
    echo "made CA $out/ca.pem"
fi

san="DNS:localhost,IP:127.0.0.1"
for name in "$@"; do
    if [[ $name =~ ^[0-9.]+$ || $name == *:* ]]; then san+=",IP:$name"; else san+=",DNS:$name"; fi
done

# sign PATH SUBJECT USAGE [SAN]: a key (PATH.key) and a certificate (PATH.pem) for SUBJECT,
# signed by the CA, with extendedKeyUsage USAGE (and subjectAltName SAN)
sign() {
    local path=$1 subject=$2 usage=$3 san=${4:-} ext
    ext=$(mktemp)
    {
        echo "basicConstraints=critical,CA:FALSE"
        echo "keyUsage=critical,digitalSignature,keyEncipherment"
        echo "extendedKeyUsage=$usage"
        if [[ -n $san ]]; then echo "subjectAltName=$san"; fi
    } >"$ext"
    openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$path.key" 2>/dev/null
    openssl req -new -key "$path.key" -subj "$subject" -out "$path.csr"
    openssl x509 -req -in "$path.csr" -CA "$out/ca.pem" -CAkey "$out/ca.key" \
        -CAcreateserial -days "$days" -sha256 -extfile "$ext" -out "$path.pem" 2>/dev/null
    rm -f "$path.csr" "$ext"
}

for role in $roles; do
    [[ -s "$out/$role.pem" ]] && continue
    # Every role may both listen and connect (peers do both), so allow both usages.
    # The CN is the role: the router's access_control matches it (cert_common_names).
    sign "$out/$role" "/O=kinesphere/CN=$role" serverAuth,clientAuth "DNS:$role,$san"
    echo "made $role: $out/$role.pem (CN=$role)"
done
# client_cert DIR KIND NAME: a certificate for one robot or operator (CN = NAME), which
# only connects (to the router), so client authentication is all it needs
client_cert() {
    local dir=$1 kind=$2 id=$3
    mkdir -p "$out/$dir"
    [[ -s "$out/$dir/$id.pem" ]] && return 0
    sign "$out/$dir/$id" "/O=kinesphere/OU=$kind/CN=$id" clientAuth
    chmod 644 "$out/$dir/$id.pem"
    echo "made $kind $id: $out/$dir/$id.pem (CN=$id)"
}
for id in $robots; do client_cert robots robot "$id"; done
for id in $operators; do client_cert operators operator "$id"; done
rm -f "$out/ca.srl"
chmod 644 "$out"/*.pem

#!/usr/bin/env bash
# Makes everything DDS Security needs for one farm: a certificate authority, a certificate and key
# per participant, and the governance and permissions documents signed by the CA.
#
#   deploy/make-pki.sh OUTDIR NAME [NAME ...]
#
# Each NAME gets OUTDIR/NAME/ with ca.cert.pem, cert.pem, key.pem, governance.p7s, permissions.p7s:
# copy that folder to the host and start the process with `--security OUTDIR/NAME` (or set
# FARM_SECURITY_DIR). A NAME's role comes from how it starts:
#   learner*  publishes ExperimentSpec, PolicyWeights, LearnerStats, EvaluationRequest; reads TransitionBatch,
#             WorkerStatus, EvaluationAnswer
#   monitor*  reads every farm topic, publishes nothing
#   anything else is a worker: publishes TransitionBatch, WorkerStatus, EvaluationAnswer; reads ExperimentSpec,
#             PolicyWeights, EvaluationRequest
# A certificate's subject is CN=NAME,O=rollout-farm. A worker's id is its certificate's name:
# farm-worker takes it by default and refuses another --id, and a learner refuses a batch whose
# worker id is not the certificate name of the participant that wrote it.
# Running it again with the same OUTDIR keeps the CA and adds or renews the named participants.
# Every certificate, like the permissions, is valid from one day before it is made
# (FARM_PKI_BACKDATE_DAYS), so a host whose clock is behind the one that made the PKI still joins:
# Fast DDS refuses a certificate that is not yet valid by the local clock.
set -euo pipefail

if [ $# -lt 2 ]; then
  echo "usage: $0 OUTDIR NAME [NAME ...]   (e.g. $0 pki learner worker-a worker-b)" >&2
  exit 2
fi
command -v openssl >/dev/null || { echo "make-pki: openssl is not installed (apt-get install openssl)" >&2; exit 1; }

OUT="$1"; shift
DAYS="${FARM_PKI_DAYS:-3650}"
BACKDATE_DAYS="${FARM_PKI_BACKDATE_DAYS:-1}"
ORG="rollout-farm"
mkdir -p "$OUT/ca"
CA_KEY="$OUT/ca/ca.key.pem"
CA_CERT="$OUT/ca/ca.cert.pem"
START="$(date -u -d "-$BACKDATE_DAYS days" +%Y%m%d%H%M%SZ)"
END="$(date -u -d "+$DAYS days" +%Y%m%d%H%M%SZ)"

# Signed with `openssl ca`: in OpenSSL 3.0 it alone takes a start date in the past (`openssl x509
# -req -days N` starts a certificate at the moment it is made).
mkdir -p "$OUT/ca/issued"
touch "$OUT/ca/index.txt"
[ -f "$OUT/ca/serial" ] || openssl rand -hex 16 > "$OUT/ca/serial"
cat > "$OUT/ca/openssl.cnf" <<EOF
[ ca ]
default_ca = farm_ca
[ farm_ca ]
database = $OUT/ca/index.txt
new_certs_dir = $OUT/ca/issued
serial = $OUT/ca/serial
default_md = sha256
policy = farm_policy
unique_subject = no
[ farm_policy ]
organizationName = supplied
commonName = supplied
[ farm_ca_ext ]
basicConstraints = critical,CA:true
subjectKeyIdentifier = hash
[ farm_participant_ext ]
basicConstraints = CA:false
subjectKeyIdentifier = hash
authorityKeyIdentifier = keyid
EOF
sign_csr() {  # sign_csr CSR OUT EXTENSIONS [openssl ca flags]
  local csr=$1 out=$2 ext=$3
  shift 3
  openssl ca -batch -notext -preserveDN -config "$OUT/ca/openssl.cnf" -startdate "$START" -enddate "$END" \
    -extensions "$ext" -in "$csr" -out "$out" "$@" 2>"$OUT/ca/openssl.log" ||
    { cat "$OUT/ca/openssl.log" >&2; echo "make-pki: signing $out failed" >&2; exit 1; }
}

if [ ! -f "$CA_KEY" ]; then
  openssl ecparam -name prime256v1 -genkey -noout -out "$CA_KEY"
  chmod 600 "$CA_KEY"
  openssl req -new -key "$CA_KEY" -subj "/O=$ORG/CN=farm CA" -out "$OUT/ca/ca.csr"
  sign_csr "$OUT/ca/ca.csr" "$CA_CERT" farm_ca_ext -selfsign -keyfile "$CA_KEY"
  rm -f "$OUT/ca/ca.csr"
  echo "make-pki: new CA in $OUT/ca (keep ca.key.pem off the farm hosts)"
fi

# Governance: only authenticated participants join; discovery, liveliness and data are encrypted
# (AES-GCM) and every topic is access controlled.
cat > "$OUT/ca/governance.xml" <<'EOF'
<?xml version="1.0" encoding="utf-8"?>
<dds xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance"
     xsi:noNamespaceSchemaLocation="http://www.omg.org/spec/DDS-Security/20170801/omg_shared_ca_governance.xsd">
  <domain_access_rules>
    <domain_rule>
      <domains><id_range><min>0</min><max>232</max></id_range></domains>
      <allow_unauthenticated_participants>false</allow_unauthenticated_participants>
      <enable_join_access_control>true</enable_join_access_control>
      <discovery_protection_kind>ENCRYPT</discovery_protection_kind>
      <liveliness_protection_kind>ENCRYPT</liveliness_protection_kind>
      <rtps_protection_kind>ENCRYPT</rtps_protection_kind>
      <topic_access_rules>
        <topic_rule>
          <topic_expression>*</topic_expression>
          <enable_discovery_protection>true</enable_discovery_protection>
          <enable_liveliness_protection>true</enable_liveliness_protection>
          <enable_read_access_control>true</enable_read_access_control>
          <enable_write_access_control>true</enable_write_access_control>
          <metadata_protection_kind>ENCRYPT</metadata_protection_kind>
          <data_protection_kind>ENCRYPT</data_protection_kind>
        </topic_rule>
      </topic_access_rules>
    </domain_rule>
  </domain_access_rules>
</dds>
EOF

topics() { for t in "$@"; do printf '          <topic>farm/%s</topic>\n' "$t"; done; }
rule() {  # rule PUBLISH_TOPICS SUBSCRIBE_TOPICS (space-separated, may be empty)
  echo "      <allow_rule>"
  echo "        <domains><id_range><min>0</min><max>232</max></id_range></domains>"
  if [ -n "$1" ]; then echo "        <publish><topics>"; topics $1; echo "        </topics></publish>"; fi
  if [ -n "$2" ]; then echo "        <subscribe><topics>"; topics $2; echo "        </topics></subscribe>"; fi
  echo "      </allow_rule>"
}

# Every participant ever named in this OUTDIR gets a grant, so the permissions stay one document.
for name in "$@"; do
  case "$name" in */*|"") echo "make-pki: bad participant name '$name'" >&2; exit 2 ;; esac
  touch "$OUT/ca/participants"
  grep -qxF "$name" "$OUT/ca/participants" || echo "$name" >> "$OUT/ca/participants"
done
NOT_BEFORE="$(date -u -d "-$BACKDATE_DAYS days" +%Y-%m-%dT%H:%M:%S)"
NOT_AFTER="$(date -u -d "+$DAYS days" +%Y-%m-%dT%H:%M:%S)"
{
  echo '<?xml version="1.0" encoding="utf-8"?>'
  echo '<dds xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance"'
  echo '     xsi:noNamespaceSchemaLocation="http://www.omg.org/spec/DDS-Security/20170801/omg_shared_ca_permissions.xsd">'
  echo '  <permissions>'
  while read -r name; do
    echo "    <grant name=\"farm_$name\">"
    echo "      <subject_name>CN=$name,O=$ORG</subject_name>"
    echo "      <validity><not_before>$NOT_BEFORE</not_before><not_after>$NOT_AFTER</not_after></validity>"
    case "$name" in
      learner*) rule "ExperimentSpec PolicyWeights LearnerStats EvaluationRequest" \
                     "TransitionBatch WorkerStatus EvaluationAnswer" ;;
      monitor*) rule "" "ExperimentSpec PolicyWeights LearnerStats TransitionBatch WorkerStatus EvaluationRequest EvaluationAnswer" ;;
      *)        rule "TransitionBatch WorkerStatus EvaluationAnswer" "ExperimentSpec PolicyWeights EvaluationRequest" ;;
    esac
    echo "      <default>DENY</default>"
    echo "    </grant>"
  done < "$OUT/ca/participants"
  echo '  </permissions>'
  echo '</dds>'
} > "$OUT/ca/permissions.xml"

sign() { openssl smime -sign -in "$1" -text -out "$2" -signer "$CA_CERT" -inkey "$CA_KEY"; }
sign "$OUT/ca/governance.xml" "$OUT/ca/governance.p7s"
sign "$OUT/ca/permissions.xml" "$OUT/ca/permissions.p7s"

while read -r name; do
  dir="$OUT/$name"
  mkdir -p "$dir"
  if [ ! -f "$dir/key.pem" ]; then
    openssl ecparam -name prime256v1 -genkey -noout -out "$dir/key.pem"
    chmod 600 "$dir/key.pem"
    openssl req -new -key "$dir/key.pem" -subj "/O=$ORG/CN=$name" -out "$dir/cert.csr"
    sign_csr "$dir/cert.csr" "$dir/cert.pem" farm_participant_ext -cert "$CA_CERT" -keyfile "$CA_KEY"
    rm -f "$dir/cert.csr"
  fi
  cp "$CA_CERT" "$dir/ca.cert.pem"
  cp "$OUT/ca/governance.p7s" "$OUT/ca/permissions.p7s" "$dir/"
done < "$OUT/ca/participants"
echo "make-pki: participants in $OUT: $(tr '\n' ' ' < "$OUT/ca/participants")"

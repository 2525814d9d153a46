#!/usr/bin/env bash
# Makes everything DDS Security needs for one farm: a certificate authority, a certificate and key
# per participant, and the governance and permissions documents signed by the CA.
#
#   deploy/make-pki.sh OUTDIR ROLE:NAME [ROLE:NAME ...]     ROLE is learner, worker or monitor
#   deploy/make-pki.sh OUTDIR --revoke NAME [NAME ...]
#
# Each NAME gets OUTDIR/NAME/ with ca.cert.pem, cert.pem, key.pem, governance.p7s, permissions.p7s
# (and crl.pem once a certificate was revoked): copy that folder to the host and start the process
# with `--security OUTDIR/NAME` (or set FARM_SECURITY_DIR). A NAME's role is the one given with it,
# never guessed from the name (a worker named learnerbox-1 is a worker), and is kept in
# OUTDIR/ca/participants ("NAME ROLE" lines); a name already there keeps its role.
#   learner  publishes ExperimentSpec, PolicyWeights, LearnerStats, EvaluationRequest; reads TransitionBatch,
#            WorkerStatus, EvaluationAnswer in every worker's partition (worker/*)
#   worker   publishes TransitionBatch, WorkerStatus, EvaluationAnswer only in its own partition
#            worker/NAME; reads ExperimentSpec, PolicyWeights, EvaluationRequest
#   monitor  reads every farm topic, publishes nothing
# NAME is letters, digits, '.', '_' and '-'. A certificate's subject is CN=NAME,O=rollout-farm. A
# worker's id is its certificate's name: farm-worker takes it by default and refuses another --id,
# and a learner takes a batch's writer's name from the partition its writer is in, which access
# control allows to that certificate alone (docs/record/reliability.md, "Trust between participants").
# Running it again with the same OUTDIR keeps the CA and adds or renews the named participants.
# --revoke NAME revokes NAME's certificate in the CA's revocation list (OUTDIR/ca/crl.pem) and signs
# the permissions again without NAME's grant; both are copied into every remaining participant's
# folder. Copy crl.pem and permissions.p7s to the hosts: a running learner takes the new permissions
# on SIGHUP (it then refuses the names they no longer grant), and every process started afterwards
# refuses the revoked certificate in authentication. NAME's folder stays as it was; naming it again
# later makes it a new key and certificate.
# Every certificate, like the permissions and the revocation list, is valid from one day before it
# is made (FARM_PKI_BACKDATE_DAYS), so a host whose clock is behind the one that made the PKI still
# joins: Fast DDS refuses a certificate that is not yet valid by the local clock.
set -euo pipefail

if [ $# -lt 2 ]; then
  echo "usage: $0 OUTDIR ROLE:NAME [ROLE:NAME ...]   (e.g. $0 pki learner:learner worker:worker-a monitor:mon)" >&2
  echo "       $0 OUTDIR --revoke NAME [NAME ...]" >&2
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
[ -f "$OUT/ca/crlnumber" ] || echo 01 > "$OUT/ca/crlnumber"
cat > "$OUT/ca/openssl.cnf" <<EOF
[ ca ]
default_ca = farm_ca
[ farm_ca ]
database = $OUT/ca/index.txt
new_certs_dir = $OUT/ca/issued
serial = $OUT/ca/serial
crlnumber = $OUT/ca/crlnumber
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
partitions() { [ $# -eq 0 ] || { echo "          <partitions>"; printf '            <partition>%s</partition>\n' "$@"; echo "          </partitions>"; }; }
block() {  # block publish|subscribe "TOPICS" [PARTITION ...]: no partition is the default one ("") alone
  local kind=$1 list=$2
  shift 2
  echo "        <$kind><topics>"; topics $list; echo "        </topics>"; partitions "$@"; echo "        </$kind>"
}
# Fast DDS checks an endpoint's partitions against every <publish> (or <subscribe>) block of the
# rule that allows its topic, so a rule has one publish block: a worker may write only in
# worker/NAME, the partition the learner reads a writer's name from.
rule() {  # rule ROLE NAME
  echo "      <allow_rule>"
  echo "        <domains><id_range><min>0</min><max>232</max></id_range></domains>"
  case "$1" in
    learner)
      block publish "ExperimentSpec PolicyWeights LearnerStats EvaluationRequest"
      block subscribe "TransitionBatch WorkerStatus EvaluationAnswer" "worker/*" ;;
    monitor)
      block subscribe "ExperimentSpec PolicyWeights LearnerStats EvaluationRequest"
      block subscribe "TransitionBatch WorkerStatus EvaluationAnswer" "worker/*" ;;
    worker)
      block publish "TransitionBatch WorkerStatus EvaluationAnswer" "worker/$2"
      block subscribe "ExperimentSpec PolicyWeights EvaluationRequest" ;;
  esac
  echo "      </allow_rule>"
}

touch "$OUT/ca/participants" "$OUT/ca/revoked"
if grep -qv '^[A-Za-z0-9._-]* \(learner\|worker\|monitor\)$' "$OUT/ca/participants"; then
  echo "make-pki: $OUT/ca/participants has lines without a role (made by an older make-pki.sh, which took roles" \
       "from name prefixes); make a new OUTDIR with ROLE:NAME for each participant" >&2
  exit 2
fi
valid_name() { [[ "$1" =~ ^[A-Za-z0-9._-]+$ ]]; }
role_of() { awk -v n="$1" '$1 == n { print $2 }' "$OUT/ca/participants"; }
if [ "$1" = "--revoke" ]; then
  shift
  [ $# -ge 1 ] || { echo "make-pki: --revoke needs at least one NAME" >&2; exit 2; }
  [ -f "$CA_KEY" ] || { echo "make-pki: no CA in $OUT/ca to revoke with" >&2; exit 2; }
  for name in "$@"; do
    valid_name "$name" && [ -n "$(role_of "$name")" ] ||
      { echo "make-pki: '$name' is not a participant of $OUT" >&2; exit 2; }
    openssl ca -config "$OUT/ca/openssl.cnf" -keyfile "$CA_KEY" -cert "$CA_CERT" -revoke "$OUT/$name/cert.pem" \
      2>"$OUT/ca/openssl.log" || grep -q "already revoked" "$OUT/ca/openssl.log" ||
      { cat "$OUT/ca/openssl.log" >&2; echo "make-pki: revoking $name failed" >&2; exit 1; }
    awk -v n="$name" '$1 != n' "$OUT/ca/participants" > "$OUT/ca/participants.new"
    mv "$OUT/ca/participants.new" "$OUT/ca/participants"
    grep -qxF "$name" "$OUT/ca/revoked" || echo "$name" >> "$OUT/ca/revoked"
    echo "make-pki: revoked $name (its folder $OUT/$name is left as it was)"
  done
  # Valid from the backdated start, like the certificates, until their end: a process refuses to start
  # with an expired revocation list (Fast DDS cannot create its participant then).
  openssl ca -config "$OUT/ca/openssl.cnf" -keyfile "$CA_KEY" -cert "$CA_CERT" -gencrl -crl_lastupdate "$START" \
    -crl_nextupdate "$END" -out "$OUT/ca/crl.pem" 2>"$OUT/ca/openssl.log" ||
    { cat "$OUT/ca/openssl.log" >&2; echo "make-pki: making the revocation list failed" >&2; exit 1; }
else
  for arg in "$@"; do
    role=${arg%%:*} name=${arg#*:}
    case "$role" in learner|worker|monitor) ;; *)
      echo "make-pki: '$arg' is not ROLE:NAME with ROLE learner, worker or monitor (roles are never taken from names)" >&2
      exit 2 ;;
    esac
    valid_name "$name" || { echo "make-pki: bad participant name '$name' (letters, digits, '.', '_', '-')" >&2; exit 2; }
    had=$(role_of "$name")
    if [ -n "$had" ]; then
      [ "$had" = "$role" ] || { echo "make-pki: $name is already a $had in $OUT" >&2; exit 2; }
    else
      echo "$name $role" >> "$OUT/ca/participants"
    fi
    if grep -qxF "$name" "$OUT/ca/revoked"; then
      # Named again after its revocation: a new key and certificate, never the revoked one.
      rm -f "$OUT/$name/key.pem" "$OUT/$name/cert.pem" "$OUT/$name/crl.pem"
      grep -vxF "$name" "$OUT/ca/revoked" > "$OUT/ca/revoked.new" || true
      mv "$OUT/ca/revoked.new" "$OUT/ca/revoked"
    fi
  done
fi

# Every current participant in this OUTDIR gets a grant, so the permissions stay one document.
NOT_BEFORE="$(date -u -d "-$BACKDATE_DAYS days" +%Y-%m-%dT%H:%M:%S)"
NOT_AFTER="$(date -u -d "+$DAYS days" +%Y-%m-%dT%H:%M:%S)"
{
  echo '<?xml version="1.0" encoding="utf-8"?>'
  echo '<dds xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance"'
  echo '     xsi:noNamespaceSchemaLocation="http://www.omg.org/spec/DDS-Security/20170801/omg_shared_ca_permissions.xsd">'
  echo '  <permissions>'
  while read -r name role; do
    echo "    <grant name=\"farm_$name\">"
    echo "      <subject_name>CN=$name,O=$ORG</subject_name>"
    echo "      <validity><not_before>$NOT_BEFORE</not_before><not_after>$NOT_AFTER</not_after></validity>"
    rule "$role" "$name"
    echo "      <default>DENY</default>"
    echo "    </grant>"
  done < "$OUT/ca/participants"
  echo '  </permissions>'
  echo '</dds>'
} > "$OUT/ca/permissions.xml"

sign() { openssl smime -sign -in "$1" -text -out "$2" -signer "$CA_CERT" -inkey "$CA_KEY"; }
sign "$OUT/ca/governance.xml" "$OUT/ca/governance.p7s"
sign "$OUT/ca/permissions.xml" "$OUT/ca/permissions.p7s"

while read -r name role; do
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
  [ ! -f "$OUT/ca/crl.pem" ] || cp "$OUT/ca/crl.pem" "$dir/crl.pem"
done < "$OUT/ca/participants"
echo "make-pki: participants in $OUT: $(awk '{ printf "%s%s (%s)", (NR > 1 ? ", " : ""), $1, $2 }' "$OUT/ca/participants")"

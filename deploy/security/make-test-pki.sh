#!/usr/bin/env bash
# Creates a TEST public-key infrastructure for DDS Security (Fast DDS builtin
# plugins PKI-DH, Access-Permissions, AES-GCM-GMAC) and a ready-to-load Fast DDS
# profiles file per identity.
#
#   deploy/security/make-test-pki.sh OUTDIR [PROFILES_XML]
#
# OUTDIR/
#   ca/ca.pem, ca/ca.key              test CA: identity CA and permissions CA (ECDSA P-256)
#   governance.xml, governance.p7s    domain governance, S/MIME-signed by the CA
#   <id>/cert.pem, <id>/key.pem       identity certificate and private key (0600)
#   <id>/permissions.xml, .p7s        permissions of the identity, S/MIME-signed by the CA
#   <id>/dds-profiles-secure.xml      PROFILES_XML (default deploy/dds-profiles.xml) with the
#                                     security properties added to the ve_participant profile
# for <id> in: encoder (the virtual encoder service), monitor (a permitted monitor and
# calibration requester), intruder (authenticated, but allowed nothing on ve/*).
#
# Validity: the CA 10 years, identity certificates 2 years, each grant the validity of
# its certificate. Idempotent: existing keys and certificates are kept; the XML files
# are rewritten and signed again only when their content changes. Quiet unless it fails.
#
# This is a test PKI: the CA key lies next to what it signs. For production, use your
# own CA (kept offline), with the same governance and permissions (see docs/dds-security.md).
set -euo pipefail

usage() { echo "usage: $0 OUTDIR [PROFILES_XML]" >&2; exit 2; }
[[ $# -ge 1 && $# -le 2 ]] || usage
command -v openssl >/dev/null || { echo "$0: openssl not found" >&2; exit 1; }

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
profiles=${2:-$here/../dds-profiles.xml}
[[ -r $profiles ]] || { echo "$0: cannot read $profiles" >&2; exit 1; }
mkdir -p "$1"
out=$(cd "$1" && pwd)
umask 077

# Subject attributes of every certificate (CN is the identity).
org="O=Virtual Encoder Test PKI"
domain_min=0
domain_max=232

log=$(mktemp)
trap 'rm -f "$log"' EXIT
run() { "$@" >"$log" 2>&1 || { cat "$log" >&2; echo "$0: failed: $*" >&2; exit 1; }; }

new_key() { [[ -s $1 ]] || run openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$1"; }

# ---- CA -------------------------------------------------------------------------
mkdir -p "$out/ca"
new_key "$out/ca/ca.key"
if [[ ! -s $out/ca/ca.pem ]]; then
  run openssl req -x509 -new -sha256 -days 3650 -key "$out/ca/ca.key" -out "$out/ca/ca.pem" \
      -subj "/$org/CN=Virtual Encoder Test CA" \
      -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign,digitalSignature"
fi

# Signs $1 (XML) into $2 (S/MIME, text) unless $2 already holds exactly $1.
sign() {
  local xml=$1 p7s=$2 tmp
  if [[ -s $p7s ]] && openssl smime -verify -in "$p7s" -CAfile "$out/ca/ca.pem" -text -out "$xml.verified" \
        >/dev/null 2>&1 && tr -d '\r' <"$xml.verified" | cmp -s "$xml" -; then
    rm -f "$xml.verified"
    return
  fi
  rm -f "$xml.verified"
  tmp=$(mktemp "$p7s.XXXXXX")
  run openssl smime -sign -text -in "$xml" -out "$tmp" -signer "$out/ca/ca.pem" -inkey "$out/ca/ca.key" -md sha256
  chmod 644 "$tmp"
  mv "$tmp" "$p7s"
}

# Writes stdin to $1 only when it differs (keeps mtimes and signatures stable).
put() {
  local tmp
  tmp=$(mktemp "$1.XXXXXX")
  cat >"$tmp"
  chmod 644 "$tmp"
  if cmp -s "$tmp" "$1" 2>/dev/null; then rm -f "$tmp"; else mv "$tmp" "$1"; fi
}

# ---- governance -----------------------------------------------------------------
# Domain-wide: only authenticated participants with a valid permissions document
# join; discovery, liveliness and every RTPS message are encrypted.
# ve/*: reading and writing need a grant. Each submessage (with the sample in it)
# is encrypted with the sending endpoint's key, which only matched, permitted
# endpoints receive: another participant of the domain cannot decrypt it, although
# it holds the participant-level key. The payload is also encrypted end to end
# (ENCRYPT, AES-GCM). Fast DDS then also protects the key (is_key_protected), which
# makes every instance handle an MD5 hash: writers must let write() compute the
# handle (they do), never pass one computed without security.
# Any other topic also needs a grant.
put "$out/governance.xml" <<XML
<?xml version="1.0" encoding="UTF-8"?>
<dds xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance"
     xsi:noNamespaceSchemaLocation="http://www.omg.org/spec/DDS-SECURITY/20170901/omg_shared_ca_governance.xsd">
  <domain_access_rules>
    <domain_rule>
      <domains>
        <id_range><min>$domain_min</min><max>$domain_max</max></id_range>
      </domains>
      <allow_unauthenticated_participants>false</allow_unauthenticated_participants>
      <enable_join_access_control>true</enable_join_access_control>
      <discovery_protection_kind>ENCRYPT</discovery_protection_kind>
      <liveliness_protection_kind>ENCRYPT</liveliness_protection_kind>
      <rtps_protection_kind>ENCRYPT</rtps_protection_kind>
      <topic_access_rules>
        <topic_rule>
          <topic_expression>ve/*</topic_expression>
          <enable_discovery_protection>true</enable_discovery_protection>
          <enable_liveliness_protection>true</enable_liveliness_protection>
          <enable_read_access_control>true</enable_read_access_control>
          <enable_write_access_control>true</enable_write_access_control>
          <metadata_protection_kind>ENCRYPT</metadata_protection_kind>
          <data_protection_kind>ENCRYPT</data_protection_kind>
        </topic_rule>
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
XML
sign "$out/governance.xml" "$out/governance.p7s"

# ---- identities -------------------------------------------------------------------
topics_xml() { local t; for t in "$@"; do printf '              <topic>%s</topic>\n' "$t"; done; }
iso_date() { date -u -d "$1" +%Y-%m-%dT%H:%M:%S; }

# identity publish-topics subscribe-topics (space-separated lists)
identity() {
  local id=$1 pub=$2 sub=$3 dir=$out/$1 subject not_before not_after
  mkdir -p "$dir"
  new_key "$dir/key.pem"
  if [[ ! -s $dir/cert.pem ]]; then
    run openssl req -new -sha256 -key "$dir/key.pem" -out "$dir/cert.csr" -subj "/$org/CN=$id"
    printf 'basicConstraints=critical,CA:FALSE\nkeyUsage=critical,digitalSignature,keyAgreement\n' >"$dir/cert.ext"
    run openssl x509 -req -sha256 -days 730 -in "$dir/cert.csr" -CA "$out/ca/ca.pem" -CAkey "$out/ca/ca.key" \
        -set_serial "0x$(openssl rand -hex 16)" -extfile "$dir/cert.ext" -out "$dir/cert.pem"
    rm -f "$dir/cert.csr" "$dir/cert.ext"
    chmod 644 "$dir/cert.pem"
  fi
  # The grant names the certificate's subject as Fast DDS prints it (RFC 2253).
  subject=$(openssl x509 -in "$dir/cert.pem" -noout -subject -nameopt RFC2253)
  subject=${subject#subject=}
  not_before=$(iso_date "$(openssl x509 -in "$dir/cert.pem" -noout -startdate | cut -d= -f2)")
  not_after=$(iso_date "$(openssl x509 -in "$dir/cert.pem" -noout -enddate | cut -d= -f2)")
  # shellcheck disable=SC2086
  put "$dir/permissions.xml" <<XML
<?xml version="1.0" encoding="UTF-8"?>
<dds xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance"
     xsi:noNamespaceSchemaLocation="http://www.omg.org/spec/DDS-SECURITY/20170901/omg_shared_ca_permissions.xsd">
  <permissions>
    <grant name="${id}_grant">
      <subject_name>$subject</subject_name>
      <validity>
        <not_before>$not_before</not_before>
        <not_after>$not_after</not_after>
      </validity>
      <allow_rule>
        <domains>
          <id_range><min>$domain_min</min><max>$domain_max</max></id_range>
        </domains>
        <publish>
          <topics>
$(topics_xml $pub)
          </topics>
        </publish>
        <subscribe>
          <topics>
$(topics_xml $sub)
          </topics>
        </subscribe>
      </allow_rule>
      <default>DENY</default>
    </grant>
  </permissions>
</dds>
XML
  sign "$dir/permissions.xml" "$dir/permissions.p7s"

  # The product's profiles with the security properties in the participant profile.
  local props
  props=$(sed -e "s#@CA@#file://$out/ca/ca.pem#g" -e "s#@CERT@#file://$dir/cert.pem#g" \
              -e "s#@KEY@#file://$dir/key.pem#g" -e "s#@GOVERNANCE@#file://$out/governance.p7s#g" \
              -e "s#@PERMISSIONS@#file://$dir/permissions.p7s#g" "$here/security-properties.xml.in")
  awk -v props="$props" -v id="$id" '
    /<participant profile_name="ve_participant">/ { inp = 1 }
    inp && /<\/rtps>/ { print props; inp = 0; done = 1 }
    { print }
    END { if (!done) exit 1 }' "$profiles" \
    | sed -e "0,/<dds /s#^<dds #<!-- Generated by deploy/security/make-test-pki.sh for the identity \"$id\" from $(basename "$profiles"). -->\n<dds #" \
    | put "$dir/dds-profiles-secure.xml" \
    || { echo "$0: no ve_participant <rtps> in $profiles" >&2; exit 1; }
}

identity encoder "ve/encoder_state ve/diagnostics ve/axis_description ve/calibration_status" "ve/calibration_command"
identity monitor "ve/calibration_command" "ve/encoder_state ve/diagnostics ve/axis_description ve/calibration_status"
# Authenticated (its certificate is from the CA) but granted only a topic outside ve/*.
identity intruder "lab/chat" "lab/chat"

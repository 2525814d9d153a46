#!/usr/bin/env bash
# Starts farm workers on a list of hosts over ssh.
#   deploy/start-workers.sh [--dry-run] [--domain D] [--dds-profiles FILE] [--discovery "IP:PORT;IP:PORT"]
#                           [--security DIR | --insecure] HOSTS_FILE
# HOSTS_FILE: one line per host, "HOST ENVS THREADS" (blank lines and # comments skipped), e.g.
#   10.77.0.2 8 1
#   gpu-box-3 64 8
# Each host runs /opt/farm/bin/farm-worker (FARM_BIN to change) in the background with id
# <HOST>-1, its output in /var/log/farm/worker-<HOST>.log there (FARM_LOG_DIR). Defaults come from
# the environment: FARM_DOMAIN (0), FARM_DDS_PROFILES (/opt/farm/share/farm/discovery/client_udp.xml),
# ROS_DISCOVERY_SERVER (the Discovery Servers, with --insecure only; unset: multicast discovery),
# SSH ("ssh -o BatchMode=yes").
# DDS Security is on by default: each worker runs with --security DIR, a folder on that host
# (FARM_SECURITY_DIR, default /etc/farm/pki) holding what `deploy/make-pki.sh pki worker:<HOST>-1` made in
# pki/<HOST>-1; a host without it refuses to start the worker and says how to make it. --insecure
# starts the workers without security, for a network where every host is trusted.
# --dry-run prints the ssh commands instead of running them. Hosts with systemd can use
# deploy/systemd/farm-worker@.service instead.
set -euo pipefail

usage() { sed -n '2,18p' "$0" | sed 's/^# \{0,1\}//'; }

dry_run=0
domain=${FARM_DOMAIN:-0}
profiles=${FARM_DDS_PROFILES:-/opt/farm/share/farm/discovery/client_udp.xml}
discovery=${ROS_DISCOVERY_SERVER:-}
bin=${FARM_BIN:-/opt/farm/bin}
log_dir=${FARM_LOG_DIR:-/var/log/farm}
security=${FARM_SECURITY_DIR:-/etc/farm/pki}
insecure=0
ssh_cmd=${SSH:-ssh -o BatchMode=yes}
hosts_file=""

die() { echo "start-workers: $*" >&2; exit 2; }
while [ $# -gt 0 ]; do
  case "$1" in
    --dry-run) dry_run=1 ;;
    --domain) [ $# -ge 2 ] || die "--domain needs a value"; domain=$2; shift ;;
    --dds-profiles) [ $# -ge 2 ] || die "--dds-profiles needs a value"; profiles=$2; shift ;;
    --discovery) [ $# -ge 2 ] || die "--discovery needs a value"; discovery=$2; shift ;;
    --security) [ $# -ge 2 ] || die "--security needs a value"; security=$2; shift ;;
    --insecure) insecure=1 ;;
    -h|--help) usage; exit 0 ;;
    -*) die "unknown option '$1' (see --help)" ;;
    *) [ -z "$hosts_file" ] || die "one HOSTS_FILE only (got '$hosts_file' and '$1')"; hosts_file=$1 ;;
  esac
  shift
done
[ -n "$hosts_file" ] || { usage >&2; exit 2; }
[ -r "$hosts_file" ] || die "cannot read hosts file '$hosts_file'"
[[ "$domain" =~ ^[0-9]+$ ]] && [ "$domain" -le 232 ] || die "--domain expects an integer 0..232, got '$domain'"
# Fast DDS 2.9.1's Discovery Server cannot carry DDS Security (discovery/peers_udp.xml says why).
[ $insecure = 1 ] || [ -z "$discovery" ] ||
  die "DDS Security cannot run through a Discovery Server in Fast DDS 2.9.1 (ROS_DISCOVERY_SERVER or --discovery:" \
    "'$discovery'): with security, unset it and use --dds-profiles .../discovery/simple.xml (multicast) or" \
    ".../discovery/peers_udp.xml (unicast to its hosts); the Discovery Server is for --insecure on a trusted network"

sq() { local q="'\\''"; printf "'%s'" "${1//\'/$q}"; }  # single-quoted for the shell
is_count() { [[ "$1" =~ ^[1-9][0-9]*$ ]]; }
n=0 failed=0 lineno=0
while read -r host envs threads extra || [ -n "${host:-}" ]; do
  lineno=$((lineno + 1))
  case "$host" in ''|'#'*) continue ;; esac
  [ -z "${extra:-}" ] || die "$hosts_file:$lineno: expected 'HOST ENVS THREADS', got extra '$extra'"
  is_count "${envs:-}" || die "$hosts_file:$lineno: ENVS must be a positive integer, got '${envs:-}'"
  is_count "${threads:-}" || die "$hosts_file:$lineno: THREADS must be a positive integer, got '${threads:-}'"
  id="$host-1"
  remote="mkdir -p $(printf %q "$log_dir") || exit 1; "
  if [ $insecure = 0 ]; then
    # Checked on the host, where the folder must be: a clear refusal instead of a worker that fails
    # in its log file.
    sec=$(printf %q "$security")
    remote+="[ -r $sec/cert.pem ] && [ -r $sec/key.pem ] || { echo \"$host: no DDS Security folder $sec"
    remote+=" (make it with deploy/make-pki.sh pki worker:$id, copy pki/$id to $host:$sec; or --insecure on a trusted"
    remote+=" network)\" >&2; exit 1; }; "
  fi
  [ -z "$discovery" ] || remote+="ROS_DISCOVERY_SERVER=$(printf %q "$discovery") "
  remote+="nohup $(printf %q "$bin/farm-worker") --id $(printf %q "$id") --envs $envs --threads $threads"
  remote+=" --domain $domain --dds-profiles $(printf %q "$profiles")"
  [ $insecure = 1 ] || remote+=" --security $(printf %q "$security")"
  remote+=" >>$(printf %q "$log_dir/worker-$host.log") 2>&1 </dev/null & echo \"started $id: pid \$!\""
  n=$((n + 1))
  if [ $dry_run = 1 ]; then
    echo "$ssh_cmd $host $(sq "$remote")"
  elif ! $ssh_cmd "$host" "$remote" </dev/null; then
    echo "start-workers: $host: ssh failed" >&2
    failed=$((failed + 1))
  fi
done <"$hosts_file"
[ $n -gt 0 ] || die "no hosts in $hosts_file"
[ $failed = 0 ] || { echo "start-workers: $failed of $n hosts failed" >&2; exit 1; }

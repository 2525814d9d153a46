#!/usr/bin/env bash
# farm-monitor --prometheus scraped by a real Prometheus server, on a live farm on this host
# (learner with the shipped pendulum config + 2 workers over Fast DDS, on a domain of its own):
#   tests/integration/test_prometheus.sh LEARNER_BIN WORKER_BIN MONITOR_BIN SOURCE_DIR
# 1. Bad --prometheus values (no port, port out of range, not an address) exit 2 naming the fault;
#    an address in use exits 1 saying so.
# 2. /metrics: the Prometheus text format (promtool accepts it), 404 elsewhere, 405 for POST, HEAD.
# 3. Through Prometheus's query API (deploy/prometheus/prometheus.yml, scraping every second):
#    a. one scrape's series equal, figure for figure, the monitor's --log line of the same snapshot
#       (farm_monitor_snapshot_timestamp_seconds = the line's unix_time);
#    b. each worker's steps/s and batches and the learner's batch counters agree with what
#       `farm-monitor --once` prints at the same moment: each counter it prints lies between the
#       values of the serving monitor's snapshots Prometheus holds just before and just after the
#       --once snapshot (about one refresh apart); steps/s within [0.5 x min, 1.5 x max] of what
#       Prometheus holds from 3 s before to 5 s after it (the exact comparison of the rates is a.).
# 4. Every series deploy/grafana/farm.json queries is one the monitor serves, and every panel's
#    query runs in Prometheus without error.
set -uo pipefail
learner=$(readlink -f "$1") worker=$(readlink -f "$2") monitor=$(readlink -f "$3") src=$(readlink -f "$4")
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init prometheus 131

command -v prometheus >/dev/null && command -v promtool >/dev/null ||
  { echo "FAIL: prometheus/promtool not installed (deploy/install-deps.sh installs them)"; exit 1; }

# Two free loopback ports: the metrics endpoint and Prometheus's own.
read -r mport pport < <(python3 -c '
import socket
s = [socket.socket() for _ in range(2)]
for x in s: x.bind(("127.0.0.1", 0))
print(*[x.getsockname()[1] for x in s])')

# 1. Flag errors.
expect_error() {  # RC PATTERN ARGS...
  local rc_want=$1 pattern=$2; shift 2
  out=$("$monitor" --domain $domain "$@" 2>&1); rc=$?
  [ $rc = "$rc_want" ] && grep -q -- "$pattern" <<<"$out" || fail "farm-monitor $*: rc $rc, '$out'"
}
expect_error 2 "'9100': no port" --prometheus 9100
expect_error 2 "port 70000 is out of range" --prometheus 127.0.0.1:70000
expect_error 2 "port 0 is out of range" --prometheus 127.0.0.1:0
expect_error 2 "'metrics.local' is not an IPv4 address" --prometheus metrics.local:9100
expect_error 2 "--prometheus: 1 required .* missing" --prometheus
expect_error 2 "cannot be combined with --once" --once --prometheus 127.0.0.1:$mport

# The farm: the shipped pendulum experiment on this test's domain, statistics every second, and a
# target return above Pendulum's best (0) so that it trains until the test ends it (it reaches the
# shipped -200 in about 10 s).
sed -e 's/^experiment_id: .*/experiment_id: "it_prometheus"/' -e 's/^log_every_seconds: .*/log_every_seconds: 1/' \
  -e 's/target_eval_return: .*/target_eval_return: 1/' -e 's/max_seconds: .*/max_seconds: 120/' \
  "$src/deploy/configs/pendulum_sac.txtpb" >"$dir/cfg.txtpb"
grep -q '^log_every_seconds: 1$' "$dir/cfg.txtpb" && grep -q 'target_eval_return: 1$' "$dir/cfg.txtpb" ||
  fail "could not set log_every_seconds and target_eval_return in the copy: $(cat "$dir/cfg.txtpb")"
"$learner" --config "$dir/cfg.txtpb" --run-dir "$dir/run" --domain $domain >"$dir/learner.log" 2>&1 & pids+=($!)
"$worker" --domain $domain --id prom-a --events "$dir/worker-a.jsonl" >"$dir/worker-a.log" 2>&1 & pids+=($!)
"$worker" --domain $domain --id prom-b --events "$dir/worker-b.jsonl" >"$dir/worker-b.log" 2>&1 & pids+=($!)
"$monitor" --domain $domain --quiet --prometheus 127.0.0.1:$mport --log "$dir/monitor.jsonl" \
  >"$dir/monitor.out" 2>&1 & mon=$!; pids+=($mon)
# Whether URL answers a GET with 200 within 2 s.
answers() { python3 -c 'import sys, urllib.request; sys.exit(urllib.request.urlopen(sys.argv[1], timeout=2).status != 200)' "$1" 2>/dev/null; }
for _ in $(seq 75); do answers "http://127.0.0.1:$mport/metrics" && break; sleep 0.2; done
answers "http://127.0.0.1:$mport/metrics" ||
  fail "the monitor does not serve http://127.0.0.1:$mport/metrics: $(cat "$dir/monitor.out")"
expect_error 1 "cannot serve there: .*Address already in use" --prometheus 127.0.0.1:$mport

sed -e "s/127.0.0.1:9469/127.0.0.1:$mport/" -e 's/scrape_interval: 5s/scrape_interval: 1s/' \
  -e 's/evaluation_interval: 5s/evaluation_interval: 1s/' -e 's/scrape_timeout: 4s/scrape_timeout: 1s/' \
  "$src/deploy/prometheus/prometheus.yml" >"$dir/prometheus.yml"
grep -q "scrape_interval: 1s" "$dir/prometheus.yml" && grep -q "127.0.0.1:$mport" "$dir/prometheus.yml" ||
  fail "could not point the shipped scrape config at the test's monitor: $(cat "$dir/prometheus.yml")"
promtool check config "$dir/prometheus.yml" >"$dir/promtool-config.out" 2>&1 ||
  fail "promtool refuses the scrape config: $(cat "$dir/promtool-config.out")"
prometheus --config.file="$dir/prometheus.yml" --storage.tsdb.path="$dir/tsdb" \
  --web.listen-address=127.0.0.1:$pport >"$dir/prometheus.log" 2>&1 & pids+=($!)

for w in a b; do
  wait_worker_event "$dir/worker-$w.jsonl" joined 30 || fail "worker prom-$w did not join: $(tail -3 "$dir/worker-$w.log")"
done

# 2. The endpoint itself (python3's urllib: no HTTP client to install).
python3 - "http://127.0.0.1:$mport" "$dir/metrics.txt" <<'PYHTTP' || failed=1
import sys, urllib.error, urllib.request
base, out = sys.argv[1:]
def get(path, method="GET", data=None):
    try:
        with urllib.request.urlopen(urllib.request.Request(base + path, data=data, method=method), timeout=10) as r:
            return r.status, r.headers.get("Content-Type", ""), r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.headers.get("Content-Type", ""), e.read()
ok = True
code, ctype, body = get("/metrics")
open(out, "wb").write(body)
if code != 200 or not ctype.startswith("text/plain; version=0.0.4") or b"# TYPE farm_worker_up gauge" not in body:
    print(f"FAIL: GET /metrics: {code} {ctype!r}, {len(body)} bytes"); ok = False
for path, method, want in (("/other", "GET", 404), ("/metrics", "POST", 405)):
    code = get(path, method, b"x=1" if method == "POST" else None)[0]
    if code != want:
        print(f"FAIL: {method} {path} answered {code}, not {want}"); ok = False
code, _, body = get("/metrics", "HEAD")
if code != 200 or body:
    print(f"FAIL: HEAD /metrics answered {code} with {len(body)} bytes"); ok = False
sys.exit(0 if ok else 1)
PYHTTP
promtool check metrics <"$dir/metrics.txt" >"$dir/promtool-metrics.out" 2>&1 ||
  fail "promtool refuses /metrics: $(head -5 "$dir/promtool-metrics.out")"
[ -s "$dir/promtool-metrics.out" ] && fail "promtool's lint: $(head -5 "$dir/promtool-metrics.out")"

# 3 and 4: Prometheus's view of the farm, in python3 (urllib).
python3 - "$pport" "$monitor" "$domain" "$dir" "$src/deploy/grafana/farm.json" <<'EOF' || failed=1
import json, re, subprocess, sys, time, urllib.parse, urllib.request

pport, monitor, domain, d, dashboard = sys.argv[1:]
ok = True
def check(cond, msg):
    global ok
    if not cond:
        print("FAIL:", msg)
        ok = False
    return cond

def query(expr, at=None):
    args = {"query": expr}
    if at is not None:
        args["time"] = f"{at:.3f}"
    url = f"http://127.0.0.1:{pport}/api/v1/query?" + urllib.parse.urlencode(args)
    with urllib.request.urlopen(url, timeout=10) as r:
        body = json.load(r)
    if body.get("status") != "success":
        raise RuntimeError(f"{expr}: {body}")
    return body["data"]["result"]

def by_worker(expr, at=None):
    return {s["metric"]["worker"]: float(s["value"][1]) for s in query(expr, at)}

def one(expr, at=None):
    r = query(expr, at)
    return float(r[0]["value"][1]) if r else None

# Wait until Prometheus scrapes the monitor and sees both workers running and batches accepted.
deadline = time.time() + 60
while True:
    try:
        up = one('up{job="farm"}')
        rates = by_worker('farm_worker_env_steps_per_second{experiment="it_prometheus"}')
        batches = one('farm_learner_batches_total{experiment="it_prometheus",result="ok"}')
    except Exception as e:  # Prometheus still starting
        up, rates, batches = None, {}, None
    if up == 1 and len(rates) == 2 and all(v > 0 for v in rates.values()) and (batches or 0) > 0:
        break
    if time.time() > deadline:
        check(False, f"Prometheus never saw the farm running: up {up}, steps/s {rates}, batches ok {batches}")
        sys.exit(1)
    time.sleep(0.5)
time.sleep(6)  # past the first seconds, when the rates still climb
print(f"--- Prometheus scrapes the farm: up 1, steps/s {rates}, batches ok {batches:.0f}")

# a. One scrape = one snapshot = one --log line.
t = time.time()
stamp = one("farm_monitor_snapshot_timestamp_seconds", t)
log = {}
for line in open(f"{d}/monitor.jsonl"):
    rec = json.loads(line)
    log[f"{rec['unix_time']:.3f}"] = rec
rec = log.get(f"{stamp:.3f}")
if check(rec is not None, f"no --log line for the snapshot of {stamp:.3f} (lines: {len(log)})"):
    def close(a, b):  # the log writes 6 significant digits
        return abs(a - b) <= 1e-5 * max(1.0, abs(a), abs(b))
    for name, key in (("farm_worker_env_steps_per_second", "steps_per_s"), ("farm_worker_env_steps_total", "env_steps"),
                      ("farm_worker_batches_sent_total", "batches_sent"), ("farm_worker_policy_version", "policy_version"),
                      ("farm_worker_envs", "envs")):
        got = by_worker(name, t)
        want = {w["id"]: float(w[key]) for w in rec["workers"]}
        check(set(got) == set(want) and all(close(got[k], want[k]) for k in want),
              f"{name}: Prometheus {got}, --log line {want}")
    L = rec["learner"]
    for result in ("ok", "lost", "duplicate", "invalid"):
        got = one(f'farm_learner_batches_total{{experiment="it_prometheus",result="{result}"}}', t)
        check(got == L[f"batches_{result}"], f"batches {result}: Prometheus {got}, --log line {L[f'batches_{result}']}")
    for name, key in (("farm_learner_env_steps_total", "env_steps"), ("farm_learner_updates_total", "updates"),
                      ("farm_learner_buffer_fill_ratio", "buffer_fill"), ("farm_learner_policy_lag_versions", "policy_lag")):
        got = one(f'{name}{{experiment="it_prometheus"}}', t)
        check(got is not None and close(got, L[key]), f"{name}: Prometheus {got}, --log line {L[key]}")
    check(one("farm_total_env_steps_per_second", t) is not None and
          close(one("farm_total_env_steps_per_second", t), rec["totals"]["steps_per_s"]), "total steps/s")
    print(f"--- the scrape of snapshot {stamp:.3f} equals its --log line")

# b. farm-monitor --once at the same moment. Prometheus keeps the serving monitor's snapshots (one
# a second, each with its farm_monitor_snapshot_timestamp_seconds); the two nearest the --once
# snapshot, one before and one after it, must bracket every counter --once prints. Both monitors
# take the same heartbeats (1 s apart) off the bus, so a counter --once prints cannot be below the
# earlier snapshot's or above the later one's. The rates are over different windows (the serving
# monitor's last 5 s, --once's last second, whose rate swings by 20 % from one second to the next on
# an idle 2-core machine), so steps/s has to lie within [0.5 x min, 1.5 x max] of the serving
# monitor's over the snapshots from 3 s before the --once one to 5 s after (when the serving
# monitor's window has caught up with the second --once measured); the exact check is (a).
once = subprocess.run([monitor, "--domain", domain, "--once", "--experiment", "it_prometheus"],
                      capture_output=True, text=True, timeout=30)
print("--- farm-monitor --once:\n" + once.stdout, end="")
check(once.returncode == 0, f"--once exited {once.returncode}: {once.stderr}")
rows = {}
for line in once.stdout.splitlines():
    f = line.split()
    if len(f) >= 8 and f[1].startswith("prom-"):
        rows[f[1]] = {"steps_per_s": float(f[3]), "batches": float(f[4])}
m = re.search(r"batches\s+ok (\d+), lost (\d+), duplicate (\d+), invalid (\d+)", once.stdout)
ing = re.search(r"ingest\s+\S+ steps/s \((\d+) env steps\)", once.stdout)
when = re.search(r"(\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3})Z", once.stdout)
check(set(rows) == {"prom-a", "prom-b"} and m and ing and when, "--once lacks a worker, the learner or its time")
if rows and m and ing and when:
    import datetime
    O = datetime.datetime.strptime(when.group(1), "%Y-%m-%dT%H:%M:%S.%f").replace(
        tzinfo=datetime.timezone.utc).timestamp()
    time.sleep(max(0.0, O + 6.5 - time.time()))  # Prometheus has scraped the snapshots up to O + 5
    T = time.time()
    snaps = [(float(ts), float(v)) for ts, v in query("farm_monitor_snapshot_timestamp_seconds[15s]", T)[0]["values"]]
    before = [x for x in snaps if x[1] <= O - 0.25]
    after = [x for x in snaps if x[1] >= O + 0.25]
    if not check(before and after, f"no scraped snapshot on both sides of {O:.3f}: {snaps}"):
        sys.exit(1)
    (sb, b_snap), (sa, a_snap) = max(before, key=lambda x: x[1]), min(after, key=lambda x: x[1])
    print(f"--once snapshot {O:.3f}; Prometheus's nearest: {b_snap - O:+.3f} s and {a_snap - O:+.3f} s")
    check(a_snap - b_snap <= 4.0, f"the bracketing snapshots are {a_snap - b_snap:.1f} s apart (scrapes missed)")

    snap_at = dict(snaps)  # scrape time -> snapshot time

    def at_scrapes(expr, key):  # {key label value: {scrape time: value}} of the raw samples
        return {s["metric"].get(key, ""): {float(ts): float(v) for ts, v in s["values"]}
                for s in query(f"{expr}[15s]", T)}

    batches = at_scrapes('farm_worker_batches_sent_total{experiment="it_prometheus"}', "worker")
    rates = at_scrapes('farm_worker_env_steps_per_second{experiment="it_prometheus"}', "worker")
    for w, r in sorted(rows.items()):
        lo, hi = batches.get(w, {}).get(sb), batches.get(w, {}).get(sa)
        between = [v for ts, v in rates.get(w, {}).items() if -3.0 <= snap_at.get(ts, -1e18) - O <= 5.0]
        rmin, rmax = (min(between), max(between)) if between else (None, None)
        print(f"{w}: --once batches {r['batches']:.0f}, Prometheus {lo}..{hi}; "
              f"--once steps/s {r['steps_per_s']:.0f}, Prometheus {rmin}..{rmax}")
        check(lo is not None and hi is not None and lo <= r["batches"] <= hi,
              f"{w}: --once batches {r['batches']} outside Prometheus's {lo}..{hi}")
        check(r["steps_per_s"] > 0 and rmin is not None and 0.5 * rmin <= r["steps_per_s"] <= 1.5 * rmax,
              f"{w}: --once steps/s {r['steps_per_s']} outside [0.5 x {rmin}, 1.5 x {rmax}] (Prometheus, +-3 s)")
    accounting = at_scrapes('farm_learner_batches_total{experiment="it_prometheus"}', "result")
    for i, result in enumerate(("ok", "lost", "duplicate", "invalid")):
        lo, hi, v = accounting.get(result, {}).get(sb), accounting.get(result, {}).get(sa), float(m.group(i + 1))
        print(f"learner batches {result}: --once {v:.0f}, Prometheus {lo}..{hi}")
        check(lo is not None and hi is not None and lo <= v <= hi, f"batches {result}: --once {v} outside {lo}..{hi}")
    steps = at_scrapes('farm_learner_env_steps_total{experiment="it_prometheus"}', "experiment")["it_prometheus"]
    lo, hi, v = steps.get(sb), steps.get(sa), float(ing.group(1))
    check(lo is not None and hi is not None and lo <= v <= hi, f"learner env steps: --once {v} outside {lo}..{hi}")
    check(float(m.group(1)) > 0, "no batch accepted")

# 4. The dashboard's series and queries.
served = set(re.findall(r"^# TYPE (\S+)", open(f"{d}/metrics.txt").read(), re.M))
dash = json.load(open(dashboard))
exprs = []
def walk(panels):
    for p in panels:
        exprs.extend(t["expr"] for t in p.get("targets", []) if t.get("expr"))
        walk(p.get("panels", []))
walk(dash["panels"])
exprs += [v["definition"] for v in dash.get("templating", {}).get("list", []) if v.get("definition")]
check(len(exprs) >= 10, f"only {len(exprs)} queries in the dashboard")
named = set()
for e in exprs:
    named |= set(re.findall(r"\bfarm_[a-z_]+", e))
check(named and named <= served, f"the dashboard names series the monitor does not serve: {sorted(named - served)}")
empty = []
for e in exprs:
    if e.startswith("label_values"):
        continue
    q = e.replace("$experiment", ".*").replace("$__rate_interval", "10s")
    try:
        if not query(q):
            empty.append(e)
    except Exception as ex:
        check(False, f"dashboard query fails in Prometheus: {ex}")
# Before the first evaluation there is no evaluation return; every other panel has data.
check(all("eval_return" in e for e in empty), f"dashboard queries without data: {empty}")
print(f"--- dashboard: {len(exprs)} queries over {len(named)} series, all served; without data: {empty or 'none'}")
sys.exit(0 if ok else 1)
EOF

kill -INT $mon; wait $mon; rc=$?
[ $rc = 0 ] || fail "farm-monitor --prometheus exited $rc on SIGINT"
if [ "$failed" = 0 ]; then echo "PASS"; exit 0; fi
echo "--- learner log tail:"; tail -5 "$dir/learner.log"
echo "--- prometheus log tail:"; tail -5 "$dir/prometheus.log"
exit 1

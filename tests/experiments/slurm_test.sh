#!/bin/bash
# End-to-end `crpgs sweep --slurm` on a throwaway single-node Slurm cluster started here:
# munged, slurmctld and slurmd with their own key, sockets, ports and state under the build dir,
# a tiny sweep run by a fake trainer (CRPGS_SWEEP_RUNNER), then `crpgs report`.
# Installs nothing: skips (exit 77, a visible SKIP line) when Slurm or munge is absent (Debian:
# slurm-wlm munge) or the daemons cannot start here.
# Usage: slurm_test.sh BUILD_DIR CRPGS_EXE
set -u
BUILD=$1
CRPGS=$2
SKIP=77
skip() { echo "SKIP: slurm test: $*"; exit $SKIP; }

for t in munged slurmctld slurmd sbatch squeue scontrol; do
  command -v "$t" > /dev/null 2>&1 || [ -x "/usr/sbin/$t" ] || skip "'$t' not found (Debian packages slurm-wlm and munge)"
done
[ "$(id -u)" = 0 ] || skip "slurmd needs root here"
[ -x "$CRPGS" ] || { echo "FAIL: no crpgs executable at $CRPGS"; exit 1; }
export PATH="$PATH:/usr/sbin"

D="$BUILD/test_tmp/slurm"
rm -rf "$D"
mkdir -p "$D/state" "$D/spool" "$D/munge"
chmod 700 "$D/munge"
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill "$p" 2> /dev/null; done
  for p in "${pids[@]}"; do wait "$p" 2> /dev/null; done
}
trap cleanup EXIT
show_logs() { for f in "$D"/*.log; do echo "--- $f"; tail -n 15 "$f"; done; }

# munge with its own key and socket.
dd if=/dev/urandom of="$D/munge/munge.key" bs=1024 count=1 status=none
chmod 600 "$D/munge/munge.key"
munged --foreground --force --key-file="$D/munge/munge.key" --socket="$D/munge/munge.sock" \
  --pid-file="$D/munge/munged.pid" --log-file="$D/munged.log" --seed-file="$D/munge/seed" \
  > "$D/munged.out" 2>&1 &
pids+=($!)
for _ in $(seq 50); do [ -S "$D/munge/munge.sock" ] && break; sleep 0.1; done
[ -S "$D/munge/munge.sock" ] || { show_logs; skip "munged did not start"; }

host=$(hostname -s)
# Ports unlikely to clash with a real cluster on this machine.
port=$((20000 + $$ % 20000))
cat > "$D/slurm.conf" << CONF
ClusterName=crpgstest
SlurmctldHost=$host
SlurmUser=root
SlurmdUser=root
SlurmctldPort=$port
SlurmdPort=$((port + 1))
AuthType=auth/munge
AuthInfo=socket=$D/munge/munge.sock
CredType=cred/munge
StateSaveLocation=$D/state
SlurmdSpoolDir=$D/spool
SlurmctldPidFile=$D/slurmctld.pid
SlurmdPidFile=$D/slurmd.pid
SlurmctldLogFile=$D/slurmctld.log
SlurmdLogFile=$D/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
SchedulerType=sched/builtin
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
MpiDefault=none
ReturnToService=2
SlurmdTimeout=30
MessageTimeout=5
NodeName=$host CPUs=$(nproc) RealMemory=2000 State=UNKNOWN
PartitionName=debug Nodes=ALL Default=YES MaxTime=INFINITE State=UP
CONF
export SLURM_CONF="$D/slurm.conf"
slurmctld -D -i -f "$SLURM_CONF" > "$D/slurmctld.out" 2>&1 &
pids+=($!)
slurmd -D -f "$SLURM_CONF" -N "$host" > "$D/slurmd.out" 2>&1 &
pids+=($!)
ok=""
# Bounded by wall time too: a client call against a daemon that never came up can block.
for _ in $(seq 100); do
  [ "$SECONDS" -gt 90 ] && break
  state=$(timeout 5 sinfo -h -N -o '%T' 2> /dev/null | head -n 1)
  case "$state" in idle*|mix*|alloc*) ok=1; break ;; esac
  sleep 0.2
done
[ -n "$ok" ] || { show_logs; cat "$D"/*.out; skip "slurmctld/slurmd did not come up (node state '${state:-none}')"; }
echo "slurm: node $host is $state"

# A tiny sweep: one real (resolvable) config, 3 rate points x 2 "methods", fake trainer.
cat > "$D/base.yaml" << 'YAML'
dataset: {format: synthetic}
train:
  lambda_dssim: 0.2
YAML
cat > "$D/sweep.yaml" << YAML
name: slurm_tiny
output: $D/runs
configs:
  - {name: alpha, path: $D/base.yaml}
  - {name: beta, path: $D/base.yaml, set: {dataset.synthetic_seed: 2}}
overrides:
  train.lambda_dssim: [0.1, 0.2, 0.4]
rate_key: train.lambda_dssim
datasets: [{name: synth}]
resources: {cpus: 1, mem: 100M, time: "00:05:00", partition: debug}
YAML
cat > "$D/fake_train.sh" << 'SH'
#!/bin/bash
# Stands in for `crpgs train -c CFG -o DIR`: metrics from the rate weight in the config.
set -eu
cfg=$3; out=$5
l=$(awk '/lambda_dssim:/ {print $2; exit}' "$cfg")
seed=$(awk '/synthetic_seed:/ {print $2; exit}' "$cfg")
awk -v l="$l" -v s="$seed" -v host="$(hostname)" 'BEGIN {
  size = int(1000000 * l * (s == 2 ? 0.5 : 1)); psnr = 25 + 10 * l;
  printf "{\"format\": \"crpgs.run_metrics/1\", \"size_bytes\": %d, \"psnr_mean\": %f, ", size, psnr;
  printf "\"train_seconds\": 3, \"encode_seconds\": 0.1, \"decode_seconds\": 0.1, \"render_seconds_per_view\": 0.01, ";
  printf "\"bitstream\": {\"geometry\": %d, \"features\": %d}, ", size / 3, size - size / 3;
  printf "\"trace\": [[1, 10, %f], [3, 30, %f]]}\n", psnr - 2, psnr;
}' > "$out/metrics.json.tmp"
mv "$out/metrics.json.tmp" "$out/metrics.json"
echo "trained on $(hostname) in job ${SLURM_ARRAY_JOB_ID:-none}"
SH
chmod 755 "$D/fake_train.sh"
export CRPGS_SWEEP_RUNNER="$D/fake_train.sh"

cd "$D"
out=$(timeout 60 "$CRPGS" sweep "$D/sweep.yaml" --slurm 2>&1)
rc=$?
echo "$out"
[ $rc = 0 ] || { show_logs; echo "FAIL: crpgs sweep --slurm exited $rc"; exit 1; }
job=$(echo "$out" | sed -n 's/^submitted Slurm job array \([0-9]*\).*/\1/p')
[ -n "$job" ] || { echo "FAIL: no job id in the output"; exit 1; }
grep -q -- '--array=0-5' "$D/runs/sweep.sbatch" || { echo "FAIL: sbatch script"; cat "$D/runs/sweep.sbatch"; exit 1; }
# The tasks read a copy of the sweep file taken at submission: editing the file while the array
# waits (here: a new first grid value, which shifts every index) must not change what they run.
frozen=$(sed -n "s|.* sweep '\([^']*\)' -o .*|\1|p" "$D/runs/sweep.sbatch")
case "$frozen" in "$D/runs/slurm/sweep-"*.yaml) ;; *) echo "FAIL: tasks read '$frozen'"; exit 1 ;; esac
cmp -s "$frozen" "$D/sweep.yaml" || { echo "FAIL: $frozen is not the submitted sweep file"; exit 1; }
cp "$D/sweep.yaml" "$D/sweep.submitted.yaml"
sed -i 's/\[0.1, 0.2, 0.4\]/[0.05, 0.1, 0.2, 0.4]/' "$D/sweep.yaml"

# Wait for the array to leave the queue (bounded).
for _ in $(seq 300); do
  [ "$SECONDS" -gt 240 ] && break
  [ -z "$(timeout 5 squeue -h -j "$job" 2> /dev/null)" ] && break
  sleep 0.5
done
[ -z "$(timeout 5 squeue -h -j "$job" 2> /dev/null)" ] || { squeue; show_logs; echo "FAIL: job $job still queued"; exit 1; }
n=$(find "$D/runs" -name metrics.json | wc -l)
[ "$n" = 6 ] || { show_logs; ls -R "$D/runs"; cat "$D"/runs/slurm/*.out; echo "FAIL: $n of 6 runs have metrics.json"; exit 1; }
grep -q "in job $job" "$D/runs/synth/alpha/lambda_dssim-0.1/stdout.log" || { echo "FAIL: run log does not show the Slurm job"; exit 1; }
[ ! -e "$D/runs/synth/alpha/lambda_dssim-0.05" ] || { echo "FAIL: a task ran the edited sweep file"; exit 1; }
mv "$D/sweep.submitted.yaml" "$D/sweep.yaml"

# A second submission has nothing left to do.
again=$(timeout 60 "$CRPGS" sweep "$D/sweep.yaml" --slurm 2>&1)
echo "$again" | grep -q "6 finished, 0 running elsewhere, 0 to submit" || { echo "$again"; echo "FAIL: resubmission was not a no-op"; exit 1; }

"$CRPGS" report "$D/runs" -o "$D/report" || { echo "FAIL: crpgs report"; exit 1; }
grep -q "6 finished runs" "$D/report/report.md" || { echo "FAIL: report.md"; exit 1; }
# beta is alpha at half the size: BD-rate -50%.
grep -q "| alpha | beta | -50.00 |" "$D/report/report.md" || { cat "$D/report/report.md"; echo "FAIL: BD row"; exit 1; }
echo "PASS: slurm sweep of 6 runs as job array $job, report in $D/report"

#!/usr/bin/env bash
# A single-node Slurm on this machine, for testing the study's Slurm path:
# munged, slurmctld and slurmd with every file they write under one folder.
#
#   client-cli/slurm/local-cluster.sh start DIR   # writes DIR/slurm.conf, starts the daemons
#   client-cli/slurm/local-cluster.sh stop DIR    # stops the daemons it started (by their PIDs)
#
# After `start`, point the Slurm commands at it:
#   export SLURM_CONF=DIR/slurm.conf
#
# Needs Debian's slurm-wlm and munge. The node has this machine's CPUs;
# processes are tracked without cgroups (proctrack/linuxproc, task/none) so
# that it runs in a container; the daemons run as the invoking user.
set -euo pipefail

usage() { echo "usage: $0 start|stop DIR" >&2; exit 2; }
[ $# -eq 2 ] || usage
cmd="$1"
dir="$(mkdir -p "$2" && cd "$2" && pwd)"

stop() {
    local name pid
    for name in slurmd slurmctld munged; do
        if [ -f "$dir/$name.pid" ]; then
            pid="$(cat "$dir/$name.pid")"
            kill "$pid" 2>/dev/null || true
            for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
            kill -9 "$pid" 2>/dev/null || true
            rm -f "$dir/$name.pid"
        fi
    done
}

wait_for() { # what, seconds, command...
    local what="$1" secs="$2"; shift 2
    for _ in $(seq $((secs * 10))); do
        if "$@" >/dev/null 2>&1; then return 0; fi
        sleep 0.1
    done
    echo "local-cluster: $what did not come up in $secs s; logs in $dir" >&2
    tail -n 20 "$dir"/*.log >&2 || true
    return 1
}

case "$cmd" in
start)
    for tool in munged mungekey slurmctld slurmd sinfo; do
        command -v "$tool" >/dev/null || { echo "local-cluster: $tool not found (install slurm-wlm and munge)" >&2; exit 1; }
    done
    user="$(id -un)"
    host="$(hostname -s)"
    cpus="$(nproc)"
    mem_mb="$(awk '/MemTotal/ { printf "%d", $2 / 1024 * 0.9 }' /proc/meminfo)"
    mkdir -p "$dir/state" "$dir/spool" "$dir/munge"
    chmod 700 "$dir/munge"
    # Its own munge key and socket: the machine's munge (if any) is left alone.
    [ -f "$dir/munge/munge.key" ] || mungekey --create --keyfile="$dir/munge/munge.key" --bits=1024
    chmod 400 "$dir/munge/munge.key"
    munged --force --key-file="$dir/munge/munge.key" --socket="$dir/munge/socket" \
        --pid-file="$dir/munged.pid" --log-file="$dir/munged.log" --seed-file="$dir/munge/seed"
    wait_for munged 10 test -S "$dir/munge/socket"
    # Ports away from the defaults (6817/6818), so that a real Slurm on the
    # machine is not disturbed.
    cat >"$dir/slurm.conf" <<CONF
ClusterName=fissure-local
SlurmctldHost=$host
SlurmUser=$user
SlurmdUser=$user
SlurmctldPort=${FISSURE_SLURMCTLD_PORT:-16817}
SlurmdPort=${FISSURE_SLURMD_PORT:-16818}
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$dir/munge/socket
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/slurmctld.log
SlurmdLogFile=$dir/slurmd.log
SlurmctldDebug=info
SlurmdDebug=info
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
MpiDefault=none
ReturnToService=2
SchedulerType=sched/backfill
# Start the next array task as soon as one ends (the defaults wait up to
# 2 s between tasks on an idle node).
SchedulerParameters=sched_min_interval=0,batch_sched_delay=0,default_queue_depth=1000
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
MaxArraySize=10000
NodeName=$host CPUs=$cpus RealMemory=$mem_mb State=UNKNOWN
PartitionName=local Nodes=$host Default=YES MaxTime=INFINITE State=UP
CONF
    export SLURM_CONF="$dir/slurm.conf"
    slurmctld -i -f "$dir/slurm.conf"
    wait_for slurmctld 20 scontrol ping
    slurmd -f "$dir/slurm.conf"
    wait_for "the node" 30 sh -c "sinfo -h -N -o %T | grep -Eq '^(idle|mixed|allocated)'"
    echo "local-cluster: up ($cpus CPUs on $host); export SLURM_CONF=$dir/slurm.conf"
    ;;
stop)
    stop
    echo "local-cluster: stopped"
    ;;
*) usage ;;
esac

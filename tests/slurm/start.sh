#!/usr/bin/env bash
# Start a one-node Slurm cluster on this machine (as root) unless one already answers:
# munged (as the munge user), slurmctld, slurmd; waits until `sinfo` shows the node idle.
# Packages: tests/install_system_deps.sh. Called by the tests' session fixture (tests/conftest.py).
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
conf_file=/etc/slurm/slurm.conf

for tool in munged munge slurmctld slurmd sinfo scontrol; do
  command -v "$tool" >/dev/null || {
    echo "start.sh: $tool not found: run tests/install_system_deps.sh as root first" >&2; exit 1; }
done
node_ready() { timeout 5 sinfo -h -o '%T' 2>/dev/null | grep -qxE '(idle|mixed|allocated)'; }
need_root() {
  [ "$(id -u)" = 0 ] || { echo "start.sh: $1 needs root (run as root)" >&2; exit 1; }
}

# This machine's slurm.conf from the template; a slurm.conf that is not ours (a real cluster's)
# is left alone.
conf="$(sed -e "s/@HOST@/$(hostname -s)/" -e "s/@NODE_LINE@/$(slurmd -C | head -n 1)/" \
  "$here/slurm.conf.in")"
if [ ! -f "$conf_file" ] || { head -n 1 "$conf_file" | grep -q '^# A one-node Slurm cluster' &&
    [ "$conf" != "$(cat "$conf_file")" ]; }; then
  need_root "writing $conf_file"
  printf '%s\n' "$conf" > "$conf_file"
  # Some settings (cred_expire) are read only at start: restart daemons that run.
  if scontrol shutdown >/dev/null 2>&1; then
    while pgrep -x slurmctld >/dev/null || pgrep -x slurmd >/dev/null; do sleep 0.5; done
  fi
fi

if node_ready; then exit 0; fi
need_root "starting Slurm"
if ! munge -n >/dev/null 2>&1; then
  mkdir -p /run/munge && chown munge:munge /run/munge && chmod 0755 /run/munge
  su -s /bin/sh munge -c /usr/sbin/munged
fi
mkdir -p /var/lib/slurm/slurmctld /var/lib/slurm/slurmd /var/log/slurm
chown slurm:slurm /var/lib/slurm/slurmctld /var/log/slurm
pgrep -x slurmctld >/dev/null || slurmctld
pgrep -x slurmd >/dev/null || slurmd

deadline=$((SECONDS + 120))
while [ "$SECONDS" -lt "$deadline" ]; do
  if node_ready; then exit 0; fi
  # A node left down by an earlier run of the daemons comes back once told to.
  timeout 5 scontrol update nodename="$(hostname -s)" state=resume >/dev/null 2>&1 || true
  sleep 1
done
echo "start.sh: the Slurm node did not become idle within 120 s:" >&2
sinfo -N -l >&2 || true
tail -n 20 /var/log/slurm/slurmctld.log /var/log/slurm/slurmd.log >&2 || true
exit 1

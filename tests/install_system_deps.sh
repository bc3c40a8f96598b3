#!/usr/bin/env bash
# System packages the tests need on a fresh Debian machine (run as root):
# offscreen OpenGL for rendering (EGL via Mesa, OSMesa as a fallback).
set -euo pipefail
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq
apt-get install -y -qq --no-install-recommends \
  libegl1 libegl-mesa0 libgl1-mesa-dri libosmesa6 >/dev/null
# The scripts compile their update with torch.compile (--compile, the default): inductor builds
# C++ kernels with g++ against Python's headers.
apt-get install -y -qq --no-install-recommends g++ python3-dev >/dev/null
# A one-node Slurm cluster for sweep.py's tests (tests/slurm/start.sh starts the daemons;
# it needs pgrep from procps, absent from minimal images).
apt-get install -y -qq --no-install-recommends slurm-wlm munge procps >/dev/null

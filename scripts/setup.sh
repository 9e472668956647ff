#!/usr/bin/env bash
# Create .venv and install torchcontact with its test tools. torch is pinned and installed
# first: an unpinned torch would pull gigabytes of CUDA packages. The rest is held to the
# versions in scripts/constraints.txt, those the README's figures were measured with (a newer
# MuJoCo or numpy rounds differently, and chaotic trials end differently).
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m venv .venv
.venv/bin/python -m pip install --quiet --upgrade pip
.venv/bin/python -m pip install --quiet "torch==2.13.0"
.venv/bin/python -m pip install --quiet -c scripts/constraints.txt -e ".[dev]"
.venv/bin/python -c "import torch, mujoco, torchcontact; print('torch', torch.__version__, '| mujoco', mujoco.__version__, '| torchcontact ready')"
# The quick start's MPC graph, compiled once into this machine's compile cache (minutes, once):
# the quick start then plans compiled from its first step (torchcontact warm --help).
OMP_NUM_THREADS=1 .venv/bin/torchcontact warm fingertips --task rotation --object cube --no-progress

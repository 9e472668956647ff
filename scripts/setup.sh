#!/usr/bin/env bash
# Create .venv and install torchcontact with its test tools. torch is pinned and installed
# first: an unpinned torch would pull gigabytes of CUDA packages.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m venv .venv
.venv/bin/python -m pip install --quiet --upgrade pip
.venv/bin/python -m pip install --quiet "torch==2.13.0"
.venv/bin/python -m pip install --quiet -e ".[dev]"
.venv/bin/python -c "import torch, mujoco, torchcontact; print('torch', torch.__version__, '| mujoco', mujoco.__version__, '| torchcontact ready')"

#!/bin/bash
# Fit-rate probe of the recipe's depth student on the device (research/fit_precision.py): fp32 (TF32) against
# bf16 autocast, two batch sizes.
for f in .gl/*.deb; do dpkg -x $f / ; done; ldconfig  # EGL loaders: importing the trainer imports MuJoCo
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 3
export PYTHONPATH=/tmp/site:$PWD/.devsite:$PWD PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name --format=csv,noheader
for B in 256 1024; do python3 research/fit_precision.py --width 32 --batch $B --repeats 25; done

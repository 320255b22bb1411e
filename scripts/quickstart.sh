#!/usr/bin/env bash
# Set up (scripts/setup.sh), then run the quickstart scenario: 4 virtual IR webcams,
# 39 markers, 2 s of wave_slow -> out/quickstart/ (videos, ground truth, exports,
# metrics.json, report.md).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/simbench run scenarios/quickstart.toml --out out/quickstart
echo "open out/quickstart/report.md (plots in out/quickstart/plots/, videos in out/quickstart/videos/)"

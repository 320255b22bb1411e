#!/usr/bin/env bash
# Install the third-party capture tools the scoreboard compares against, each in its own
# virtual environment (they pin other OpenCV builds, so they never enter ./.venv):
#   .venv-aniposelib/  aniposelib (calibration, triangulation incl. RANSAC and optim)
#   .venv-pose2sim/    Pose2Sim (triangulation and filtering functions)
# Usage: scripts/setup_adapters.sh [aniposelib] [pose2sim]   (default: both)
# Idempotent: a stamp file per venv records the pinned versions it holds.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
ANIPOSELIB_VERSION=0.8.0
POSE2SIM_VERSION=0.10.49
# aniposelib 0.8.0 asks for opencv-contrib-python>=4.7 and pip picks 5.x, where
# findChessboardCorners returns an empty array (not None) on a frame without the board and
# aniposelib's cornerSubPix call then fails the whole video: pin the last 4.x.
ANIPOSELIB_OPENCV=opencv-contrib-python==4.14.0.94

install_venv() {  # name, pip requirements...
  local dir=".venv-$1"; shift
  local want="$*"
  if [ -f "$dir/.simbench-adapter" ] && [ "$(cat "$dir/.simbench-adapter")" = "$want" ]; then
    echo "$dir: up to date ($want)"; return 0
  fi
  [ -x "$dir/bin/python" ] || "$PY" -m venv "$dir"
  "$dir/bin/python" -m pip install --quiet --upgrade pip
  "$dir/bin/python" -m pip install --quiet "$@"
  "$dir/bin/python" -m pip check
  echo "$want" > "$dir/.simbench-adapter"
  echo "$dir: installed $want"
}

targets=("$@")
[ ${#targets[@]} -gt 0 ] || targets=(aniposelib pose2sim)
for t in "${targets[@]}"; do
  case "$t" in
    aniposelib) install_venv aniposelib "aniposelib==$ANIPOSELIB_VERSION" "$ANIPOSELIB_OPENCV" ;;
    pose2sim) install_venv pose2sim "pose2sim==$POSE2SIM_VERSION" ;;
    *) echo "scripts/setup_adapters.sh: unknown adapter '$t' (known: aniposelib, pose2sim)" >&2; exit 2 ;;
  esac
done

#!/usr/bin/env bash
# Set up simbench in ./.venv (Python 3.11+) and check that off-screen OpenGL works.
# Idempotent: re-running only installs what is missing.
set -euo pipefail
cd "$(dirname "$0")/.."

PY=${PYTHON:-python3}
if ! "$PY" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)' 2>/dev/null; then
  echo "simbench needs Python >= 3.11 (found: $("$PY" --version 2>&1)). Install it, or set PYTHON=/path/to/python3.11" >&2
  exit 2
fi
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv || { echo "could not create .venv: on Debian/Ubuntu run: sudo apt-get install -y python3-venv" >&2; exit 2; }
fi
stamp=.venv/.simbench-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  .venv/bin/python -m pip install --quiet --upgrade pip
  .venv/bin/python -m pip install --quiet -e ".[test]"
  .venv/bin/python -m pip check
  touch "$stamp"
fi

# Off-screen GL: EGL on Mesa (llvmpipe) first, OSMesa as the fallback.
need_pkgs=()
ldconfig -p 2>/dev/null | grep -q 'libEGL.so.1' || need_pkgs+=(libegl1)
ldconfig -p 2>/dev/null | grep -q 'libGL.so.1' || need_pkgs+=(libgl1)
compgen -G '/usr/lib/*/dri/swrast_dri.so' >/dev/null || need_pkgs+=(libgl1-mesa-dri)  # llvmpipe lives in swrast_dri.so
if [ ${#need_pkgs[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    apt-get update -qq && apt-get install -y -qq "${need_pkgs[@]}" >/dev/null
  else
    echo "off-screen rendering needs: sudo apt-get install -y ${need_pkgs[*]}" >&2
  fi
fi
if ! .venv/bin/python -m simbench.gl_check; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    echo "EGL failed; installing OSMesa (libosmesa6) and retrying with MUJOCO_GL=osmesa" >&2
    apt-get update -qq && apt-get install -y -qq libosmesa6 >/dev/null
    export MUJOCO_GL=osmesa PYOPENGL_PLATFORM=osmesa
    .venv/bin/python -m simbench.gl_check || exit 2
    echo "export MUJOCO_GL=osmesa PYOPENGL_PLATFORM=osmesa before running simbench on this machine" >&2
  else
    echo "no off-screen GL: run 'sudo apt-get install -y libegl1 libgl1-mesa-dri' (EGL) or 'sudo apt-get install -y libosmesa6' and export MUJOCO_GL=osmesa PYOPENGL_PLATFORM=osmesa" >&2
    exit 2
  fi
fi

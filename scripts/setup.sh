#!/usr/bin/env bash
# One-shot set-up on a fresh Debian machine with Python 3.11: Debian packages, the
# virtualenv, the project's Python dependencies and the ROS interface packages. Safe to
# run again: it only installs what is missing.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${VENV:-.venv}
PYTHON=${PYTHON:-python3.11}

# Debian packages: espeak-ng (speech), Mesa's EGL and GL drivers (headless MuJoCo), cmake and
# a C++ compiler (the ROS interface packages in interfaces/).
debs=(espeak-ng libegl1 libegl-mesa0 libgl1-mesa-dri libgles2 cmake g++ make)
missing=()
for p in "${debs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
# The interface build compiles against Python's headers: Debian's python3.11 keeps them in
# python3.11-dev (a pyenv or python.org build ships its own).
if command -v "$PYTHON" >/dev/null &&
  ! "$PYTHON" -c 'import os, sysconfig, sys; sys.exit(not os.path.exists(os.path.join(sysconfig.get_paths()["include"], "Python.h")))'; then
  missing+=("${PYTHON##*/}-dev")
fi
if [ ${#missing[@]} -gt 0 ]; then
  echo "setup: installing Debian packages: ${missing[*]}"
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${missing[@]}" >/dev/null
fi

if [ ! -x "$VENV/bin/python" ]; then
  echo "setup: creating $VENV with $PYTHON"
  "$PYTHON" -m venv "$VENV"
fi
# The extras: dev (pytest, ruff, mypy) and ray (`vigil montecarlo --ray`, tested by `make
# test`). The stamp holds them: a changed pyproject.toml or list of extras installs again.
extras="dev,ray"
stamp="$VENV/.installed"
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ] || [ "$(cat "$stamp")" != "$extras" ]; then
  echo "setup: installing Python dependencies ($extras) into $VENV"
  "$VENV/bin/python" -m pip install -q --upgrade pip
  "$VENV/bin/python" -m pip install -q -e ".[$extras]"
  echo "$extras" >"$stamp"
fi

# The ROS interface packages (vigil_interfaces, tf2_msgs): built once, cached by a hash.
VENV="$VENV" bash scripts/build_interfaces.sh

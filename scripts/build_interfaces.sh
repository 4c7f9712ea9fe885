#!/usr/bin/env bash
# Build the ROS 2 interface packages in interfaces/ (vigil_interfaces, tf2_msgs) with cmake and
# the PyPI rosidl generators, and install them into the virtualenv's prefix beside the ROS
# wheels: libraries in $VENV/lib (on the loader path the wheels' bootstrapper sets), Python
# modules in site-packages, the ament index and message definitions in $VENV/share.
#
# Skipped when the stamp $VENV/.interfaces-hash holds the hash of interfaces/, this script,
# the generator versions and the Python version, and the messages import. Called by
# scripts/setup.sh; safe to run again. Build files stay in $VENV/interfaces-build.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${VENV:-.venv}
VENV=$(cd "$VENV" && pwd)  # cmake needs an absolute prefix
PY="$VENV/bin/python"
PACKAGES=(tf2_msgs vigil_interfaces)

# The generators' and runtime's versions: a new wheel means a new build.
versions=$("$PY" - <<'EOF'
import sys
from importlib import metadata
names = sorted(
    d.metadata["Name"] for d in metadata.distributions()
    if d.metadata["Name"] and d.metadata["Name"].lower().startswith(("ros-rosidl", "ros-ament-cmake"))
)
print(sys.version.split()[0], *(f"{n}=={metadata.version(n)}" for n in names))
EOF
)
hash=$( {
  echo "$versions"
  sha256sum scripts/build_interfaces.sh
  find interfaces -type f -print0 | LC_ALL=C sort -z | xargs -0 sha256sum
} | sha256sum | cut -d' ' -f1)
stamp="$VENV/.interfaces-hash"
imports="import tf2_msgs.msg, vigil_interfaces.msg, vigil_interfaces.action"

if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$hash" ] && "$PY" -c "$imports" 2>/dev/null; then
  exit 0
fi

for tool in cmake g++ make; do
  command -v "$tool" >/dev/null || {
    echo "build_interfaces: '$tool' is missing (scripts/setup.sh installs it)" >&2
    exit 1
  }
done

echo "setup: building the ROS interface packages (${PACKAGES[*]}) into $VENV"
start=$(date +%s)
build="$VENV/interfaces-build"
export AMENT_PREFIX_PATH="$VENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"  # the typesupports' index
rm -f "$stamp"
for pkg in "${PACKAGES[@]}"; do
  echo "setup:   $pkg"
  log="$build/$pkg.log"
  # a build folder configured from another checkout sharing this venv (a git worktree):
  # CMake refuses another source for its cache, so start that package's build afresh
  cache="$build/$pkg/CMakeCache.txt"
  if [ -f "$cache" ] && ! grep -qxF "CMAKE_HOME_DIRECTORY:INTERNAL=$PWD/interfaces/$pkg" "$cache"; then
    rm -rf "${build:?}/$pkg"
  fi
  mkdir -p "$build/$pkg"
  if ! {
    cmake -S "interfaces/$pkg" -B "$build/$pkg" \
      -DCMAKE_BUILD_TYPE=Release \
      -DCMAKE_INSTALL_PREFIX="$VENV" \
      -DCMAKE_PREFIX_PATH="$VENV" \
      -DPython3_EXECUTABLE="$PY" \
      -DPython3_FIND_VIRTUALENV=ONLY \
      -DBUILD_TESTING=OFF &&
      cmake --build "$build/$pkg" -j "$(nproc)" &&
      cmake --install "$build/$pkg"
  } >"$log" 2>&1; then
    tail -n 40 "$log" >&2
    echo "build_interfaces: building $pkg failed; the whole log is $log" >&2
    exit 1
  fi
done

if ! "$PY" -c "$imports"; then
  echo "build_interfaces: built, but the messages do not import with $PY" >&2
  exit 1
fi
echo "$hash" >"$stamp"
echo "setup: interface packages built in $(($(date +%s) - start)) s"

#!/usr/bin/env bash
# Installs the benchmark peers into the venv given as $1 (default .venv), each on its
# own: one that cannot be had is reported and skipped, never fatal. Peers are never
# runtime dependencies of geosynth.
set -u
venv=${1:-.venv}
pip="$venv/bin/python -m pip --disable-pip-version-check --quiet"
apt_ok=0
if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
  # open3d needs libusb at import; pysdf has no wheel and builds against Eigen.
  if apt-get install -y -qq libusb-1.0-0 libeigen3-dev >/dev/null 2>&1 \
     || { apt-get update -qq >/dev/null 2>&1 && apt-get install -y -qq libusb-1.0-0 libeigen3-dev >/dev/null 2>&1; }; then
    apt_ok=1
  fi
fi
[ "$apt_ok" = 1 ] || echo "install_peers: could not apt-get libusb-1.0-0 / libeigen3-dev (not root or no apt): open3d and pysdf may be missing"
for spec in faiss-cpu open3d mesh2sdf; do
  $pip install "$spec" >/dev/null 2>&1 && echo "install_peers: $spec ok" || echo "install_peers: $spec could not be installed; its rows are left out"
done
CPLUS_INCLUDE_PATH=/usr/include/eigen3 $pip install pysdf >/dev/null 2>&1 \
  && echo "install_peers: pysdf ok" || echo "install_peers: pysdf could not be built; its rows are left out"
exit 0

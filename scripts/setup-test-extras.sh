#!/usr/bin/env bash
# Test extras: PCL (Debian libpcl-dev) and build the small pybind11 binding of the paper's PCL
# baselines (Harris3D + SHOT, OUR-CVFH) into the cache, when root; otherwise say what to do.
# Also Debian's chromium, headless, for the browser tests of `jsrte view` and `jsrte report`.
set -euo pipefail
cd "$(dirname "$0")/.."
# The dev extras (pytest-xdist runs the suite in two processes), where a .venv predates them.
.venv/bin/python -c "import xdist" 2>/dev/null || .venv/bin/python -m pip install -q -e ".[dev]"
if ! command -v chromium >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ]; then
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null \
      || echo "setup-test-extras: chromium did not install; the browser tests are skipped" >&2
  else
    echo "setup-test-extras: install chromium (Debian) for the browser tests of jsrte view/report (they skip)" >&2
  fi
fi
if [ ! -f /usr/include/pcl-1.13/pcl/features/shot.h ]; then
  if [ "$(id -u)" = 0 ]; then
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libpcl-dev pybind11-dev g++ pkg-config >/dev/null
  else
    echo "setup-pcl: install libpcl-dev pybind11-dev g++ pkg-config for the PCL baselines (their tests skip)" >&2
    exit 0
  fi
fi
.venv/bin/python -m jsrte.baselines.pcl || echo "setup-pcl: the PCL binding did not build; the PCL baselines are skipped" >&2
# Ray (for `jsrte fit-many --ray` and its local test); optional for users: pip install -e ".[ray]"
.venv/bin/python -m pip install -q -e ".[ray]" || echo "setup-pcl: Ray did not install; its test is skipped" >&2

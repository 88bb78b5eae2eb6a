#!/usr/bin/env bash
# Set up a fresh Debian/Ubuntu machine for AMRST Studio, then run the app or the tests.
#   bash packaging/bootstrap.sh app  [TARGET SOURCE]   -> opens the app (bundled sample by default)
#   bash packaging/bootstrap.sh test [PYTEST ARGS]     -> runs the whole test suite headless
# Idempotent: the second run skips what is already installed.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$here"
mode="${1:-app}"; shift || true

# System libraries Qt (xcb), VTK (GL) and open3d (libusb) need; Xvfb for headless use.
# Without libxcb-cursor0/icccm4/keysyms1 Qt aborts, without libusb open3d fails;
# gcc and python3-dev build python-lzf (compiled LZF for PCD), which has no wheel.
apt_pkgs="xvfb xauth libgl1 libgl1-mesa-dri libglx-mesa0 libegl1 libegl-mesa0 libglib2.0-0 \
libdbus-1-3 libfontconfig1 fonts-dejavu-core libx11-xcb1 libxkbcommon-x11-0 libxcb-cursor0 \
libxcb-icccm4 libxcb-image0 libxcb-keysyms1 libxcb-randr0 libxcb-render-util0 libxcb-shape0 \
libxcb-xfixes0 libxcb-sync1 libxcb-xkb1 libusb-1.0-0 libxcursor1 gcc python3-dev"
if command -v dpkg-query >/dev/null 2>&1; then
  missing=""
  for p in $apt_pkgs; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "ok installed" || missing="$missing $p"
  done
  if [ -n "$missing" ]; then
    echo "[bootstrap] installing system packages:$missing"
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends $missing >/dev/null
  fi
fi

# Python environment in .venv, reinstalled only when pyproject.toml changes.
py="${PYTHON:-python3}"
[ -x .venv/bin/python ] || "$py" -m venv .venv
stamp=".venv/.amrst-installed"
want="$(sha256sum pyproject.toml | cut -d' ' -f1)"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  echo "[bootstrap] installing Python packages into .venv (first time: about a minute)"
  .venv/bin/python -m pip install -q --upgrade pip
  .venv/bin/python -m pip install -q -e ".[all,test]"
  echo "$want" > "$stamp"
fi

export LIBGL_ALWAYS_SOFTWARE="${LIBGL_ALWAYS_SOFTWARE:-1}"
case "$mode" in
  app)
    if [ -z "${DISPLAY:-}" ] && [ -z "${WAYLAND_DISPLAY:-}" ]; then
      echo "[bootstrap] no display found: starting the app on a virtual screen (xvfb-run)."
      echo "[bootstrap] it runs but cannot be seen here; stop it with Ctrl+C. To see it, run this"
      echo "[bootstrap] on a desktop or over ssh -X; for a picture: .venv/bin/amrst-gui --screenshot out.png"
      exec xvfb-run -a -s "-screen 0 1600x1000x24" .venv/bin/amrst-gui "$@"
    fi
    exec .venv/bin/amrst-gui "$@"
    ;;
  test)
    # Architecture contract: amrst/ never imports Qt or pyvista.
    .venv/bin/lint-imports --config pyproject.toml
    # House rules, configured in pyproject.toml: layout, lint, then types.
    .venv/bin/ruff format --check --quiet .
    .venv/bin/ruff check .
    .venv/bin/python -m mypy
    # Own process group under a timeout, so a crash never leaves Xvfb behind.
    # SIGABRT at the timeout: pytest's faulthandler prints every thread's stack.
    export QT_QPA_PLATFORM=xcb
    set +e
    # Wall-clock checks (the perf marker) depend on how loaded the machine is: they
    # run on request only (pytest -m perf), never in this command.
    timeout -s ABRT --kill-after=30 1500 setsid .venv/bin/python -m pytest -m "not perf" -n 2 --durations=15 "$@"
    rc=$?
    set -e
    exit $rc
    ;;
  *)
    echo "usage: bash packaging/bootstrap.sh app|test [args]" >&2; exit 2;;
esac

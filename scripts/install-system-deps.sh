#!/usr/bin/env bash
# Installs the Debian packages gyrocal's tests drive for real, when they are missing.
set -euo pipefail
need=()
command -v dbus-daemon >/dev/null 2>&1 || need+=(dbus)
# the store tests start a throwaway PostgreSQL cluster from Debian's server binaries
compgen -G "/usr/lib/postgresql/*/bin/initdb" >/dev/null || need+=(postgresql)
# the firmware library (wearable_protocol/c) is built and tested with the system C compiler
command -v cc >/dev/null 2>&1 || need+=(gcc libc6-dev)
# the wizard page tests drive Debian's Chromium headless shell through Playwright (never a downloaded browser)
[ -x /usr/lib/chromium/chromium-headless-shell ] || need+=(chromium-headless-shell)
# a fleet test runs one gateway with its clock set back (libfaketime), as a gateway off NTP would be
compgen -G "/usr/lib/*/faketime/libfaketime.so.1" >/dev/null || need+=(faketime)
if [ ${#need[@]} -eq 0 ]; then
  exit 0
fi
if [ "$(id -u)" -ne 0 ]; then
  echo "gyrocal tests need these Debian packages: ${need[*]}" >&2
  echo "Install them with: sudo apt-get install -y ${need[*]}" >&2
  exit 1
fi
export DEBIAN_FRONTEND=noninteractive
# another apt (an unattended upgrade, a second terminal) may hold the lock: wait for it rather than fail
wait_lock=(-o DPkg::Lock::Timeout=600)
apt-get "${wait_lock[@]}" update -qq
apt-get "${wait_lock[@]}" install -y -qq --no-install-recommends "${need[@]}"

#!/usr/bin/env bash
# Make sure a PoCL that can compile kernels on this CPU is present.
# The pip PoCL 3.0 (LLVM 14) rejects CPUs LLVM 14 does not know (e.g. AMD Zen 5: "unknown target
# CPU 'generic'"); then install the distribution's PoCL, which reings picks up automatically.
set -u
PY=${1:-.venv/bin/python}
if "$PY" -m reings.backends.opencl.device pocl; then exit 0; fi
echo "ensure_pocl: the pip PoCL cannot compile on this CPU; installing the system PoCL (pocl-opencl-icd)" >&2
SUDO=""
if [ "$(id -u)" != 0 ]; then SUDO="sudo -n"; fi
if command -v apt-get >/dev/null 2>&1; then
  $SUDO apt-get install -y -q pocl-opencl-icd >/dev/null 2>&1 || \
    { $SUDO apt-get update -q >/dev/null 2>&1 && $SUDO apt-get install -y -q pocl-opencl-icd >/dev/null 2>&1; }
fi
"$PY" -m reings.backends.opencl.device pocl || {
  echo "ensure_pocl: no working PoCL; install your distribution's PoCL package (pocl-opencl-icd)" >&2; exit 1; }

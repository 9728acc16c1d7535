#!/usr/bin/env bash
# Issue 14 item 21: a plain `pip install` (no extras) must refuse a run that needs OpenCV before any
# work, in one line that names the package and the install command, and write nothing.
set -uo pipefail
cd "$(dirname "$0")/.."
V=${1:-/tmp/reings_noextras}
rm -rf "$V" /tmp/reings_noextras_run
python3 -m venv "$V" && "$V/bin/python" -m pip install -q -e . || { echo "no-extras install failed" >&2; exit 1; }
"$V/bin/python" -c "import cv2" 2>/dev/null && { echo "cv2 is importable without extras?" >&2; exit 1; }
out=$("$V/bin/reings" run --out /tmp/reings_noextras_run 2>&1); rc=$?
echo "$out"
[ $rc = 2 ] || { echo "expected exit 2, got $rc" >&2; exit 1; }
echo "$out" | grep -q "needs OpenCV: pip install 'reings\[data\]'" || { echo "no install hint" >&2; exit 1; }
[ "$(echo "$out" | wc -l)" = 1 ] || { echo "expected one line" >&2; exit 1; }
[ ! -e /tmp/reings_noextras_run ] || { echo "the refused run wrote /tmp/reings_noextras_run" >&2; exit 1; }
"$V/bin/python" -c "import reings, sys; assert 'torch' not in sys.modules; print('import reings without extras: ok')"
echo "no-extras check passed"

#!/bin/sh
# Install the Debian packages minirt needs (POV-Ray, and libLLVM >= 19 for Dr.Jit's LLVM backend).
# As root: apt-get installs what is missing. Otherwise: print the exact command and fail.
missing=""
for p in "$@"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
done
[ -z "$missing" ] && exit 0
if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
    echo "installing Debian packages:$missing"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq && apt-get install -y -qq --no-install-recommends $missing >/dev/null || {
        echo "error: apt-get install$missing failed" >&2; exit 2; }
    exit 0
fi
echo "error: missing Debian packages:$missing" >&2
echo "run:   sudo apt-get update && sudo apt-get install -y$missing" >&2
exit 2

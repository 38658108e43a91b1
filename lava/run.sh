#!/bin/sh
# Install runner (into a virtual environment, from this checkout) and run one scenario, reporting each cell
# to LAVA: the run's --lava calls lava-test-set and lava-test-case when LAVA put them on PATH, and prints
# the same lines otherwise, so this script runs the same on a desk as in a lab (docs/labs.md).
#
#   lava/run.sh [SCENARIO [DURATION [OUT [VENV]]]]
#
# The results go to OUT/<UTC time>/ (results.json, report.md, junit.xml and kcidb.json for KernelCI).
#
# Exits 0 when the run judged its cells (its verdicts are the test cases, failed ones included); a
# run that could not judge them (invalid input 2, missing permission 3, run error 4, interrupted 130)
# is the case `runner-run` failed, and its exit code is this script's, so LAVA stops the definition.
set -u

scenario=${1:-scenarios/fifo80.yaml}
duration=${2:-}
out=${3:-/tmp/runner-lava}
venv=${4:-/tmp/runner-lava-venv}
here=$(cd "$(dirname "$0")/.." && pwd)

case_() {  # as LAVA asks of test scripts: its helper when it is there, the same line otherwise
    if command -v lava-test-case >/dev/null 2>&1; then
        lava-test-case "$@"
    else
        echo "lava-test-case $*"
    fi
}

if [ ! -x "$venv/bin/runner" ]; then
    echo "runner: installing from $here into $venv"
    if ! { python3 -m venv "$venv" && "$venv/bin/python" -m pip install --quiet "$here"; }; then
        case_ runner-install --result fail
        exit 1
    fi
fi
case_ runner-install --result pass

run="$out/$(date -u +%Y%m%dT%H%M%SZ)"  # a folder of its own: a run never writes into another's
set -- "$scenario" --out "$run" --lava --junit "$run/junit.xml" --no-plots
if [ -n "$duration" ]; then
    set -- "$@" --duration "$duration"
fi
"$venv/bin/runner" "$@"
code=$?
if [ -f "$run/results.json" ]; then  # KernelCI's format beside, for the lab to submit (no network here)
    "$venv/bin/runner" report "$run" --kcidb "$run/kcidb.json" || true
fi

case $code in
    0 | 1) exit 0 ;;
    *)
        case_ runner-run --result fail --measurement "$code" --units exit-code
        exit "$code"
        ;;
esac

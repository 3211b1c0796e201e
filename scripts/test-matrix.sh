#!/usr/bin/env bash
# `make test-matrix`: every test that runs tshark, against each supported Wireshark release:
# 4.0 from this machine (Debian 12), 4.4 and 4.6 from Debian 13 and unstable root filesystems
# (scripts/rootfs.sh, built when missing; scripts/tshark-in-rootfs runs tshark there as an
# unprivileged user). The tests get the release through $SHAREDLINK_TSHARK. Before the tests,
# each release must load every dissector/*.lua and decode the sample captures, or it fails.
#
#   scripts/test-matrix.sh [PYTEST ARG...]      e.g. -x, -k prefix
#   MATRIX_RELEASES="host sid" scripts/test-matrix.sh
set -uo pipefail
cd "$(dirname "$0")/.." || exit 2
PY=${PY:-.venv/bin/python}
read -r -a releases <<<"${MATRIX_RELEASES:-host trixie sid}"
# the test files that run tshark: through tests/tshark_util.py (or sl_checks.py), the fuzz harness or the variable
mapfile -t tests < <(grep -rl -E 'tshark_util|sl_checks|fuzz_harness|SHAREDLINK_TSHARK' --include='test_*.py' tests | sort)
[ ${#tests[@]} -gt 0 ] || { echo "test-matrix: no test file runs tshark" >&2; exit 2; }
echo "test-matrix: ${#tests[@]} test files: ${tests[*]}"

summary=()
failed=0
for rel in "${releases[@]}"; do
    if [ "$rel" = host ]; then cmd=tshark; else cmd="scripts/tshark-in-rootfs $rel"; fi
    start=$SECONDS
    version=$($cmd --version 2>/dev/null | head -1)
    [ -n "$version" ] || version="(no tshark)"
    echo; echo "== $rel: $version"
    # the check first (it names the failure plainly), then the tests whatever it said
    result=passed
    SHAREDLINK_TSHARK="$cmd" $PY scripts/fuzz.py --check || result=FAILED
    SHAREDLINK_TSHARK="$cmd" $PY -m pytest -q -n 2 -p no:cacheprovider "$@" "${tests[@]}" || result=FAILED
    [ $result = passed ] || failed=1
    summary+=("$(printf '%-7s %-7s %4d s  %s' "$rel" "$result" $((SECONDS - start)) "$version")")
done
echo; echo "== test-matrix"
printf '%s\n' "${summary[@]}"
exit $failed

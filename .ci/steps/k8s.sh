#!/usr/bin/env bash
# CI step: the Kubernetes manifests in deploy/k8s are consistent (names,
# ports, env, Secret keys, resources, probes; tests/k8s/check_manifests.py),
# and the checker reports broken ones: each break of its self-test, and a
# copy of the manifests with a Secret key renamed. No cluster runs here: the
# manifests have not been applied to a live cluster in CI.
set -euo pipefail
cd "$(dirname "$0")/../.."

command -v python3 >/dev/null 2>&1 || {
  echo "SKIPPED: k8s manifest checks (no python3)"
  exit 0
}
if ! python3 -c 'import yaml' 2>/dev/null; then
  echo "installing PyYAML"
  python3 -m pip install --quiet --user pyyaml >/dev/null 2>&1 ||
    python3 -m pip install --quiet --break-system-packages --user pyyaml >/dev/null 2>&1 || true
fi
python3 -c 'import yaml' 2>/dev/null || {
  echo "SKIPPED: k8s manifest checks (PyYAML not installed and pip could not install it)"
  exit 0
}

python3 tests/k8s/check_manifests.py deploy/k8s
python3 tests/k8s/check_manifests.py --self-test deploy/k8s

broken=$(mktemp -d)
trap 'rm -rf "$broken"' EXIT
cp deploy/k8s/*.yaml "$broken/"
sed -i 's/^  token: /  admin-token: /' "$broken/secret.example.yaml"
if out=$(python3 tests/k8s/check_manifests.py "$broken"); then
  echo "FAIL: a Secret without the key 'token' passed the checks" >&2
  exit 1
fi
grep -q "asks for key 'token'" <<<"$out" || {
  echo "FAIL: the renamed Secret key was not named in the report:" >&2
  echo "$out" >&2
  exit 1
}
echo "PASS: a manifest set with a renamed Secret key is reported ($(grep -c '^FAIL' <<<"$out") problems)"

#!/usr/bin/env bash
# CI step: the compose deployment end to end (tests/compose/smoke.sh) when a
# Docker engine answers; otherwise a SKIPPED line and success.
set -euo pipefail
cd "$(dirname "$0")/../.."

if ! command -v docker >/dev/null 2>&1; then
  echo "SKIPPED: compose smoke test (no docker command on this machine)"
  exit 0
fi
if ! timeout 20 docker info >/dev/null 2>&1; then
  echo "SKIPPED: compose smoke test (no Docker engine answers \`docker info\`)"
  exit 0
fi
# Tools the smoke test needs, from Debian's packages when missing.
need=()
docker compose version >/dev/null 2>&1 || command -v docker-compose >/dev/null 2>&1 ||
  need+=(docker-compose)
command -v curl >/dev/null 2>&1 || need+=(curl)
command -v python3 >/dev/null 2>&1 || need+=(python3)
if [ ${#need[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "installing ${need[*]}"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need[@]}" >/dev/null
  else
    echo "SKIPPED: compose smoke test (missing ${need[*]} and cannot apt-get install)"
    exit 0
  fi
fi

bash tests/compose/smoke.sh

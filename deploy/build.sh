#!/usr/bin/env bash
# Builds the statically linked `irlgrid` binary and the deploy image from it,
# in one step:
#
#   deploy/build.sh [TAG]        # TAG defaults to $IRLGRID_IMAGE or irlgrid:latest
#
# The binary links glibc statically (`-C target-feature=+crt-static`) so the
# image can be `FROM scratch`. `--target` is given explicitly so that the flag
# reaches only the binary, not build scripts or proc macros. CARGO_TARGET_DIR
# is honoured (default: target/). IRLGRID_BINARY=PATH skips cargo and
# packages that (static) binary instead.
set -euo pipefail
cd "$(dirname "$0")/.."

tag=${1:-${IRLGRID_IMAGE:-irlgrid:latest}}
triple=x86_64-unknown-linux-gnu
target_dir=${CARGO_TARGET_DIR:-target}

if [ -n "${IRLGRID_BINARY:-}" ]; then
  # A binary built earlier (or elsewhere) with the command below.
  bin=$IRLGRID_BINARY
  echo "==> using the prebuilt $bin (IRLGRID_BINARY)"
else
  echo "==> cargo build --release --target $triple (static)"
  RUSTFLAGS="${RUSTFLAGS:-} -C target-feature=+crt-static" \
    cargo build --release --locked --target "$triple" --bin irlgrid
  bin=$target_dir/$triple/release/irlgrid
fi

# A dynamic binary would fail in the scratch image with a confusing
# "no such file or directory": refuse it here instead.
if readelf -d "$bin" 2>/dev/null | grep -q '(NEEDED)' \
  || readelf -l "$bin" 2>/dev/null | grep -q 'INTERP'; then
  echo "error: $bin is dynamically linked; the scratch image needs a static binary" >&2
  readelf -d "$bin" | grep NEEDED >&2 || true
  exit 1
fi

ctx=$(mktemp -d)
trap 'rm -rf "$ctx"' EXIT
# The release profile keeps line tables (80 MB); the image gets a copy
# without them (about 18 MB). Symbols stay, so backtraces still name functions.
strip --strip-debug -o "$ctx/irlgrid" "$bin"
chmod 0555 "$ctx/irlgrid"
mkdir -m 0755 "$ctx/data"

echo "==> docker build -t $tag"
docker build -f deploy/Dockerfile -t "$tag" "$ctx"
echo "built $tag ($(du -h "$ctx/irlgrid" | cut -f1) binary)"

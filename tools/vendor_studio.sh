#!/bin/sh
# Refresh the studio's vendored JavaScript (graphkit/studio/static/vendor/) from the npm
# registry: each package's pinned tarball is downloaded, checked against SHA256SUMS (the
# tarball's checksum and each vendored file's), and the files the studio loads are copied out
# with the package's licence.  `make vendor-studio`; `make vendor-studio UPDATE=1` writes
# new checksums after a deliberate version change (review the diff).
set -eu
VENDOR=graphkit/studio/static/vendor
SUMS=$VENDOR/SHA256SUMS
TMP=$(mktemp -d); trap 'rm -rf "$TMP"' EXIT
# name version tarball-url file... (paths inside the tarball's package/)
PACKAGES='
litegraph 0.17.2 https://registry.npmjs.org/@comfyorg/litegraph/-/litegraph-0.17.2.tgz dist/litegraph.umd.js dist/css/litegraph.css LICENSE
elkjs 0.12.1 https://registry.npmjs.org/elkjs/-/elkjs-0.12.1.tgz lib/elk.bundled.js LICENSE.md
'
echo "$PACKAGES" | while read -r name version url files; do
  [ -n "$name" ] || continue
  tgz=$TMP/$name-$version.tgz
  curl -fsSL "$url" -o "$tgz"
  mkdir -p "$TMP/$name" && tar xzf "$tgz" -C "$TMP/$name"
  dest=$VENDOR/$name-$version
  rm -rf "$dest" && mkdir -p "$dest"
  for f in $files; do cp "$TMP/$name/package/$f" "$dest/$(basename "$f")"; done
  (cd "$TMP" && sha256sum "$name-$version.tgz") >> "$TMP/tarballs"
done
new=$TMP/SHA256SUMS
{ cat "$TMP/tarballs"; (cd "$VENDOR" && find . -type f ! -name SHA256SUMS | sort | xargs sha256sum); } > "$new"
if [ "${UPDATE:-}" = 1 ] || [ ! -f "$SUMS" ]; then cp "$new" "$SUMS"; echo "wrote $SUMS"; exit 0; fi
if ! diff -u "$SUMS" "$new"; then echo "vendor-studio: checksums differ from $SUMS (UPDATE=1 to accept)" >&2; exit 1; fi
echo "vendor-studio: $VENDOR matches $SUMS"

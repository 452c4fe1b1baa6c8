#!/usr/bin/env bash
# The committed Python stubs (client/python/dance/v1/dance_pb2*.py) must be what protoc generates from
# proto/dance/v1/dance.proto today: regenerate into a temporary directory and compare byte for byte.
# Usage: python_stubs_test.sh SOURCE_DIR PROTOC GRPC_PYTHON_PLUGIN
set -euo pipefail
src="$1" protoc="$2" plugin="$3"
out="$(mktemp -d)"
trap 'rm -rf "$out"' EXIT
"$protoc" -I "$src/proto" --python_out="$out" --grpc_python_out="$out" \
  --plugin=protoc-gen-grpc_python="$plugin" "$src/proto/dance/v1/dance.proto"
status=0
for f in dance_pb2.py dance_pb2_grpc.py; do
  if ! cmp -s "$out/dance/v1/$f" "$src/client/python/dance/v1/$f"; then
    echo "client/python/dance/v1/$f is stale: regenerate with" >&2
    echo "  protoc -I proto --python_out=client/python --grpc_python_out=client/python \\" >&2
    echo "    --plugin=protoc-gen-grpc_python=$plugin proto/dance/v1/dance.proto" >&2
    status=1
  fi
done
[ "$status" = 0 ] && echo "python stubs match proto/dance/v1/dance.proto"
exit "$status"

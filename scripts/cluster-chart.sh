#!/usr/bin/env bash
# Checks the Helm chart (deploy/helm/dance): helm lint, helm template with the default values and with an
# external store, every rendered manifest decoded strictly against the Kubernetes API types
# (deploy/helm/validate), and the rendered haproxy.cfg parsed by haproxy itself (haproxy -c).
# Installs helm (pinned) with go install if it is missing; needs Go (>= 1.24) and haproxy.
#   scripts/cluster-chart.sh
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
helm_version=v4.3.2
export PATH="$PATH:/usr/local/go/bin:$(go env GOPATH 2>/dev/null || echo "$HOME/go")/bin"
command -v go >/dev/null || { echo "cluster-chart.sh: Go is needed (helm and the validator are Go)" >&2; exit 1; }
if ! helm version --short 2>/dev/null | grep -q "^${helm_version%.*}"; then
  GOBIN=/usr/local/bin go install "helm.sh/helm/v4/cmd/helm@$helm_version"
fi
work=$(mktemp -d /tmp/dance-chart.XXXXXX)
trap 'rm -rf "$work"' EXIT
(cd "$root/deploy/helm/validate" && go build -o "$work/validate" .)
chart="$root/deploy/helm/dance"
helm lint --strict "$chart"
helm lint --strict "$chart" --set redis.enabled=false --set redis.externalAddress=redis.example:6379
for variant in default external-store no-autoscaling; do
  case $variant in
    default) args=() ;;
    external-store) args=(--set redis.enabled=false --set redis.externalAddress=redis.example:6379) ;;
    no-autoscaling) args=(--set autoscaling.enabled=false --set server.replicas=5) ;;
  esac
  helm template dance "$chart" --namespace dance "${args[@]}" >"$work/$variant.yaml"
  echo "--- $variant"
  "$work/validate" <"$work/$variant.yaml"
done
/usr/bin/python3 - "$work/default.yaml" "$work/haproxy.cfg" <<'PY'
import sys, yaml
for d in yaml.safe_load_all(open(sys.argv[1])):
    if d and d["kind"] == "ConfigMap" and "haproxy.cfg" in d.get("data", {}):
        open(sys.argv[2], "w").write(d["data"]["haproxy.cfg"])
PY
haproxy -c -f "$work/haproxy.cfg"
echo "cluster-chart.sh: passed"

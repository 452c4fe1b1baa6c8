{{/* haproxy.cfg of the proxy (templates/proxy.yaml); its hash restarts the proxy when it changes. */}}
{{- define "dance.proxyConfig" -}}
global
  maxconn 8000
resolvers kube
  parse-resolv-conf
  hold valid 5s
  hold obsolete 5s
defaults
  mode http
  timeout connect 2s
  timeout http-request 10s
  timeout client 1h
  timeout server 1h
  timeout tunnel 1h
  timeout client-fin 5s
  timeout server-fin 5s
  default-server inter 500ms fastinter 250ms downinter 500ms rise 1 fall 1 resolvers kube init-addr none
frontend dance
  bind :8000
  acl grpc req.hdr(content-type) -m beg application/grpc
  acl perform path /dance.v1.DanceService/Perform
  acl ws_perform path /ws/perform
  use_backend perform if grpc perform
  use_backend grpc if grpc
  use_backend ws_perform if ws_perform
  default_backend http
frontend health
  bind :8404
  monitor-uri /healthz
{{- $dns := printf "%s-server.%s.svc.cluster.local" (include "dance.name" .) .Release.Namespace }}
{{- $n := int .Values.proxy.maxServers }}
{{- $g := int .Values.server.grpcPort }}
{{- $h := int .Values.server.httpPort }}
backend perform
  balance leastconn
  option httpchk GET /healthz
  http-check expect status 200
  server-template s {{ $n }} {{ $dns }}:{{ $g }} proto h2 check-proto h1 check port {{ $h }}
backend grpc
  balance leastconn
  option httpchk GET /healthz
  http-check expect rstatus ^(200|503)$
  server-template s {{ $n }} {{ $dns }}:{{ $g }} proto h2 check-proto h1 check port {{ $h }}
backend ws_perform
  balance leastconn
  option httpchk GET /healthz
  http-check expect status 200
  server-template s {{ $n }} {{ $dns }}:{{ $h }} check
backend http
  balance leastconn
  option httpchk GET /healthz
  http-check expect rstatus ^(200|503)$
  server-template s {{ $n }} {{ $dns }}:{{ $h }} check
{{- end -}}

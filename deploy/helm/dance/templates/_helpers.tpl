{{- define "dance.name" -}}{{ .Release.Name }}-dance{{- end -}}
{{- define "dance.labels" -}}
app.kubernetes.io/name: dance
app.kubernetes.io/instance: {{ .Release.Name }}
app.kubernetes.io/version: {{ .Chart.AppVersion | quote }}
helm.sh/chart: {{ .Chart.Name }}-{{ .Chart.Version }}
{{- end -}}
{{- define "dance.selector" -}}
app.kubernetes.io/name: dance
app.kubernetes.io/instance: {{ .Release.Name }}
{{- end -}}
{{- define "dance.store" -}}
{{- if .Values.redis.enabled -}}{{ include "dance.name" . }}-redis:6379{{- else -}}{{ required "redis.externalAddress is required when redis.enabled=false" .Values.redis.externalAddress }}{{- end -}}
{{- end -}}

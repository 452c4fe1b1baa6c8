// The session picker's data and the model description, from the server's JSON API (docs/protocol.md):
//   GET api/sessions -> {"sessions": [{"session_id", "client_name", "started_unix_ms", "frames", "audio_ms",
//                                      "viewers", "style": [{"name", "weight"}]}]}
//   GET api/model    -> {"model_id", "latency_ms", "fps", "joint_names", "parents", "rest_offsets", "styles", ...}

import { apiUrl } from './connection.js';

/** Fetches the model description (styles, skeleton, latency). */
export async function fetchModel() {
  const res = await fetch(apiUrl('api/model'), { cache: 'no-store' });
  if (!res.ok) throw new Error(`api/model: HTTP ${res.status}`);
  return res.json();
}

/** Fetches the live sessions; resolves to [{id, ...}] (ids as strings). */
export async function fetchSessions() {
  const res = await fetch(apiUrl('api/sessions'), { cache: 'no-store' });
  if (!res.ok) throw new Error(`api/sessions: HTTP ${res.status}`);
  const body = await res.json();
  const list = Array.isArray(body) ? body : Array.isArray(body.sessions) ? body.sessions : [];
  return list
    .map((s) => (typeof s === 'object' && s !== null ? s : { id: s }))
    .map((s) => ({ ...s, id: String(s.id ?? s.session_id ?? '') }))
    .filter((s) => s.id !== '');
}

/** A one-line description of a session for the picker. */
export function sessionLabel(s) {
  const parts = [s.id];
  const style = Array.isArray(s.style) ?
    s.style.map((x) => (typeof x === 'string' ? x : x.name)).join('+') : s.style;
  if (style) parts.push(style);
  if (s.client_name) parts.push(s.client_name);
  if (typeof s.audio_ms === 'number') parts.push(`${Math.round(s.audio_ms / 1000)} s`);
  if (typeof s.viewers === 'number' && s.viewers > 0) parts.push(`${s.viewers} watching`);
  return parts.join(' \u00b7 ');
}

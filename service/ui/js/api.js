// The dashboard talks to Caliper only through the public REST API, like any other client.
// A token (when the server asks for one) lives in session storage: it is gone with the tab.

const TOKEN_KEY = 'caliper.token';

export function getToken() {
  return sessionStorage.getItem(TOKEN_KEY) || '';
}

export function setToken(t) {
  if (t) sessionStorage.setItem(TOKEN_KEY, t);
  else sessionStorage.removeItem(TOKEN_KEY);
}

/** An RFC 9457 problem returned by the API. */
export class ApiError extends Error {
  constructor(status, problem) {
    super(problem.detail || problem.title || `HTTP ${status}`);
    this.status = status;
    this.problem = problem;
    this.code = problem.code || 'http_' + status;
  }
}

function authHeaders(extra) {
  const headers = new Headers(extra || {});
  const t = getToken();
  if (t) headers.set('Authorization', 'Bearer ' + t);
  return headers;
}

async function problemOf(r) {
  try {
    return await r.json();
  } catch {
    return { title: r.statusText || 'request failed' };
  }
}

/** Fetch a path of the API; JSON bodies come back parsed, others as text. */
export async function api(path, opts = {}) {
  const init = { ...opts, headers: authHeaders(opts.headers) };
  if (opts.json !== undefined) {
    init.body = JSON.stringify(opts.json);
    init.headers.set('Content-Type', 'application/json');
    init.method = opts.method || 'POST';
  }
  const r = await fetch(path, init);
  if (r.status === 401) document.dispatchEvent(new CustomEvent('caliper:unauthorized'));
  if (!r.ok) throw new ApiError(r.status, await problemOf(r));
  const ct = r.headers.get('content-type') || '';
  if (ct.includes('json')) return r.json();
  return r.text();
}

/** Fetch bytes (an export or artifact) as a Blob, with the token. */
export async function apiBlob(path) {
  const r = await fetch(path, { headers: authHeaders() });
  if (!r.ok) throw new ApiError(r.status, await problemOf(r));
  return r.blob();
}

/** Upload files as one dataset; `onProgress(sent, total)` follows the bytes. */
export function uploadDataset(files, onProgress) {
  return new Promise((resolve, reject) => {
    const form = new FormData();
    for (const f of files) form.append('file', f, f.name);
    const xhr = new XMLHttpRequest();
    xhr.open('POST', '/v1/datasets');
    const t = getToken();
    if (t) xhr.setRequestHeader('Authorization', 'Bearer ' + t);
    xhr.upload.onprogress = (e) => onProgress && onProgress(e.loaded, e.total);
    xhr.onerror = () => reject(new ApiError(0, { title: 'network error during upload' }));
    xhr.onload = () => {
      let body;
      try {
        body = JSON.parse(xhr.responseText);
      } catch {
        body = { title: xhr.statusText };
      }
      if (xhr.status >= 200 && xhr.status < 300) resolve(body);
      else reject(new ApiError(xhr.status, body));
    };
    xhr.send(form);
  });
}

/**
 * Follow a job's Server-Sent Events. EventSource cannot send an Authorization header, so the
 * stream is read with fetch. Returns a function that stops following.
 */
export function followJob(id, onEvent, onEnd) {
  const ctrl = new AbortController();
  (async () => {
    try {
      const r = await fetch(`/v1/jobs/${encodeURIComponent(id)}/events`, {
        headers: authHeaders({ Accept: 'text/event-stream' }),
        signal: ctrl.signal,
      });
      if (!r.ok || !r.body) throw new ApiError(r.status, await problemOf(r));
      const reader = r.body.pipeThrough(new TextDecoderStream()).getReader();
      let buf = '';
      for (;;) {
        const { value, done } = await reader.read();
        if (done) break;
        buf += value;
        let cut;
        while ((cut = buf.indexOf('\n\n')) >= 0) {
          const block = buf.slice(0, cut);
          buf = buf.slice(cut + 2);
          let event = 'message';
          let data = '';
          for (const line of block.split('\n')) {
            if (line.startsWith('event:')) event = line.slice(6).trim();
            else if (line.startsWith('data:')) data += line.slice(5).trim();
          }
          if (data) {
            try {
              onEvent(event, JSON.parse(data));
            } catch {
              /* keep-alive comments and malformed blocks are skipped */
            }
          }
        }
      }
      onEnd && onEnd(null);
    } catch (e) {
      if (e.name !== 'AbortError') onEnd && onEnd(e);
    }
  })();
  return () => ctrl.abort();
}

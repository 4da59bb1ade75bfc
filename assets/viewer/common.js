// Shared by the viewer pages: API access (with an optional key kept in a cookie), error
// capture (so a test can see console errors in the DOM), small DOM helpers.

const errors = [];
function recordError(msg) {
  errors.push(String(msg));
  document.body.dataset.errors = String(errors.length);
  const pre = document.getElementById('console-errors');
  if (pre) { pre.textContent = errors.join('\n'); pre.hidden = false; }
}
window.addEventListener('error', (e) => recordError(e.message || e));
window.addEventListener('unhandledrejection', (e) => recordError(e.reason && e.reason.message || e.reason));
const consoleError = console.error.bind(console);
console.error = (...a) => { recordError(a.join(' ')); consoleError(...a); };

// A key given once as ?key=K is kept in a cookie scoped to the API's pages and removed
// from the address bar.
const KEY_COOKIE = 'grounder_key';
(function keepKey() {
  const params = new URLSearchParams(location.search);
  const k = params.get('key');
  if (k) {
    document.cookie = `${KEY_COOKIE}=${encodeURIComponent(k)}; path=/v1/; SameSite=Strict`;
    params.delete('key');
    const q = params.toString();
    history.replaceState(null, '', location.pathname + (q ? '?' + q : ''));
  }
})();
function apiKey() {
  const m = document.cookie.split('; ').find((c) => c.startsWith(KEY_COOKIE + '='));
  return m ? decodeURIComponent(m.slice(KEY_COOKIE.length + 1)) : null;
}

export async function api(path, as = 'json') {
  const headers = {};
  const k = apiKey();
  if (k) headers.Authorization = `Bearer ${k}`;
  const r = await fetch(path, { headers });
  if (!r.ok) {
    let detail = `${r.status}`;
    try { detail = (await r.json()).detail || detail; } catch (_) { /* not JSON */ }
    const err = new Error(`${path}: ${detail}`);
    err.status = r.status;
    throw err;
  }
  if (as === 'json') return r.json();
  if (as === 'blob') return r.blob();
  return r.arrayBuffer();
}

// An <img> for an API image, loaded (null when missing). Without a key the browser loads
// the URL itself; with one, it is fetched with the key and shown from a blob.
export function image(path) {
  return new Promise((resolve, reject) => {
    const img = new Image();
    img.onload = () => resolve(img);
    img.onerror = () => resolve(null);
    if (!apiKey()) { img.src = path; return; }
    api(path, 'blob').then((b) => { img.src = URL.createObjectURL(b); })
      .catch((e) => (e.status === 404 ? resolve(null) : reject(e)));
  });
}

// Follow a job until it is terminal, calling onUpdate(job) whenever its trace or status
// changed. Polls GET /v1/jobs/{id}; an events stream can replace this one function.
export async function watchJob(id, onUpdate, intervalMs = 1000) {
  let seen = '';
  for (;;) {
    const job = await api(`/v1/jobs/${id}`);
    const sig = `${job.status}/${(job.trace || []).length}`;
    if (sig !== seen) { seen = sig; await onUpdate(job); }
    if (['succeeded', 'failed', 'canceled'].includes(job.status)) return job;
    await new Promise((r) => setTimeout(r, intervalMs));
  }
}

export function el(tag, attrs = {}, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === 'class') e.className = v; else if (k === 'text') e.textContent = v; else e.setAttribute(k, v);
  }
  for (const c of children) if (c != null) e.append(c);
  return e;
}

export const fmt = (x, d = 3) => (typeof x === 'number' ? x.toFixed(d) : String(x ?? ''));

// Draw an image with boxes ([x1,y1,x2,y2] in `srcW` x `srcH` pixels) and an optional mask
// image tinted over it, on a canvas.
export function annotated(img, { srcW, srcH, boxes = [], mask = null, title = '' }) {
  const c = el('canvas', { class: 'frame', title });
  c.width = img.naturalWidth; c.height = img.naturalHeight;
  const g = c.getContext('2d');
  g.drawImage(img, 0, 0);
  if (mask) {
    const m = document.createElement('canvas');
    m.width = c.width; m.height = c.height;
    const mg = m.getContext('2d');
    mg.drawImage(mask, 0, 0, c.width, c.height);
    const d = mg.getImageData(0, 0, c.width, c.height);
    for (let i = 0; i < d.data.length; i += 4) {
      const on = d.data[i] > 127;
      d.data[i] = 0; d.data[i + 1] = 220; d.data[i + 2] = 255; d.data[i + 3] = on ? 110 : 0;
    }
    mg.putImageData(d, 0, 0);
    g.drawImage(m, 0, 0);
  }
  const sx = c.width / (srcW || c.width), sy = c.height / (srcH || c.height);
  for (const b of boxes) {
    g.lineWidth = b.chosen ? 4 : 2;
    g.strokeStyle = b.chosen ? '#ff2d55' : '#ffd60a';
    const [x1, y1, x2, y2] = b.box;
    g.strokeRect(x1 * sx, y1 * sy, (x2 - x1) * sx, (y2 - y1) * sy);
    if (b.label) {
      g.fillStyle = g.strokeStyle; g.font = '14px sans-serif';
      g.fillText(b.label, x1 * sx + 3, Math.max(14, y1 * sy - 3));
    }
  }
  return c;
}

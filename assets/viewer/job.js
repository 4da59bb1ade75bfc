// The job page: renders the job's trace as it grows, then the 3D view once it is done.
import { api, image, watchJob, el, fmt, annotated } from './common.js';
import { show } from './points3d.js';

const id = document.body.dataset.job;
const $ = (s) => document.getElementById(s);
const steps = (job, name) => (job.trace || []).filter((s) => s.step === name);
const last = (job, name) => steps(job, name).slice(-1)[0];
const section = (sid) => { const s = $(sid); s.querySelectorAll(':scope > :not(h2)').forEach((n) => n.remove()); return s; };

function boxTable(b) {
  const t = el('table', { id: 'box-table' });
  t.append(el('tr', {}, el('th', { text: '' }), el('th', { text: 'x' }), el('th', { text: 'y' }), el('th', { text: 'z' })));
  for (const k of ['min', 'max', 'center', 'size']) {
    t.append(el('tr', { class: `box-${k}` }, el('th', { text: k }), ...b[k].map((v) => el('td', { class: 'num', text: fmt(v) }))));
  }
  return t;
}

function renderHeader(job) {
  $('query').textContent = job.query;
  const st = $('status'); st.textContent = job.status; st.className = `badge ${job.status}`;
  $('scene-link').href = `/v1/scenes/${job.scene_id}/view`;
  $('object-ply').href = `/v1/jobs/${id}/object.ply`;
  $('scene-ply').href = `/v1/scenes/${job.scene_id}/points.ply?voxel=0.05`;
}

function renderResult(job) {
  const s = section('result');
  if (job.result && job.result.box) {
    s.append(el('div', { id: 'box' }, boxTable(job.result.box)));
    s.append(el('p', { text: `frame ${job.result.frame} (image ${job.result.image_id}), ${job.result.views_used} views fused` }));
  } else if (job.error) {
    const where = (job.trace || []).slice(-1)[0];
    s.append(el('p', { id: 'failure', class: 'failure',
      text: `failed at ${where ? where.step : 'start'}: ${job.error.code}: ${job.error.detail}` }));
  } else {
    s.append(el('p', { text: `${job.status}…` }));
  }
}

function renderAnalysis(job) {
  const s = section('analysis');
  const a = last(job, 'query_analysis');
  const an = a && a.outputs && a.outputs.analysis;
  if (!an) { s.append(el('p', { text: 'not yet' })); return; }
  const t = el('table', { id: 'analysis-table' });
  for (const [k, v] of Object.entries(an)) t.append(el('tr', {}, el('th', { text: k }), el('td', { text: Array.isArray(v) ? v.join(', ') : JSON.stringify(v) })));
  s.append(t);
}

async function renderGrids(job) {
  const s = section('grids');
  const st = last(job, 'stitching');
  if (!st) { s.append(el('p', { text: 'not yet' })); return; }
  const chosen = (last(job, 'image_selection') || {}).outputs?.image_id;
  for (const g of st.outputs.grids) {
    const img = await image(g.url);
    if (!img) continue;
    img.className = 'grid';
    const w = el('div', { class: 'gridwrap' }, img);
    const k = g.image_ids.indexOf(chosen);
    if (k >= 0) {
      const pick = el('div', { class: 'pick', id: 'chosen-in-grid' });
      pick.style.left = `${(100 * (k % g.cols)) / g.cols}%`;
      pick.style.top = `${(100 * Math.floor(k / g.cols)) / g.rows}%`;
      pick.style.width = `${100 / g.cols}%`; pick.style.height = `${100 / g.rows}%`;
      w.append(pick);
    }
    s.append(w);
  }
}

function renderVlm(job) {
  const s = section('vlm');
  for (const step of job.trace || []) {
    for (const [i, x] of ((step.outputs && step.outputs.vlm) || []).entries()) {
      const d = el('details', { class: 'exchange' }, el('summary', { text: `${step.step} #${i + 1}${x.invalid ? ' (invalid)' : ''}` }));
      for (const m of x.sent || []) d.append(el('pre', { text: `[${m.role}] ${m.text}${(m.images || []).length ? `\n(${m.images.length} images)` : ''}` }));
      if (x.reply) d.append(el('pre', { text: `[reply] ${x.reply.text ?? JSON.stringify(x.reply)}` }));
      if (x.invalid) d.append(el('p', { class: 'invalid', text: `invalid: ${x.invalid}` }));
      if (x.feedback) d.append(el('pre', { text: `[feedback] ${x.feedback}` }));
      s.append(d);
    }
  }
  if (s.children.length === 1) s.append(el('p', { text: 'no exchange yet' }));
}

async function frameCanvas(job, imageId, boxes, title) {
  const img = await image(`/v1/scenes/${job.scene_id}/frames/${imageId}.jpg`);
  if (!img) return el('p', { text: `frame ${imageId} is not available` });
  const mask = await image(`/v1/jobs/${id}/masks/${imageId}.png`);
  const scene = await sceneRecord(job);
  return annotated(img, { srcW: scene.color_size[0], srcH: scene.color_size[1], boxes, mask, title });
}

let sceneRec = null;
async function sceneRecord(job) { sceneRec = sceneRec || await api(`/v1/scenes/${job.scene_id}`); return sceneRec; }

async function renderChosen(job) {
  const s = section('chosen');
  const det = last(job, 'detection');
  const seg = last(job, 'segmentation');
  const inst = last(job, 'instance_selection');
  const imageId = (seg || det || {}).outputs?.image_id;
  if (!imageId) { s.append(el('p', { text: 'not yet' })); return; }
  const chosenBox = inst && inst.outputs.box;
  const boxes = ((det && det.outputs.image_id === imageId && det.outputs.detections) || []).map((d, i) => ({
    box: d.box, label: String(i), chosen: chosenBox && d.box.every((v, j) => Math.abs(v - chosenBox[j]) < 1e-3) }));
  if (chosenBox && !boxes.some((b) => b.chosen)) boxes.push({ box: chosenBox, chosen: true });
  const c = await frameCanvas(job, imageId, boxes, `image ${imageId}`);
  c.id = 'chosen-frame';
  s.append(el('p', { text: `image ${imageId}, ${boxes.length} candidate(s); the chosen one in red, its mask in blue` }), c);
}

async function renderViews(job) {
  const s = section('views');
  const p = last(job, 'projection');
  if (!p) { s.append(el('p', { text: 'not yet' })); return; }
  const wrap = el('div', { class: 'views' });
  for (const v of p.outputs.views.filter((v) => v.kept)) {
    const c = await frameCanvas(job, v.image_id, [{ box: v.box, chosen: true }], `image ${v.image_id}`);
    wrap.append(el('figure', {}, c, el('figcaption', { text: `image ${v.image_id}: ${v.points} points, chamfer ${fmt(v.chamfer)}` })));
  }
  if (!wrap.children.length) wrap.append(el('p', { text: 'the box comes from the chosen view alone' }));
  s.append(wrap);
}

function renderTimings(job) {
  const s = section('timings');
  const t = el('table', { id: 'timings-table' });
  for (const st of job.trace || []) t.append(el('tr', {}, el('th', { text: st.step }), el('td', { class: 'num', text: `${fmt(st.ms, 1)} ms` })));
  s.append(t);
}

let shown3d = false;
async function render3d(job) {
  if (shown3d || !['succeeded', 'failed', 'canceled'].includes(job.status)) return;
  shown3d = true;
  const clouds = [];
  clouds.push({ ply: await api(`/v1/scenes/${job.scene_id}/points.ply?voxel=0.05`, 'buf'), size: 0.04 });
  const boxes = [];
  if (job.result && job.result.box) {
    try { clouds.push({ ply: await api(`/v1/jobs/${id}/object.ply`, 'buf'), size: 0.05, color: 0xff2d55 }); } catch (e) { if (e.status !== 404) throw e; }
    boxes.push({ min: job.result.box.min, max: job.result.box.max, color: 0x30d158 });
  }
  const n = show($('scene3d'), { clouds, boxes });
  $('scene3d').dataset.points = String(n);
}

async function render(job) {
  renderHeader(job); renderResult(job); renderAnalysis(job); renderVlm(job); renderTimings(job);
  await renderGrids(job); await renderChosen(job); await renderViews(job); await render3d(job);
}

watchJob(id, render).then(() => { document.body.dataset.ready = '1'; })
  .catch((e) => { console.error(e.message || e); document.body.dataset.ready = '1'; });

// The scene page: frames with their detections, the camera path, points in 3D, jobs.
import { api, image, el, annotated } from './common.js';
import { show } from './points3d.js';

const id = document.body.dataset.scene;
const $ = (s) => document.getElementById(s);

async function main() {
  const scene = await api(`/v1/scenes/${id}`);
  $('name').textContent = `${scene.name} (${scene.frames} frames)`;
  const st = $('status'); st.textContent = scene.status; st.className = `badge ${scene.status}`;
  const { frames } = await api(`/v1/scenes/${id}/frames`);
  const jobs = await api(`/v1/jobs?scene_id=${id}&limit=100`);
  const list = el('table', { id: 'jobs-table' });
  for (const j of jobs.jobs) {
    list.append(el('tr', {}, el('td', {}, el('a', { href: `/v1/jobs/${j.id}/view`, text: j.query })), el('td', { text: j.status })));
  }
  $('jobs').append(jobs.jobs.length ? list : el('p', { text: 'no jobs yet' }));
  const path = frames.filter((f) => f.position).map((f) => f.position);
  const ply = await api(`/v1/scenes/${id}/points.ply?voxel=0.05`, 'buf');
  $('scene3d').dataset.points = String(show($('scene3d'), { clouds: [{ ply, size: 0.04 }], path }));
  for (const f of frames) {
    const fig = el('figure', { class: f.usable ? 'frame' : 'frame unusable', 'data-image-id': f.image_id });
    const img = await image(`/v1/scenes/${id}/frames/${f.image_id}.jpg`);
    if (img) {
      const boxes = f.detections.map((d) => ({ box: d.box, label: `${d.label} ${d.score.toFixed(2)}` }));
      fig.append(annotated(img, { srcW: scene.color_size[0], srcH: scene.color_size[1], boxes }));
    }
    fig.append(el('figcaption', { text: `${f.image_id} (frame ${f.name})${f.usable ? '' : ' — unusable pose'} · ${f.detections.length} detections` }));
    $('thumbs').append(fig);
  }
}

main().then(() => { document.body.dataset.ready = '1'; })
  .catch((e) => { console.error(e.message || e); document.body.dataset.ready = '1'; });

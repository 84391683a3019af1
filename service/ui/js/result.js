// A document rendered for people: a section per kind (camera, IMU, photometric, deblur, blur)
// on top of what every document has (quality numbers, artifacts, the raw JSON).

import { apiBlob } from './api.js';
import { h, fmt } from './dom.js';
import { barChart, residualPlot, curveChart } from './charts.js';

function artifactUrl(job, name) {
  return `/v1/jobs/${job}/artifacts/${encodeURIComponent(name)}`;
}

/** An <img> of an artifact, loaded with the token (so it works when auth is on). */
function artifactImage(job, name, alt) {
  const img = h('img', { alt, loading: 'lazy' });
  apiBlob(artifactUrl(job, name)).then((b) => { img.src = URL.createObjectURL(b); }).catch(() => { img.alt = `${alt} (not available)`; });
  return img;
}

function qualityTable(q) {
  if (!q || typeof q !== 'object') return null;
  const rows = Object.entries(q).filter(([, v]) => v === null || typeof v !== 'object');
  return h('dl', { class: 'kv quality' }, rows.flatMap(([k, v]) => [h('dt', {}, k.replaceAll('_', ' ')), h('dd', {}, fmt(v))]));
}

function camera(doc) {
  const p = doc.parameters || {};
  const cal = p.calibration || {};
  const out = [];
  const est = cal.parameters || [];
  if (est.length) {
    out.push(h('h2', {}, 'Intrinsics'), h('div', { class: 'table-wrap' }, h('table', { id: 'intrinsics' },
      h('thead', {}, h('tr', {}, ['Parameter', 'Value', 'σ (1σ)'].map((t) => h('th', { scope: 'col' }, t)))),
      h('tbody', {}, est.map((e) => h('tr', {}, h('td', {}, e.name), h('td', { class: 'num' }, fmt(e.value, 6)),
        h('td', { class: 'num' }, e.fixed ? 'fixed' : fmt(e.std_dev, 3))))))));
  }
  const views = cal.views || [];
  if (views.length) {
    out.push(h('h2', {}, 'Per-view reprojection error'), barChart({
      title: `RMS per view (px), overall ${fmt(cal.rms, 3)} px`,
      labels: views.map((v) => v.name), values: views.map((v) => (typeof v.rms === 'number' ? v.rms : NaN)),
      excluded: views.map((v) => !v.used), unit: ' px', threshold: cal.rms,
    }));
  }
  const obs = p.observations || [];
  const res = cal.residuals || [];
  if (obs.length && res.length && p.image_size) {
    const pix = new Map();
    obs.forEach((v, vi) => (v.corners || []).forEach((c) => pix.set(`${vi}:${c.index}`, c.pixel)));
    const residuals = res.filter((r) => r.residual).map((r) => ({ pixel: pix.get(`${r.view}:${r.index}`), residual: r.residual, inlier: r.inlier }));
    out.push(h('h2', {}, 'Residuals'), residualPlot({ width: p.image_size[0], height: p.image_size[1], residuals, title: 'Reprojection residuals over the image' }));
  }
  if (p.coverage && typeof p.coverage.fraction === 'number') {
    out.push(h('p', {}, `Board coverage of the image: ${Math.round(p.coverage.fraction * 100)} % of cells.`));
  }
  return out;
}

function allanModel(fit, tau) {
  // σ²(τ) = N²/τ + (2 ln 2/π)·B² + K²·τ/3 (IEEE Std 952 terms the fit estimates).
  const n = fit.n || 0, b = fit.b || 0, k = fit.k || 0;
  return Math.sqrt((n * n) / tau + (2 * Math.LN2 / Math.PI) * b * b + (k * k * tau) / 3);
}

function imu(doc) {
  const axes = (doc.parameters || {}).axes || [];
  if (!axes.length) return [];
  const out = [h('h2', {}, 'Allan deviation')];
  for (const sensor of ['gyro', 'accel']) {
    const own = axes.filter((a) => a.sensor === sensor);
    if (!own.length) continue;
    const series = [];
    for (const a of own) {
      const x = a.curve.map((c) => c.tau_s);
      series.push({ label: `${sensor} ${a.axis}`, x, y: a.curve.map((c) => c.adev) });
      if (a.fit && (a.fit.n || a.fit.b || a.fit.k)) series.push({ label: `${sensor} ${a.axis} fit`, x, y: x.map((t) => allanModel(a.fit, t)), dash: [5, 4] });
    }
    out.push(curveChart({ title: `${sensor}: Allan deviation and fitted noise model`, series, xLabel: 'τ (s)', yLabel: 'σ(τ)', logX: true, logY: true }));
    out.push(h('div', { class: 'table-wrap' }, h('table', {},
      h('thead', {}, h('tr', {}, ['Axis', 'N', 'B', 'K'].map((t) => h('th', { scope: 'col' }, t)))),
      h('tbody', {}, own.map((a) => h('tr', {}, h('td', {}, `${sensor} ${a.axis}`),
        ...['n', 'b', 'k'].map((k) => h('td', { class: 'num' }, a.fit && a.fit[k] !== null ? `${fmt(a.fit[k], 3)} ${a.units[k]}` : '—'))))))));
  }
  return out;
}

async function photometric(doc) {
  const job = doc.provenance && doc.provenance.job;
  const names = (doc.artifacts || []).map((a) => a.name);
  if (!job || !names.includes('pcalib.txt')) return [];
  try {
    const text = await (await apiBlob(artifactUrl(job, 'pcalib.txt'))).text();
    const g = text.trim().split(/\s+/).map(Number).filter(Number.isFinite);
    if (g.length < 2) return [];
    const x = g.map((_, i) => i);
    return [h('h2', {}, 'Inverse response'), curveChart({ title: 'Inverse response G(pixel value) (DSO pcalib.txt)', series: [{ label: 'G', x, y: g }], xLabel: 'pixel value', yLabel: 'irradiance' })];
  } catch {
    return [];
  }
}

function deblur(doc) {
  const job = doc.provenance && doc.provenance.job;
  const images = (doc.parameters || {}).images || [];
  const names = (doc.artifacts || []).map((a) => a.name);
  if (!job || !doc.provenance.dataset) return [];
  const out = [h('h2', {}, 'Before and after')];
  images.forEach((im, i) => {
    const name = im.name || im.file;
    if (!name) return;
    const stem = name.replace(/\.[^.]+$/, '');
    const after = names.find((n) => n === `${stem}.preview.png`) || names.find((n) => n === name);
    if (!after) return;
    const before = h('img', { alt: `${name} before`, class: 'before' });
    apiBlob(`/v1/datasets/${doc.provenance.dataset}/files/${i}`).then((b) => { before.src = URL.createObjectURL(b); }).catch(() => {});
    const afterImg = artifactImage(job, after, `${name} after`);
    const pane = h('div', { class: 'after' }, afterImg);
    const slider = h('input', { type: 'range', min: 0, max: 100, value: 50, 'aria-label': `Before/after position for ${name}` });
    const setW = () => {
      pane.style.width = `${slider.value}%`;
      afterImg.style.height = `${before.clientHeight}px`;
    };
    slider.addEventListener('input', setW);
    before.addEventListener('load', setW);
    const kernel = names.find((n) => n === `${stem}.kernel.png`);
    out.push(h('figure', { class: 'compare' }, before, pane, slider,
      h('figcaption', {}, `${name}: left of the handle deblurred, right the input`)));
    if (kernel) out.push(h('figure', {}, artifactImage(job, kernel, `${name} kernel`), h('figcaption', {}, 'Estimated kernel')));
  });
  return out;
}

function blur(doc) {
  const imgs = (doc.parameters || {}).images || [];
  if (!imgs.length) return [];
  return [h('h2', {}, 'Sharpness per image'),
    barChart({ title: 'Laplacian variance per image (blurred ones greyed)', labels: imgs.map((i) => i.name), values: imgs.map((i) => i.laplacian_variance), excluded: imgs.map((i) => i.blurred) }),
    barChart({ title: 'Singular-value feature β per image', labels: imgs.map((i) => i.name), values: imgs.map((i) => i.svd_beta), excluded: imgs.map((i) => i.blurred) })];
}

export async function renderDocument(doc) {
  const kind = doc.kind || '';
  let body = [];
  if (kind === 'camera_calibration') body = camera(doc);
  else if (kind.startsWith('imu_noise')) body = imu(doc);
  else if (kind.startsWith('photometric')) body = await photometric(doc);
  else if (kind === 'deblur') body = deblur(doc);
  else if (kind === 'blur_score') body = blur(doc);
  const job = doc.provenance && doc.provenance.job;
  const arts = (doc.artifacts || []).filter((a) => /^image\//.test(a.media_type));
  return h('div', { class: 'document' },
    h('h2', {}, 'Quality'), qualityTable(doc.quality),
    body,
    job && arts.length ? [h('h2', {}, 'Artifacts'), h('div', { class: 'artifacts' }, arts.slice(0, 12).map((a) => h('figure', {}, artifactImage(job, a.name, a.name), h('figcaption', {}, a.name))))] : null,
    h('details', {}, h('summary', {}, 'Document JSON'), h('pre', { class: 'json' }, JSON.stringify(doc, null, 2).slice(0, 200000))),
  );
}

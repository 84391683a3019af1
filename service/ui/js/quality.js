// A badge per document from its `quality` numbers: what an engineer looks at first. The
// thresholds are conventional (sub-pixel RMS is good for a calibration; a fit with warnings
// needs a look), not tuned to any data set.

import { h, fmt } from './dom.js';

export function badge(kind, q) {
  const b = grade(kind, q || {});
  return h('span', { class: `badge ${b.level}`, title: b.title || b.text }, b.text);
}

function grade(kind, q) {
  if (kind === 'camera_calibration' && typeof q.rms === 'number') {
    const level = q.rms < 0.5 ? 'good' : q.rms < 1.0 ? 'warn' : 'bad';
    const cov = typeof q.coverage === 'number' ? `, coverage ${Math.round(q.coverage * 100)} %` : '';
    const weak = typeof q.coverage === 'number' && q.coverage < 0.5 && level === 'good';
    return { level: weak ? 'warn' : level, text: `RMS ${fmt(q.rms, 3)} px`, title: `RMS ${fmt(q.rms, 3)} px${cov}` };
  }
  if (q.converged === false) return { level: 'bad', text: 'not converged' };
  if (typeof q.warnings === 'number' && q.warnings > 0) {
    return { level: 'warn', text: `${q.warnings} warning${q.warnings > 1 ? 's' : ''}` };
  }
  if (kind === 'blur_score' && typeof q.blurred === 'number') {
    const level = q.blurred === 0 ? 'good' : 'warn';
    return { level, text: `${q.blurred}/${q.images} blurred` };
  }
  if (typeof q.relative_rms === 'number') {
    return { level: q.relative_rms < 0.02 ? 'good' : 'warn', text: `rel. RMS ${fmt(q.relative_rms, 2)}` };
  }
  return { level: 'info', text: 'ok' };
}

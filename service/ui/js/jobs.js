// Jobs, live: the list comes from GET /v1/jobs; each queued or running job is followed over
// its Server-Sent Events (progress, status), and the list is re-read every few seconds to
// pick up jobs other clients queue.

import { api, followJob } from './api.js';
import { h, age, enc, shortId } from './dom.js';
import { renderDocument } from './result.js';

const FOLLOW_MAX = 10;

function progressCell(job) {
  const p = job.progress;
  const pct = p ? Math.round(p.percent) : job.status === 'succeeded' ? 100 : 0;
  const bar = h('progress', { max: 100, value: pct, 'aria-label': `Progress of job ${job.id}` });
  const label = job.status === 'succeeded' ? '100 %' : p ? `${p.step} ${pct} %` : job.status === 'queued' ? 'waiting' : '';
  const text = h('span', { class: 'muted step' }, label);
  return { cell: h('div', { class: 'progress-row' }, bar, text), bar, text };
}

function cancelButton(job, after) {
  if (job.status !== 'queued' && job.status !== 'running') return null;
  return h('button', {
    type: 'button', class: 'danger', dataset: { cancel: job.id },
    onclick: async (e) => {
      e.target.disabled = true;
      await api(`/v1/jobs/${job.id}/cancel`, { method: 'POST' });
      after && after();
    },
  }, 'Cancel');
}

function statusBadge(status) {
  const level = { succeeded: 'good', failed: 'bad', canceled: 'warn', running: 'info', queued: 'info' }[status] || 'info';
  return h('span', { class: `badge ${level} status` }, status);
}

function jobRow(job, refresh) {
  const prog = progressCell(job);
  const status = h('td', {}, statusBadge(job.status));
  const err = job.error ? h('div', { class: 'error-text' }, `${job.error.code}: ${job.error.message}`) : null;
  const row = h('tr', { dataset: { job: job.id, status: job.status } },
    h('td', {}, h('a', { href: `#/jobs/${job.id}`, title: job.id }, shortId(job.id)), h('div', { class: 'muted' }, age(job.created_at))),
    h('td', {}, job.kind, job.device ? h('div', { class: 'muted' }, `${job.device}/${job.sensor || 'default'}`) : null),
    status,
    h('td', {}, prog.cell, err),
    h('td', {}, cancelButton(job, refresh)));
  return { row, prog, status };
}

function applyEvent(parts, row, ev) {
  if (ev.progress) {
    const pct = Math.round(ev.progress.percent);
    parts.prog.bar.value = pct;
    parts.prog.text.textContent = `${ev.progress.step} ${pct} %`;
  }
  if (ev.status) {
    parts.status.replaceChildren(statusBadge(ev.status));
    row.dataset.status = ev.status;
    if (ev.status !== 'queued' && ev.status !== 'running') {
      for (const b of row.querySelectorAll('[data-cancel]')) b.remove();
    }
    if (ev.status === 'succeeded') {
      parts.prog.bar.value = 100;
      parts.prog.text.textContent = '100 %';
    }
  }
}

export async function jobsPage() {
  const tbody = h('tbody');
  const followers = new Map();
  let timer = null;
  let stopped = false;
  const load = async () => {
    const page = await api('/v1/jobs?limit=50');
    const rows = page.items.map((job) => {
      const parts = jobRow(job, load);
      if ((job.status === 'queued' || job.status === 'running') && followers.size < FOLLOW_MAX && !followers.has(job.id)) {
        followers.set(job.id, followJob(job.id, (_, ev) => {
          const live = tbody.querySelector(`tr[data-job="${job.id}"]`);
          if (live && live.__parts) applyEvent(live.__parts, live, ev);
        }, () => followers.delete(job.id)));
      }
      parts.row.__parts = parts;
      return parts.row;
    });
    tbody.replaceChildren(...rows);
  };
  await load();
  const tick = async () => {
    if (stopped) return;
    try {
      await load();
    } catch {
      /* a failed refresh keeps the last list; the next one may succeed */
    }
    timer = setTimeout(tick, 3000);
  };
  timer = setTimeout(tick, 3000);
  const node = h('section', {},
    h('h1', {}, 'Jobs'),
    h('p', { class: 'muted' }, 'Newest first; queued and running jobs update live.'),
    h('div', { class: 'table-wrap' }, h('table', { id: 'jobs-table' },
      h('thead', {}, h('tr', {}, ['Job', 'Kind', 'Status', 'Progress', ''].map((t) => h('th', { scope: 'col' }, t)))),
      tbody)));
  return {
    node, title: 'Jobs',
    cleanup: () => {
      stopped = true;
      clearTimeout(timer);
      for (const stop of followers.values()) stop();
    },
  };
}

export async function jobPage(id) {
  const job = await api(`/v1/jobs/${id}`);
  // After a cancel the stream reports the new status; nothing to reload.
  const parts = jobRow(job, () => {});
  const result = h('div', { id: 'job-result' });
  const showResult = async () => {
    const doc = await api(`/v1/jobs/${id}/result`);
    const link = job.document || doc.device
      ? h('p', {}, 'Filed as ', h('a', { href: `#/devices/${enc(doc.device)}/${enc(doc.sensor)}/${enc(doc.kind)}/${doc.rev}` }, `${doc.device}/${doc.sensor} ${doc.kind} r${doc.rev}`))
      : null;
    result.replaceChildren(h('h2', {}, 'Result'), link || '', await renderDocument(doc));
  };
  let stop = null;
  if (job.status === 'succeeded') await showResult();
  else if (job.status === 'queued' || job.status === 'running') {
    stop = followJob(id, (_, ev) => {
      applyEvent(parts, parts.row, ev);
      if (ev.status === 'succeeded') showResult().catch(() => {});
      if (ev.status === 'failed' || ev.status === 'canceled') {
        api(`/v1/jobs/${id}`).then((j) => {
          if (j.error) result.replaceChildren(h('p', { class: 'error-text', id: 'job-error' }, `${j.error.code}: ${j.error.message}`));
        }).catch(() => {});
      }
    });
  }
  const node = h('section', {},
    h('p', {}, h('a', { href: '#/jobs' }, '← Jobs')),
    h('h1', {}, 'Job ', h('code', { title: id }, shortId(id))),
    h('div', { class: 'table-wrap' }, h('table', { id: 'job-table' },
      h('thead', {}, h('tr', {}, ['Job', 'Kind', 'Status', 'Progress', ''].map((t) => h('th', { scope: 'col' }, t)))),
      h('tbody', {}, parts.row))),
    h('details', {}, h('summary', {}, 'Parameters'), h('pre', { class: 'json' }, JSON.stringify(job.params, null, 2))),
    result);
  return { node, title: `Job ${shortId(id)}`, cleanup: () => stop && stop() };
}
